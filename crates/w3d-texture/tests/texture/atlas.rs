//! The UV atlas on real meshes: no two triangles overlap in uv space (exact test on the
//! f32 uvs), utilisation ≥ 60 %, the geometry is unchanged; angle distortion is reported.

use std::collections::HashMap;

use w3d_core::{Mesh, load_mesh};
use w3d_texture::{Atlas, AtlasOptions, build_atlas};

fn mesh(path: &str) -> Mesh {
    let mut mesh = load_mesh(format!("{}/../../{path}", env!("CARGO_MANIFEST_DIR"))).unwrap();
    mesh.normalize_unit_cube();
    mesh
}

/// An f32 in `[0, 1]` as an exact fixed-point integer (units of 2⁻⁶⁰).
fn fixed(v: f32) -> i128 {
    assert!((0.0..=1.0).contains(&v), "uv {v} outside [0, 1]");
    let scaled = f64::from(v) * (1u64 << 60) as f64;
    assert_eq!(scaled.fract(), 0.0, "uv {v} is not a multiple of 2^-60");
    scaled as i128
}

type Point = [i128; 2];

/// Exact orientation of `c` relative to `a → b` (|coordinates| ≤ 2⁶⁰, so no overflow).
fn orient(a: Point, b: Point, c: Point) -> i128 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Whether the interiors of two non-degenerate triangles intersect. By the separating
/// axis theorem for convex polygons, interiors are disjoint iff some edge line of one
/// triangle has the other triangle entirely on its closed outer side; touching along
/// shared edges or vertices is therefore not an overlap.
fn interiors_overlap(t: [Point; 3], u: [Point; 3]) -> bool {
    let separated_by_edges_of = |a: [Point; 3], b: [Point; 3]| {
        let s = orient(a[0], a[1], a[2]).signum();
        (0..3).any(|k| {
            let (p, q) = (a[k], a[(k + 1) % 3]);
            b.iter().all(|&x| orient(p, q, x).signum() * s <= 0)
        })
    };
    !(separated_by_edges_of(t, u) || separated_by_edges_of(u, t))
}

/// Every pair of triangles whose uv boxes meet (grid broad phase, each pair tested once),
/// checked exactly; returns the overlapping pairs and the degenerate uv triangles.
fn uv_overlaps(atlas: &Atlas) -> (Vec<(usize, usize)>, Vec<usize>) {
    let tris: Vec<[Point; 3]> = atlas.triangles.iter().map(|t| t.map(|v| atlas.uvs[v as usize].map(fixed))).collect();
    let degenerate: Vec<usize> = (0..tris.len()).filter(|&i| orient(tris[i][0], tris[i][1], tris[i][2]) == 0).collect();
    let cells = (tris.len() as f64).sqrt().ceil() as i64;
    let cell_of =
        |v: i128| ((v as f64 / (1u64 << 60) as f64) * cells as f64).floor().clamp(0.0, (cells - 1) as f64) as i64;
    let bbox = |t: &[Point; 3]| {
        let lo = [0, 1].map(|k| t.iter().map(|p| p[k]).min().unwrap());
        let hi = [0, 1].map(|k| t.iter().map(|p| p[k]).max().unwrap());
        (lo, hi)
    };
    let mut grid: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (i, t) in tris.iter().enumerate() {
        let (lo, hi) = bbox(t);
        for cx in cell_of(lo[0])..=cell_of(hi[0]) {
            for cy in cell_of(lo[1])..=cell_of(hi[1]) {
                grid.entry((cx, cy)).or_default().push(i);
            }
        }
    }
    let mut overlaps = Vec::new();
    for (&(cx, cy), members) in &grid {
        for (k, &i) in members.iter().enumerate() {
            for &j in &members[k + 1..] {
                let ((li, hi_i), (lj, hi_j)) = (bbox(&tris[i]), bbox(&tris[j]));
                let lo = [li[0].max(lj[0]), li[1].max(lj[1])];
                let hi = [hi_i[0].min(hi_j[0]), hi_i[1].min(hi_j[1])];
                // Boxes apart, or this pair belongs to another cell (the one holding `lo`).
                if lo[0] > hi[0] || lo[1] > hi[1] || (cell_of(lo[0]), cell_of(lo[1])) != (cx, cy) {
                    continue;
                }
                if !degenerate.contains(&i) && !degenerate.contains(&j) && interiors_overlap(tris[i], tris[j]) {
                    overlaps.push((i.min(j), i.max(j)));
                }
            }
        }
    }
    (overlaps, degenerate)
}

