//! Wavefront OBJ + MTL.

use std::io::Write;
use std::path::Path;

use crate::image::Image;
use crate::io::write_atomic;
use crate::{Error, Mesh, Result};

/// Reads an OBJ file (all objects/groups concatenated, polygons fan-triangulated) with
/// its normals, texture coordinates, vertex colours and — when the MTL gives one — the
/// diffuse texture (`map_Kd`) of the first material that has it.
///
/// Vertices are split where normals or uvs differ (one index buffer) and numbered in the
/// order the faces first use them, so reading an OBJ that this crate wrote gives back the
/// same vertex order; other files may be renumbered (the geometry is the same). A `mtllib` that
/// cannot be read, or a `map_Kd` texture that is missing, is an error naming that file.
pub fn read_obj(path: impl AsRef<Path>) -> Result<Mesh> {
    let path = path.as_ref();
    // tobj reports a missing file as a generic error; check first for a clear message.
    std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let options = tobj::LoadOptions { single_index: true, triangulate: true, ignore_points: true, ignore_lines: true };
    let (models, materials) = tobj::load_obj(path, &options)
        .map_err(|e| Error::format(path, "OBJ data", format!("a valid OBJ file ({e})")))?;
    let materials = materials.map_err(|e| Error::format(path, "mtllib", format!("a readable MTL file ({e})")))?;

    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut normals: Vec<[f32; 3]> = Vec::new();
    let mut uvs: Vec<[f32; 2]> = Vec::new();
    let mut colours: Vec<[f32; 3]> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let (mut all_normals, mut all_uvs, mut all_colours) = (true, true, true);
    for model in &models {
        let m = &model.mesh;
        let base = positions.len() as u32;
        let n = m.positions.len() / 3;
        positions.extend(m.positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        all_normals &= m.normals.len() == n * 3;
        all_uvs &= m.texcoords.len() == n * 2;
        all_colours &= m.vertex_color.len() == n * 3;
        normals.extend(m.normals.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        uvs.extend(m.texcoords.chunks_exact(2).map(|c| [c[0], c[1]]));
        colours.extend(m.vertex_color.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        for (k, t) in m.indices.chunks_exact(3).enumerate() {
            if t.iter().any(|&i| i as usize >= n) {
                return Err(Error::format(
                    path,
                    format!("object {:?} face {k}", model.name),
                    format!("vertex indices that exist (1..={n})"),
                ));
            }
            triangles.push([t[0] + base, t[1] + base, t[2] + base]);
        }
    }
    let mut mesh = Mesh::new(positions, triangles).map_err(|e| e.in_file(path))?;
    if all_normals && !normals.is_empty() {
        mesh = mesh.with_normals(normals).map_err(|e| e.in_file(path))?;
    }
    if all_uvs && !uvs.is_empty() {
        mesh = mesh.with_uvs(uvs).map_err(|e| e.in_file(path))?;
    }
    if all_colours && !colours.is_empty() {
        mesh = mesh.with_colours(colours).map_err(|e| e.in_file(path))?;
    }
    if let Some(texture_name) = materials.iter().find_map(|m| m.diffuse_texture.clone()) {
        let texture_path = path.parent().unwrap_or(Path::new(".")).join(texture_name.trim());
        if !texture_path.is_file() {
            return Err(Error::format(
                path,
                "material map_Kd",
                format!("an existing texture file, {} is missing", texture_path.display()),
            ));
        }
        if mesh.uvs().is_some() {
            let texture = Image::read_png(&texture_path)?;
            if !matches!(texture.channels(), 3 | 4) {
                return Err(Error::format(
                    &texture_path,
                    "PNG channels",
                    format!("an RGB or RGBA texture, got {} channels", texture.channels()),
                ));
            }
            mesh = mesh.with_texture(texture)?;
        }
    }
    Ok(mesh)
}

/// Writes an OBJ file (positions, uvs, normals, vertex colours as `v x y z r g b`).
/// A textured mesh also gets `<stem>.mtl` and `<stem>.png` beside it. Each file is
/// written atomically.
pub fn write_obj(path: impl AsRef<Path>, mesh: &Mesh) -> Result<()> {
    let path = path.as_ref();
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "mesh".into());
    if let Some(texture) = mesh.texture() {
        let png = path.with_file_name(format!("{stem}.png"));
        texture.write_png(&png)?;
        let mtl = path.with_file_name(format!("{stem}.mtl"));
        write_atomic(&mtl, |w| {
            write!(w, "newmtl material0\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {stem}.png\n")
                .map_err(|e| Error::io(&mtl, e))
        })?;
    }
    write_atomic(path, |w| {
        let io = |e| Error::io(path, e);
        writeln!(w, "# written by wonder3d-rs").map_err(io)?;
        if mesh.texture().is_some() {
            writeln!(w, "mtllib {stem}.mtl\nusemtl material0").map_err(io)?;
        }
        for (i, p) in mesh.positions().iter().enumerate() {
            match mesh.colours() {
                Some(c) => writeln!(w, "v {} {} {} {} {} {}", p[0], p[1], p[2], c[i][0], c[i][1], c[i][2]),
                None => writeln!(w, "v {} {} {}", p[0], p[1], p[2]),
            }
            .map_err(io)?;
        }
        for t in mesh.uvs().unwrap_or(&[]) {
            writeln!(w, "vt {} {}", t[0], t[1]).map_err(io)?;
        }
        for n in mesh.normals().unwrap_or(&[]) {
            writeln!(w, "vn {} {} {}", n[0], n[1], n[2]).map_err(io)?;
        }
        let (has_uv, has_n) = (mesh.uvs().is_some(), mesh.normals().is_some());
        for t in mesh.triangles() {
            let [a, b, c] = t.map(|i| i + 1);
            match (has_uv, has_n) {
                (true, true) => writeln!(w, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}"),
                (true, false) => writeln!(w, "f {a}/{a} {b}/{b} {c}/{c}"),
                (false, true) => writeln!(w, "f {a}//{a} {b}//{b} {c}//{c}"),
                (false, false) => writeln!(w, "f {a} {b} {c}"),
            }
            .map_err(io)?;
        }
        Ok(())
    })
}
