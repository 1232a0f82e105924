//! Convert a mesh between formats (OBJ / PLY / glTF in, OBJ / PLY / GLB out), optionally
//! turning it about the y (up) axis and normalising it into the unit cube.
//!
//! ```text
//! cargo run --release -p wonder3d-examples --example convert -- assets/spot.obj spot.glb --normalize
//! cargo run --release -p wonder3d-examples --example convert -- assets/spot.obj spot.glb --rotate-y 90
//! ```

use wonder3d::core::glam::{Quat, Vec3};

fn main() -> Result<(), wonder3d::Error> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(input), Some(output)) = (args.first(), args.get(1)) else {
        eprintln!("usage: convert INPUT OUTPUT [--rotate-y DEGREES] [--normalize]");
        std::process::exit(2);
    };
    let mut mesh = wonder3d::load_mesh(input)?;
    if let Some(i) = args.iter().position(|a| a == "--rotate-y") {
        let degrees: f32 = args
            .get(i + 1)
            .and_then(|d| d.parse().ok())
            .ok_or_else(|| wonder3d::Error::invalid("--rotate-y", "an angle in degrees"))?;
        // Counter-clockwise seen from above (+y), so +90 turns a +x-facing object to face -z.
        let turn = Quat::from_rotation_y(degrees.to_radians());
        mesh.map_positions(|p: Vec3| turn * p)?;
        if let Some(normals) = mesh.normals() {
            let turned = normals.iter().map(|&n| (turn * Vec3::from(n)).to_array()).collect();
            mesh = mesh.with_normals(turned)?;
        }
    }
    if args.iter().any(|a| a == "--normalize") {
        mesh.normalize_unit_cube();
    }
    wonder3d::save_mesh(output, &mesh)?;
    println!("{input} -> {output}: {} vertices, {} triangles", mesh.vertex_count(), mesh.triangle_count());
    Ok(())
}
