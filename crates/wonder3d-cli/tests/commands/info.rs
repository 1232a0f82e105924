//! `wonder3d info` agrees with the properties table of `../shared/data/meshes/SOURCES.md`
//! (computed there with trimesh) on all 18 test meshes.

use std::path::PathBuf;
use std::process::Command;

fn shared_meshes() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes")
}

/// One row of the SOURCES.md table: file, triangles, watertight, boundary edges, components, euler.
struct Expected {
    file: String,
    triangles: usize,
    watertight: bool,
    boundary_edges: Option<usize>,
    components: usize,
    euler: i64,
}

fn expected_rows() -> Vec<Expected> {
    let text = std::fs::read_to_string(shared_meshes().join("SOURCES.md")).unwrap();
    text.lines()
        .filter_map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            // | file | extra | origin | licence | character | v | f | watertight | comps | euler | bbox |
            let file = cells.get(1)?;
            if cells.len() < 12 || !(file.ends_with(".obj") || file.ends_with(".ply")) {
                return None;
            }
            // "500 (968 tris)" for quad meshes: the triangle count is in parentheses.
            let f = cells[7];
            let triangles = match f.split_once('(') {
                Some((_, rest)) => rest.trim_end_matches(" tris)").parse().unwrap(),
                None => f.parse().unwrap(),
            };
            let w = cells[8];
            let boundary_edges =
                w.split_once('(').map(|(_, rest)| rest.split_whitespace().next().unwrap().parse().unwrap());
            Some(Expected {
                file: file.to_string(),
                triangles,
                watertight: w.starts_with("yes"),
                boundary_edges: if w.starts_with("yes") { Some(0) } else { boundary_edges },
                components: cells[9].parse().unwrap(),
                euler: cells[10].parse().unwrap(),
            })
        })
        .collect()
}

fn info_json(path: &std::path::Path) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_wonder3d")).arg("info").arg("--json").arg(path).output().unwrap();
    assert!(out.status.success(), "{}: {}", path.display(), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn info_matches_sources_table_for_all_meshes() {
    let rows = expected_rows();
    assert_eq!(rows.len(), 18, "SOURCES.md lists 18 meshes");
    for row in rows {
        let info = info_json(&shared_meshes().join(&row.file));
        let what = &row.file;
        assert_eq!(info["triangles"], row.triangles, "{what}: triangles");
        assert_eq!(info["watertight"], row.watertight, "{what}: watertight");
        if let Some(b) = row.boundary_edges {
            assert_eq!(info["boundary_edges"], b, "{what}: boundary edges");
        }
        assert_eq!(info["components"], row.components, "{what}: components");
        assert_eq!(info["euler"], row.euler, "{what}: euler");
    }
}

#[test]
fn info_prints_genus_for_closed_meshes() {
    let out = Command::new(env!("CARGO_BIN_EXE_wonder3d"))
        .args(["info"])
        .arg(shared_meshes().join("torus.obj"))
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("watertight    yes") && text.contains("genus         1"), "{text}");
}

#[test]
fn info_on_a_missing_file_fails_with_its_name() {
    let out = Command::new(env!("CARGO_BIN_EXE_wonder3d")).args(["info", "no/such/mesh.obj"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("no/such/mesh.obj"), "{err}");
}
