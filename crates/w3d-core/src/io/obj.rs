//! Wavefront OBJ + MTL.

use std::io::Write;
use std::path::Path;

use crate::error::{Error, Result};
use crate::files::write_atomic_all;
use crate::image::Image;
use crate::mesh::Mesh;

/// Reads an OBJ file (all objects/groups concatenated, polygons fan-triangulated) with
/// its normals, texture coordinates, vertex colours and — when the MTL gives one — the
/// diffuse texture (`map_Kd`) of the first material that has it.
///
/// Vertices are split where normals or uvs differ (one index buffer) and numbered in the
/// order the faces first use them, so reading an OBJ that this crate wrote gives back the
/// same vertex order; other files may be renumbered (the geometry is the same). A `mtllib` that
/// cannot be read, or a `map_Kd` texture that is missing, is an error naming that file.
///
/// Before parsing, every line is checked, so a face that names a vertex the file does not
/// have, a record cut short (the usual trace of a truncated file: a face of fewer than 3
/// vertices or of mixed forms like `3/3` after `1/1/1`, a vertex with too few numbers), a
/// missing `mtllib` file or a file with vertices but no faces is an error naming the line or
/// the file rather than a partial mesh. A cut between two lines, or inside the last number
/// of a line, leaves a valid shorter file and cannot be detected (OBJ has no counts).
pub fn read_obj(path: impl AsRef<Path>) -> Result<Mesh> {
    let path = path.as_ref();
    let bytes = crate::files::read_input(path)?;
    let scan = check_obj_text(path, &String::from_utf8_lossy(&bytes))?;
    drop(bytes);
    let options = tobj::LoadOptions { single_index: true, triangulate: true, ignore_points: true, ignore_lines: true };
    let (models, materials) = tobj::load_obj(path, &options)
        .map_err(|e| Error::format(path, "OBJ data", format!("a valid OBJ file ({e})")))?;
    let materials = materials.map_err(|e| {
        Error::format(path, "mtllib", format!("a readable MTL file ({}: {e})", scan.mtllibs.join(", ")))
    })?;

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

/// What [`check_obj_text`] found.
struct ObjScan {
    /// The `mtllib` files, as paths beside the OBJ file.
    mtllibs: Vec<String>,
}

/// Checks the lines of an OBJ file before it is parsed, naming the line of the first
/// problem:
/// - `v` has 3 coordinates (4 with a weight, 6 or 7 with a colour), `vt` 1 to 3, `vn` 3,
///   all numbers;
/// - `f` has at least 3 vertices, all written in one form (`v`, `v/vt`, `v//vn` or
///   `v/vt/vn`), with indices that exist in the file (1 to the count of that kind, or
///   negative within the records before the line);
/// - every `mtllib` file exists beside the OBJ file;
/// - there is at least one face when there are vertices.
///
/// Most truncations show up here: a cut inside a face leaves fewer than 3 vertices or a
/// vertex of another form (`3/3` after `1/1/1`), a cut inside a vertex record leaves fewer
/// coordinates, and a cut before the faces leaves vertices without faces; the face indices
/// are then checked against the vertices that are really there. A cut that falls between
/// two lines, or inside the last number of a line (`0.123` becoming `0.12`, `145` becoming
/// `14`), leaves a valid shorter file and cannot be detected: OBJ has no counts or end
/// marker, and many exporters end the last line without a newline.
fn check_obj_text(path: &Path, text: &str) -> Result<ObjScan> {
    // Totals first: faces may legally name vertices defined further down.
    let (mut total_v, mut total_vt, mut total_vn) = (0i64, 0i64, 0i64);
    for line in text.lines() {
        match line.split_whitespace().next() {
            Some("v") => total_v += 1,
            Some("vt") => total_vt += 1,
            Some("vn") => total_vn += 1,
            _ => {}
        }
    }
    let (mut seen_v, mut seen_vt, mut seen_vn, mut faces) = (0i64, 0i64, 0i64, 0usize);
    let mut mtllibs = Vec::new();
    let base = path.parent().unwrap_or(Path::new("."));
    for (n, line) in text.lines().enumerate() {
        let at = || format!("line {}", n + 1);
        let line = line.split('#').next().unwrap_or("");
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else { continue };
        let rest: Vec<&str> = words.collect();
        let numbers = |allowed: &[usize], what: &str| -> Result<()> {
            if !allowed.contains(&rest.len()) || rest.iter().any(|w| w.parse::<f32>().is_err()) {
                return Err(Error::format(
                    path,
                    at(),
                    format!("{what}, got {:?} (a truncated or damaged file?)", line.trim()),
                ));
            }
            Ok(())
        };
        match keyword {
            "v" => {
                numbers(&[3, 4, 6, 7], "an OBJ vertex `v x y z` (optionally `w` or `r g b`) of numbers")?;
                seen_v += 1;
            }
            "vt" => {
                numbers(&[1, 2, 3], "an OBJ texture coordinate `vt u [v [w]]` of numbers")?;
                seen_vt += 1;
            }
            "vn" => {
                numbers(&[3], "an OBJ normal `vn x y z` of numbers")?;
                seen_vn += 1;
            }
            "f" => {
                check_face(path, &at(), &rest, [(seen_v, total_v), (seen_vt, total_vt), (seen_vn, total_vn)])?;
                faces += 1;
            }
            "mtllib" => {
                let name = line.trim_start()["mtllib".len()..].trim();
                let whole = base.join(name);
                // tobj takes the first word; accept either spelling when it exists.
                let first = rest.first().map(|w| base.join(w));
                if !whole.is_file() && !first.as_ref().is_some_and(|p| p.is_file()) {
                    return Err(Error::format(
                        path,
                        format!("{} mtllib", at()),
                        format!("an existing material file, {} is missing", whole.display()),
                    ));
                }
                mtllibs.push(whole.display().to_string());
            }
            _ => {}
        }
    }
    if faces == 0 {
        let what = if total_v == 0 {
            "no vertices and no faces".to_string()
        } else {
            format!("{total_v} vertices (`v` lines) and no faces")
        };
        return Err(Error::format(path, "faces", format!("at least one face (`f` line); the file has {what}")));
    }
    Ok(ObjScan { mtllibs })
}

/// Checks one face line's vertices (see [`check_obj_text`]); `counts` are `(seen so far,
/// total)` of `v`, `vt` and `vn`.
fn check_face(path: &Path, at: &str, refs: &[&str], counts: [(i64, i64); 3]) -> Result<()> {
    if refs.len() < 3 {
        return Err(Error::format(
            path,
            at,
            format!("a face of at least 3 vertices, got {} (a truncated or damaged file?)", refs.len()),
        ));
    }
    let form = |r: &str| -> Vec<bool> { r.split('/').map(|p| !p.is_empty()).collect() };
    let first = form(refs[0]);
    for r in refs {
        let parts: Vec<&str> = r.split('/').collect();
        if parts.len() > 3 || form(r) != first || parts[0].is_empty() {
            return Err(Error::format(
                path,
                at,
                format!(
                    "face vertices all of one form (`v`, `v/vt`, `v//vn` or `v/vt/vn`), got {r:?} after {:?} \
                     (a truncated or damaged file?)",
                    refs[0]
                ),
            ));
        }
        for ((part, (seen, total)), kind) in parts.iter().zip(counts).zip(["v", "vt", "vn"]) {
            if part.is_empty() {
                continue;
            }
            let ok = match part.parse::<i64>() {
                Ok(i) if i > 0 => i <= total,
                Ok(i) if i < 0 => -i <= seen,
                _ => false,
            };
            if !ok {
                return Err(Error::format(
                    path,
                    at,
                    format!(
                        "{kind} indices that exist (1..={total}, or -1..=-{seen} counting back), got {part:?} in {r:?} \
                         (a truncated or damaged file?)"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Writes an OBJ file (positions, uvs, normals, vertex colours as `v x y z r g b`).
/// A textured mesh also gets `<stem>.mtl` and `<stem>.png` beside it. All files are
/// encoded first, checked (no destination may be a folder) and then written together
/// ([`crate::io::write_atomic_all`]): a failure leaves every existing file as it was.
pub fn write_obj(path: impl AsRef<Path>, mesh: &Mesh) -> Result<()> {
    let path = path.as_ref();
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "mesh".into());
    let obj = encode_obj(mesh, &stem);
    match mesh.texture() {
        Some(texture) => {
            let png = texture.encode_png()?;
            let mtl = format!("newmtl material0\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {stem}.png\n");
            let png_path = path.with_file_name(format!("{stem}.png"));
            let mtl_path = path.with_file_name(format!("{stem}.mtl"));
            write_atomic_all(&[(&png_path, &png), (&mtl_path, mtl.as_bytes()), (path, &obj)])
        }
        None => write_atomic_all(&[(path, &obj)]),
    }
}

/// The OBJ text of `mesh`, naming `<stem>.mtl` when it has a texture.
fn encode_obj(mesh: &Mesh, stem: &str) -> Vec<u8> {
    let mut w = Vec::new();
    // Writing into a Vec cannot fail.
    let _ = (|| -> std::io::Result<()> {
        writeln!(w, "# written by wonder3d-rs")?;
        if mesh.texture().is_some() {
            writeln!(w, "mtllib {stem}.mtl\nusemtl material0")?;
        }
        for (i, p) in mesh.positions().iter().enumerate() {
            match mesh.colours() {
                Some(c) => writeln!(w, "v {} {} {} {} {} {}", p[0], p[1], p[2], c[i][0], c[i][1], c[i][2]),
                None => writeln!(w, "v {} {} {}", p[0], p[1], p[2]),
            }?;
        }
        for t in mesh.uvs().unwrap_or(&[]) {
            writeln!(w, "vt {} {}", t[0], t[1])?;
        }
        for n in mesh.normals().unwrap_or(&[]) {
            writeln!(w, "vn {} {} {}", n[0], n[1], n[2])?;
        }
        let (has_uv, has_n) = (mesh.uvs().is_some(), mesh.normals().is_some());
        for t in mesh.triangles() {
            let [a, b, c] = t.map(|i| i + 1);
            match (has_uv, has_n) {
                (true, true) => writeln!(w, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}"),
                (true, false) => writeln!(w, "f {a}/{a} {b}/{b} {c}/{c}"),
                (false, true) => writeln!(w, "f {a}//{a} {b}//{b} {c}//{c}"),
                (false, false) => writeln!(w, "f {a} {b} {c}"),
            }?;
        }
        Ok(())
    })();
    w
}
