//! Stanford PLY (ascii, binary little- and big-endian).

use std::io::Write;
use std::path::Path;

use crate::error::{Error, Result};
use crate::files::write_atomic;
use crate::mesh::Mesh;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Debug, Clone)]
struct Property {
    name: String,
    /// `Some(count type)` for list properties.
    list: Option<Scalar>,
    value: Scalar,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

/// Reads values of one element after another from the body of a PLY file.
enum Body<'a> {
    Ascii { tokens: std::str::SplitAsciiWhitespace<'a> },
    Binary { bytes: &'a [u8], pos: usize, little: bool },
}

impl Body<'_> {
    fn read(&mut self, t: Scalar) -> Option<f64> {
        match self {
            Body::Ascii { tokens } => tokens.next()?.parse::<f64>().ok(),
            Body::Binary { bytes, pos, little } => {
                let n = t.size();
                let b = bytes.get(*pos..*pos + n)?;
                *pos += n;
                let mut a = [0u8; 8];
                a[..n].copy_from_slice(b);
                if !*little {
                    a[..n].reverse();
                }
                Some(match t {
                    Scalar::I8 => a[0] as i8 as f64,
                    Scalar::U8 => a[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::F64 => f64::from_le_bytes(a),
                })
            }
        }
    }
}

/// Reads a PLY mesh: the `vertex` element's `x y z` (and `nx ny nz`, `red green blue`,
/// `s t` / `u v` / `texture_u texture_v` when all are present) and the `face` element's
/// `vertex_indices` (or `vertex_index`) lists, fan-triangulated. Other elements and
/// properties are skipped.
pub fn read_ply(path: impl AsRef<Path>) -> Result<Mesh> {
    let path = path.as_ref();
    let bytes = crate::files::read_input(path)?;
    let bad = |field: &str, expected: &str| Error::format(path, field, expected);
    let header_end = find_header_end(&bytes).ok_or_else(|| bad("header", "a PLY header ending in `end_header`"))?;
    let header = std::str::from_utf8(&bytes[..header_end]).map_err(|_| bad("header", "ASCII header text"))?;
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(bad("line 1", "the magic word `ply`"));
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for (n, line) in lines.enumerate() {
        let line_no = format!("header line {}", n + 2);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, _version] => {
                encoding = Some(match *f {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Little,
                    "binary_big_endian" => Encoding::Big,
                    _ => return Err(bad(&line_no, "format ascii, binary_little_endian or binary_big_endian")),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count.parse().map_err(|_| bad(&line_no, "an element count"))?,
                properties: Vec::new(),
            }),
            ["property", "list", count_type, value_type, name] => {
                let (Some(c), Some(v)) = (Scalar::parse(count_type), Scalar::parse(value_type)) else {
                    return Err(bad(&line_no, "known list property types"));
                };
                elements
                    .last_mut()
                    .ok_or_else(|| bad(&line_no, "a property after an element"))?
                    .properties
                    .push(Property { name: name.to_string(), list: Some(c), value: v });
            }
            ["property", value_type, name] => {
                let v = Scalar::parse(value_type).ok_or_else(|| bad(&line_no, "a known property type"))?;
                elements
                    .last_mut()
                    .ok_or_else(|| bad(&line_no, "a property after an element"))?
                    .properties
                    .push(Property { name: name.to_string(), list: None, value: v });
            }
            ["comment", ..] | ["obj_info", ..] | ["end_header"] | [] => {}
            _ => return Err(bad(&line_no, "a format, element, property or comment line")),
        }
    }
    let encoding = encoding.ok_or_else(|| bad("header", "a `format` line"))?;
    let body_bytes = &bytes[header_end..];
    check_claimed_sizes(path, &elements, encoding, body_bytes.len())?;
    let mut body = match encoding {
        Encoding::Ascii => Body::Ascii {
            tokens: std::str::from_utf8(body_bytes).map_err(|_| bad("body", "ASCII numbers"))?.split_ascii_whitespace(),
        },
        Encoding::Little | Encoding::Big => {
            Body::Binary { bytes: body_bytes, pos: 0, little: encoding == Encoding::Little }
        }
    };

    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut normals: Vec<[f32; 3]> = Vec::new();
    let mut colours: Vec<[f32; 3]> = Vec::new();
    let mut uvs: Vec<[f32; 2]> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut values: Vec<f64> = Vec::new();
    for element in &elements {
        let find = |names: &[&str]| -> Option<Vec<usize>> {
            names.iter().map(|n| element.properties.iter().position(|p| p.name == *n && p.list.is_none())).collect()
        };
        let is_vertex = element.name == "vertex";
        let xyz = if is_vertex {
            Some(find(&["x", "y", "z"]).ok_or_else(|| bad("element vertex", "properties x, y and z"))?)
        } else {
            None
        };
        let nxyz = if is_vertex { find(&["nx", "ny", "nz"]) } else { None };
        let rgb = if is_vertex { find(&["red", "green", "blue"]) } else { None };
        let uv = if is_vertex {
            find(&["s", "t"]).or_else(|| find(&["u", "v"])).or_else(|| find(&["texture_u", "texture_v"]))
        } else {
            None
        };
        let face_list = (element.name == "face")
            .then(|| {
                element
                    .properties
                    .iter()
                    .position(|p| p.list.is_some() && (p.name == "vertex_indices" || p.name == "vertex_index"))
            })
            .flatten();
        for row in 0..element.count {
            let at = || format!("element {} row {row}", element.name);
            values.clear();
            let mut face: Vec<u32> = Vec::new();
            for (k, p) in element.properties.iter().enumerate() {
                match p.list {
                    None => values.push(
                        body.read(p.value).ok_or_else(|| bad(&at(), &format!("a value for property {}", p.name)))?,
                    ),
                    Some(count_type) => {
                        values.push(f64::NAN);
                        let count = body.read(count_type).ok_or_else(|| bad(&at(), "a list length"))?;
                        if !(count >= 0.0 && count.fract() == 0.0) {
                            return Err(bad(&at(), "a non-negative whole list length"));
                        }
                        for _ in 0..count as usize {
                            let v = body.read(p.value).ok_or_else(|| bad(&at(), &format!("{count} list values")))?;
                            if Some(k) == face_list {
                                if !(v >= 0.0 && v.fract() == 0.0 && v < u32::MAX as f64) {
                                    return Err(bad(&at(), &format!("non-negative whole vertex indices, got {v}")));
                                }
                                face.push(v as u32);
                            }
                        }
                    }
                }
            }
            if let Some(xyz) = &xyz {
                positions.push([values[xyz[0]] as f32, values[xyz[1]] as f32, values[xyz[2]] as f32]);
                if let Some(n) = &nxyz {
                    normals.push([values[n[0]] as f32, values[n[1]] as f32, values[n[2]] as f32]);
                }
                if let Some(c) = &rgb {
                    let scale = if element.properties[c[0]].value == Scalar::U8 { 1.0 / 255.0 } else { 1.0 };
                    colours.push([0, 1, 2].map(|i| (values[c[i]] * scale) as f32));
                }
                if let Some(t) = &uv {
                    uvs.push([values[t[0]] as f32, values[t[1]] as f32]);
                }
            }
            if face.len() >= 3 {
                for i in 1..face.len() - 1 {
                    triangles.push([face[0], face[i], face[i + 1]]);
                }
            }
        }
    }
    let mut mesh = Mesh::new(positions, triangles).map_err(|e| e.in_file(path))?;
    if !normals.is_empty() {
        mesh = mesh.with_normals(normals).map_err(|e| e.in_file(path))?;
    }
    if !colours.is_empty() {
        mesh = mesh.with_colours(colours).map_err(|e| e.in_file(path))?;
    }
    if !uvs.is_empty() {
        mesh = mesh.with_uvs(uvs).map_err(|e| e.in_file(path))?;
    }
    Ok(mesh)
}

/// Refuses element counts the body cannot hold, before reading any row (so a header that
/// claims 10¹⁸ rows fails at once instead of looping or allocating): an element with rows
/// needs properties, and the rows need at least `count × (smallest row)` bytes, the
/// smallest row being the fixed-size values plus the list lengths in binary files, and one
/// character and one separator per value in ascii files.
fn check_claimed_sizes(path: &Path, elements: &[Element], encoding: Encoding, body_len: usize) -> Result<()> {
    let mut needed: u128 = 0;
    for e in elements {
        if e.count > 0 && e.properties.is_empty() {
            return Err(Error::format(
                path,
                format!("element {}", e.name),
                format!("properties for its {} rows (a PLY element without properties can only have 0 rows)", e.count),
            ));
        }
        let row: usize = e
            .properties
            .iter()
            .map(|p| match (encoding, p.list) {
                (Encoding::Ascii, _) => 2,
                (_, Some(count)) => count.size(),
                (_, None) => p.value.size(),
            })
            .sum();
        let before = needed;
        needed += e.count as u128 * row as u128;
        // Ascii: the last value of the file needs no separator after it.
        let available = body_len as u128 + u128::from(encoding == Encoding::Ascii);
        if needed > available {
            // Binary rows have a known smallest size: name the first row that cannot fit.
            let field = match encoding {
                Encoding::Ascii => format!("element {}", e.name),
                _ => format!("element {} row {}", e.name, (available.saturating_sub(before)) / row.max(1) as u128),
            };
            return Err(Error::format(
                path,
                field,
                format!(
                    "at most as many rows as the file holds: {} rows need at least {needed} bytes with the \
                     elements before them, the body has {body_len} (a wrong count, or a truncated file)",
                    e.count
                ),
            ));
        }
    }
    Ok(())
}

/// Byte offset just past the `end_header` line.
fn find_header_end(bytes: &[u8]) -> Option<usize> {
    let key = b"end_header";
    let at = bytes.windows(key.len()).position(|w| w == key)?;
    let mut end = at + key.len();
    if bytes.get(end) == Some(&b'\r') {
        end += 1;
    }
    (bytes.get(end) == Some(&b'\n')).then_some(end + 1)
}

/// Writes a binary little-endian PLY with positions, normals, uvs (`s t`) and colours
/// (`red green blue` as uchar) when present, and triangles as `vertex_indices`.
pub fn write_ply(path: impl AsRef<Path>, mesh: &Mesh) -> Result<()> {
    let path = path.as_ref();
    write_atomic(path, |w| {
        let io = |e| Error::io(path, e);
        let mut header = format!(
            "ply\nformat binary_little_endian 1.0\ncomment written by wonder3d-rs\nelement vertex {}\n",
            mesh.vertex_count()
        );
        header += "property float x\nproperty float y\nproperty float z\n";
        if mesh.normals().is_some() {
            header += "property float nx\nproperty float ny\nproperty float nz\n";
        }
        if mesh.uvs().is_some() {
            header += "property float s\nproperty float t\n";
        }
        if mesh.colours().is_some() {
            header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
        }
        header +=
            &format!("element face {}\nproperty list uchar uint vertex_indices\nend_header\n", mesh.triangle_count());
        w.write_all(header.as_bytes()).map_err(io)?;
        for i in 0..mesh.vertex_count() {
            let mut floats: Vec<f32> = mesh.positions()[i].to_vec();
            if let Some(n) = mesh.normals() {
                floats.extend(n[i]);
            }
            if let Some(t) = mesh.uvs() {
                floats.extend(t[i]);
            }
            for f in floats {
                w.write_all(&f.to_le_bytes()).map_err(io)?;
            }
            if let Some(c) = mesh.colours() {
                w.write_all(&c[i].map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8)).map_err(io)?;
            }
        }
        for t in mesh.triangles() {
            w.write_all(&[3u8]).map_err(io)?;
            for v in t {
                w.write_all(&v.to_le_bytes()).map_err(io)?;
            }
        }
        Ok(())
    })
}
