//! `wonder3d info MESH`.

use std::path::PathBuf;

use serde::Serialize;
use wonder3d::{Result, load_mesh};

/// Arguments of `wonder3d info`.
#[derive(clap::Args)]
pub struct InfoArgs {
    /// Mesh file (.obj, .ply, .glb, .gltf).
    mesh: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// What `wonder3d info` reports. Topology is computed after merging vertices by
/// position (ignoring uv and normal seams), like trimesh's `process=True`.
#[derive(Serialize)]
struct MeshInfo {
    file: String,
    vertices: usize,
    triangles: usize,
    /// Zero-area triangles (two corners at one position, or collinear corners); merging
    /// drops the first kind, so they are not in `faces`.
    degenerate_triangles: usize,
    merged_vertices: usize,
    edges: usize,
    faces: usize,
    bbox_min: [f32; 3],
    bbox_max: [f32; 3],
    watertight: bool,
    boundary_edges: usize,
    non_manifold_edges: usize,
    components: usize,
    euler: i64,
    genus: Option<i64>,
    surface_area: f64,
    signed_volume: f64,
    has_normals: bool,
    has_uvs: bool,
    has_colours: bool,
    texture: Option<[u32; 2]>,
}

/// Runs `wonder3d info`.
pub fn run(args: &InfoArgs) -> Result<()> {
    let mesh = load_mesh(&args.mesh)?;
    let (merged, _) = mesh.merge_by_position();
    let topo = merged.topology();
    let (lo, hi) = mesh.bbox();
    let info = MeshInfo {
        file: args.mesh.display().to_string(),
        vertices: mesh.vertex_count(),
        triangles: mesh.triangle_count(),
        degenerate_triangles: mesh.degenerate_triangle_count(),
        merged_vertices: topo.vertices,
        edges: topo.edges,
        faces: topo.faces,
        bbox_min: lo.to_array(),
        bbox_max: hi.to_array(),
        watertight: topo.is_watertight(),
        boundary_edges: topo.boundary_edges,
        non_manifold_edges: topo.non_manifold_edges,
        components: topo.components,
        euler: topo.euler,
        genus: topo.genus(),
        surface_area: merged.surface_area(),
        signed_volume: merged.signed_volume(),
        has_normals: mesh.normals().is_some(),
        has_uvs: mesh.uvs().is_some(),
        has_colours: mesh.colours().is_some(),
        texture: mesh.texture().map(|t| [t.width(), t.height()]),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info).expect("plain data serialises"));
        return Ok(());
    }
    println!("{}", info.file);
    println!("  vertices      {} ({} after merging by position)", info.vertices, info.merged_vertices);
    println!("  triangles     {}", info.triangles);
    if info.degenerate_triangles > 0 {
        println!("  degenerate    {} triangles of zero area (no orientation, no surface)", info.degenerate_triangles);
    }
    println!("  edges         {}", info.edges);
    let [a, b, c] = info.bbox_min;
    let [d, e, f] = info.bbox_max;
    println!("  bbox          [{a:.4}, {b:.4}, {c:.4}] -> [{d:.4}, {e:.4}, {f:.4}]");
    if info.watertight {
        println!("  watertight    yes");
    } else if info.faces == 0 {
        println!("  watertight    no (no triangle of non-zero size is left after merging by position)");
    } else {
        println!(
            "  watertight    no ({} boundary edges, {} non-manifold edges)",
            info.boundary_edges, info.non_manifold_edges
        );
    }
    println!("  components    {}", info.components);
    println!("  euler         {}", info.euler);
    match info.genus {
        Some(g) => println!("  genus         {g}"),
        None => println!("  genus         undefined (not watertight)"),
    }
    println!("  surface area  {:.6}", info.surface_area);
    println!("  volume        {:.6}", info.signed_volume);
    let yes = |b: bool| if b { "yes" } else { "no" };
    println!(
        "  attributes    normals {}, uvs {}, colours {}, texture {}",
        yes(info.has_normals),
        yes(info.has_uvs),
        yes(info.has_colours),
        info.texture.map_or("no".to_string(), |[w, h]| format!("{w}×{h}"))
    );
    Ok(())
}
