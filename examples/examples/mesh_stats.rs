//! Load a mesh, normalise it into the unit cube and print its topology, then project its
//! bounding box into the front view of the Wonder3D rig.
//!
//! ```text
//! cargo run --release -p wonder3d-examples --example mesh_stats -- assets/spot.obj
//! ```

use wonder3d::{ViewRig, load_mesh};

fn main() -> Result<(), wonder3d::Error> {
    let path = std::env::args_os()
        .nth(1)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| wonder3d_examples::assets_dir().join("spot.obj"));
    let mut mesh = load_mesh(&path)?;
    let transform = mesh.normalize_unit_cube();
    let (merged, _) = mesh.merge_by_position();
    let topology = merged.topology();
    println!("{}: {} vertices, {} triangles", path.display(), mesh.vertex_count(), mesh.triangle_count());
    println!("scaled by {:.4} about {:?} into the unit cube", transform.scale, transform.centre);
    println!(
        "watertight: {}, components: {}, euler: {}, genus: {:?}",
        topology.is_watertight(),
        topology.components,
        topology.euler,
        topology.genus()
    );

    let rig = ViewRig::wonder3d_ortho();
    let front = &rig.views[0].camera;
    let (lo, hi) = mesh.bbox();
    let (a, b) = (front.project(lo, 256, 256), front.project(hi, 256, 256));
    println!("front view (256²): bbox spans pixels x {:.1}..{:.1}, y {:.1}..{:.1}", a.x, b.x, b.y, a.y);
    Ok(())
}
