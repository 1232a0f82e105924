//! Convert a mesh between formats (OBJ / PLY / glTF in, OBJ / PLY / GLB out), optionally
//! normalising it into the unit cube.
//!
//! ```text
//! cargo run --release -p wonder3d-examples --example convert -- assets/spot.obj spot.glb --normalize
//! ```

fn main() -> Result<(), w3d_core::Error> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(input), Some(output)) = (args.first(), args.get(1)) else {
        eprintln!("usage: convert INPUT OUTPUT [--normalize]");
        std::process::exit(2);
    };
    let mut mesh = w3d_core::load_mesh(input)?;
    if args.iter().any(|a| a == "--normalize") {
        mesh.normalize_unit_cube();
    }
    w3d_core::save_mesh(output, &mesh)?;
    println!("{input} -> {output}: {} vertices, {} triangles", mesh.vertex_count(), mesh.triangle_count());
    Ok(())
}