fn check(name: &str, path: &str) {
    let mesh = mesh(path);
    let options = AtlasOptions::default();
    let start = std::time::Instant::now();
    let atlas = build_atlas(&mesh, &options).unwrap();
    let r = atlas.report;
    println!(
        "{name}: {} faces → {} charts ({} fallbacks), utilisation {:.3}, angle distortion {:.2}°, {:.0} texels/unit, {} vertices (from {}), {:.2} s",
        mesh.triangle_count(),
        r.charts,
        r.fallback_charts,
        r.utilisation,
        r.angle_distortion_deg,
        r.texels_per_unit,
        atlas.positions.len(),
        mesh.vertex_count(),
        start.elapsed().as_secs_f64()
    );
    // Same triangles, same corner positions (bit for bit).
    assert_eq!(atlas.triangles.len(), mesh.triangle_count());
    for (t, (a, m)) in atlas.triangles.iter().zip(mesh.triangles()).enumerate() {
        for k in 0..3 {
            let p = atlas.positions[a[k] as usize];
            assert_eq!(p, mesh.positions()[m[k] as usize], "triangle {t} corner {k}");
            assert_eq!(p, mesh.positions()[atlas.source_vertex[a[k] as usize] as usize]);
        }
    }
    // Each vertex belongs to one chart.
    let mut chart_of_vertex = vec![u32::MAX; atlas.positions.len()];
    for (t, a) in atlas.triangles.iter().enumerate() {
        for &v in a {
            let c = &mut chart_of_vertex[v as usize];
            assert!(*c == u32::MAX || *c == atlas.triangle_chart[t], "vertex {v} in two charts");
            *c = atlas.triangle_chart[t];
        }
    }
    let (overlaps, degenerate) = uv_overlaps(&atlas);
    assert!(
        degenerate.is_empty(),
        "{name}: {} degenerate uv triangles, e.g. {:?}",
        degenerate.len(),
        &degenerate[..degenerate.len().min(5)]
    );
    assert!(
        overlaps.is_empty(),
        "{name}: {} overlapping uv triangle pairs, e.g. {:?}",
        overlaps.len(),
        &overlaps[..overlaps.len().min(5)]
    );
    assert!(r.utilisation >= 0.6, "{name}: utilisation {:.3}", r.utilisation);
    assert!(r.angle_distortion_deg < 10.0, "{name}: angle distortion {:.2}°", r.angle_distortion_deg);
}

#[test]
fn spot_atlas() {
    check("spot", "assets/spot.obj");
}

#[test]
fn armadillo_atlas() {
    check("armadillo (3k decimation)", "crates/w3d-eval/fixtures/armadillo_decimated.obj");
}

#[test]
fn the_overlap_test_finds_overlaps() {
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
    let mesh = Mesh::new(p, vec![[0, 1, 2], [1, 3, 2]]).unwrap();
    let mut atlas = build_atlas(&mesh, &AtlasOptions::default().with_size(64)).unwrap();
    assert!(uv_overlaps(&atlas).0.is_empty());
    // Sharing an edge is not an overlap; folding one triangle over the other is.
    let t = atlas.triangles[1];
    let shared: Vec<u32> = t.iter().copied().filter(|v| atlas.triangles[0].contains(v)).collect();
    assert_eq!(shared.len(), 2, "one chart for a flat quad");
    let apex = *t.iter().find(|v| !shared.contains(v)).unwrap() as usize;
    // Reflect the apex through the shared edge's midpoint: it lands on triangle 0's apex.
    let (s0, s1) = (atlas.uvs[shared[0] as usize], atlas.uvs[shared[1] as usize]);
    let m = [(s0[0] + s1[0]) * 0.5, (s0[1] + s1[1]) * 0.5];
    atlas.uvs[apex] = [2.0 * m[0] - atlas.uvs[apex][0], 2.0 * m[1] - atlas.uvs[apex][1]];
    assert_eq!(uv_overlaps(&atlas).0, vec![(0, 1)]);
}
