//! The campaign's inputs: valid seed files of every format `wonder3d` reads (made in
//! `target/hostile/inputs`), and the byte-level builders and damages the cases apply to them.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::{Value, json};

/// The unit cube's corners.
pub(crate) const CUBE_POSITIONS: [[f32; 3]; 8] = [
    [-0.5, -0.5, -0.5],
    [0.5, -0.5, -0.5],
    [0.5, 0.5, -0.5],
    [-0.5, 0.5, -0.5],
    [-0.5, -0.5, 0.5],
    [0.5, -0.5, 0.5],
    [0.5, 0.5, 0.5],
    [-0.5, 0.5, 0.5],
];

/// The unit cube's triangles, wound outward (0-based).
pub(crate) const CUBE_TRIANGLES: [[u32; 3]; 12] = [
    [0, 2, 1],
    [0, 3, 2],
    [4, 5, 6],
    [4, 6, 7],
    [0, 1, 5],
    [0, 5, 4],
    [3, 7, 6],
    [3, 6, 2],
    [0, 4, 7],
    [0, 7, 3],
    [1, 2, 6],
    [1, 6, 5],
];

/// The valid seed files and folders every case starts from.
#[derive(Clone, Debug)]
pub(crate) struct Seeds {
    /// `target/hostile/inputs`.
    pub dir: PathBuf,
    /// The cube as OBJ.
    pub cube_obj: PathBuf,
    /// The cube as ASCII PLY.
    pub cube_ply_ascii: PathBuf,
    /// The cube as binary little-endian PLY.
    pub cube_ply: PathBuf,
    /// The cube as GLB.
    pub cube_glb: PathBuf,
    /// The cube as glTF with its buffer in a base64 data URI.
    pub cube_gltf: PathBuf,
    /// The bundled torus (a smooth closed mesh of genus 1).
    pub torus: PathBuf,
    /// Oracle views of the cube at 32² (`wonder3d render`), with the file list.
    pub views: PathBuf,
    /// An RGBA PNG: an opaque disc on a transparent background.
    pub disc_png: PathBuf,
    /// The disc as lossless RGBA WebP.
    pub disc_webp: PathBuf,
    /// A photo without alpha: the disc on a grey, lightly textured background (JPEG).
    pub photo_jpg: PathBuf,
    /// The disc as a 16-bit RGBA PNG.
    pub disc16_png: PathBuf,
    /// A copy of the tiny random-weight checkpoint (32² images).
    pub tiny: PathBuf,
    /// A copy of the shipped small model (`assets/model-small`).
    pub small: PathBuf,
    /// A training set of the cube at the tiny model's 32² (`wonder3d dataset`, one sample).
    pub dataset: PathBuf,
    /// A batch manifest with one item: the view folder.
    pub manifest: PathBuf,
    /// A batch manifest with one item: the RGBA image (needs `--weights`).
    pub manifest_image: PathBuf,
    /// A regular file (for paths under a file).
    pub file: PathBuf,
}

impl Seeds {
    /// The seeds' paths in `dir` (nothing is made).
    pub(crate) fn at(dir: &Path) -> Seeds {
        let p = |s: &str| dir.join(s);
        Seeds {
            dir: dir.to_path_buf(),
            cube_obj: p("cube.obj"),
            cube_ply_ascii: p("cube_ascii.ply"),
            cube_ply: p("cube.ply"),
            cube_glb: p("cube.glb"),
            cube_gltf: p("cube.gltf"),
            torus: p("torus.obj"),
            views: p("views"),
            disc_png: p("disc.png"),
            disc_webp: p("disc.webp"),
            photo_jpg: p("photo.jpg"),
            disc16_png: p("disc16.png"),
            tiny: p("tiny"),
            small: p("small"),
            dataset: p("dataset"),
            manifest: p("items.txt"),
            manifest_image: p("images.txt"),
            file: p("file.txt"),
        }
    }

    /// Makes every seed, using `bin` (the `wonder3d` binary) for the view folder and the
    /// training set; `root` is the workspace.
    pub(crate) fn make(&self, bin: &Path, root: &Path) -> Result<(), String> {
        std::fs::create_dir_all(&self.dir).map_err(|e| format!("{}: {e}", self.dir.display()))?;
        let write = |p: &Path, bytes: &[u8]| std::fs::write(p, bytes).map_err(|e| format!("{}: {e}", p.display()));
        let (pos, tri) = (&CUBE_POSITIONS[..], &CUBE_TRIANGLES[..]);
        write(&self.cube_obj, obj(pos, tri).as_bytes())?;
        write(&self.cube_ply_ascii, ply_ascii(pos, tri).as_bytes())?;
        write(&self.cube_ply, &ply_binary(pos, tri))?;
        let (doc, bin_bytes) = gltf_cube();
        write(&self.cube_glb, &glb(doc.to_string().as_bytes(), &bin_bytes))?;
        write(&self.cube_gltf, gltf_embedded(doc, &bin_bytes).to_string().as_bytes())?;
        write(&self.file, b"a regular file\n")?;
        let copy = |from: &Path, to: &Path| super::case::copy_recursive(from, to);
        copy(&root.join("assets/torus.obj"), &self.torus)?;
        copy(&root.join("crates/w3d-diffusion/tests/fixtures/wonder3d_tiny"), &self.tiny)?;
        copy(&root.join("assets/model-small"), &self.small)?;
        write(&self.disc_png, &disc_png())?;
        let rgba = disc_rgba(48, 40, false);
        write(&self.disc_webp, &encode(&rgba, image::ImageFormat::WebP)?)?;
        let photo = image::DynamicImage::ImageRgba8(disc_rgba(64, 64, true)).to_rgb8();
        write(&self.photo_jpg, &encode(&image::DynamicImage::ImageRgb8(photo), image::ImageFormat::Jpeg)?)?;
        let sixteen = image::DynamicImage::ImageRgba8(rgba).to_rgba16();
        write(&self.disc16_png, &encode(&image::DynamicImage::ImageRgba16(sixteen), image::ImageFormat::Png)?)?;
        let wonder3d = |args: &[&str]| -> Result<(), String> {
            let out = Command::new(bin).args(args).output().map_err(|e| format!("{}: {e}", bin.display()))?;
            if out.status.success() {
                Ok(())
            } else {
                Err(format!("seed `wonder3d {}` failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr)))
            }
        };
        let s = |p: &Path| p.to_string_lossy().into_owned();
        wonder3d(&["render", &s(&self.cube_obj), "--size", "32", "--out", &s(&self.views)])?;
        let data = ["dataset", &s(&self.cube_obj), "--size", "32", "--samples", "1", "--quiet", "--out"];
        wonder3d(&[&data[..], &[&s(&self.dataset)]].concat())?;
        write(&self.manifest, b"views\n")?;
        write(&self.manifest_image, b"disc.png\n")?;
        Ok(())
    }
}

/// An OBJ file of the triangles (1-based indices).
pub(crate) fn obj(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> String {
    let mut s = String::new();
    for p in positions {
        s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    for t in triangles {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

/// An ASCII PLY file of the triangles.
pub(crate) fn ply_ascii(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        positions.len(),
        triangles.len()
    );
    for p in positions {
        s += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    for t in triangles {
        s += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    s
}

/// The header of a binary little-endian PLY with `vertices` float xyz rows and `faces`
/// `uchar`-counted `int` index lists (the counts as text, so that absurd claims fit).
pub(crate) fn ply_binary_header(vertices: &str, faces: &str) -> String {
    format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {vertices}\nproperty float x\nproperty float y\n\
         property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
}

/// The body of a binary PLY of the triangles (after [`ply_binary_header`]).
pub(crate) fn ply_binary_body(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<u8> {
    let mut b = Vec::new();
    for p in positions {
        for c in p {
            b.extend(c.to_le_bytes());
        }
    }
    for t in triangles {
        b.push(3);
        for i in t {
            b.extend(i.to_le_bytes());
        }
    }
    b
}

/// A binary little-endian PLY file of the triangles.
pub(crate) fn ply_binary(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<u8> {
    let header = ply_binary_header(&positions.len().to_string(), &triangles.len().to_string());
    [header.into_bytes(), ply_binary_body(positions, triangles)].concat()
}

/// The cube's glTF document (buffer 0 without a `uri`, as in a GLB) and its binary buffer:
/// positions (`f32` × 3 × 8) then indices (`u32` × 36).
pub(crate) fn gltf_cube() -> (Value, Vec<u8>) {
    let mut bin = Vec::new();
    for p in CUBE_POSITIONS {
        for c in p {
            bin.extend(c.to_le_bytes());
        }
    }
    let positions_len = bin.len();
    for t in CUBE_TRIANGLES {
        for i in t {
            bin.extend(i.to_le_bytes());
        }
    }
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3",
             "min": [-0.5, -0.5, -0.5], "max": [0.5, 0.5, 0.5]},
            {"bufferView": 1, "componentType": 5125, "count": 36, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions_len},
            {"buffer": 0, "byteOffset": positions_len, "byteLength": bin.len() - positions_len}
        ],
        "buffers": [{"byteLength": bin.len()}]
    });
    (doc, bin)
}

/// The document with its buffer embedded as a base64 data URI (a self-contained `.gltf`).
pub(crate) fn gltf_embedded(mut doc: Value, bin: &[u8]) -> Value {
    doc["buffers"][0]["uri"] = format!("data:application/octet-stream;base64,{}", base64(bin)).into();
    doc
}

/// A GLB container of a JSON chunk and a BIN chunk (both padded to 4 bytes).
pub(crate) fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let mut j = json.to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = Vec::with_capacity(total);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(j);
    out.extend((b.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(b);
    out
}

/// Standard base64 with padding.
pub(crate) fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for chunk in bytes.chunks(3) {
        let n = chunk.iter().enumerate().fold(0u32, |n, (i, &b)| n | (b as u32) << (16 - 8 * i));
        for i in 0..4 {
            if i <= chunk.len() {
                s.push(ALPHABET[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// CRC-32 (IEEE) as PNG chunks use it.
pub(crate) fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xffff_ffffu32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xedb8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

/// A PNG whose IHDR is replaced: `width × height` (the image data left as it was; the
/// chunk's CRC recomputed so that only the claim is wrong).
pub(crate) fn png_with_size(png: &[u8], width: u32, height: u32) -> Vec<u8> {
    let mut out = png.to_vec();
    // Signature (8), IHDR length (4), "IHDR" (4), width, height, …, CRC after 13 data bytes.
    if out.len() >= 33 && &out[12..16] == b"IHDR" {
        out[16..20].copy_from_slice(&width.to_be_bytes());
        out[20..24].copy_from_slice(&height.to_be_bytes());
        let crc = crc32(&out[12..29]);
        out[29..33].copy_from_slice(&crc.to_be_bytes());
    }
    out
}

/// A JPEG whose first SOF0/SOF2 frame header claims `width × height`.
pub(crate) fn jpeg_with_size(jpeg: &[u8], width: u16, height: u16) -> Vec<u8> {
    let mut out = jpeg.to_vec();
    let at = out.windows(2).position(|w| w[0] == 0xff && (w[1] == 0xc0 || w[1] == 0xc2));
    if let Some(i) = at.filter(|i| i + 9 <= out.len()) {
        // FF C0, length (2), precision (1), height (2), width (2).
        out[i + 5..i + 7].copy_from_slice(&height.to_be_bytes());
        out[i + 7..i + 9].copy_from_slice(&width.to_be_bytes());
    }
    out
}

/// A lossless WebP whose VP8L header claims `width × height` (each at most 16384).
pub(crate) fn webp_with_size(webp: &[u8], width: u32, height: u32) -> Vec<u8> {
    let mut out = webp.to_vec();
    if let Some(i) = out.windows(4).position(|w| w == b"VP8L").filter(|i| i + 13 <= out.len()) {
        // "VP8L", chunk size (4), signature 0x2f, then 14 bits width-1, 14 bits height-1, …
        let rest = u32::from_le_bytes([out[i + 9], out[i + 10], out[i + 11], out[i + 12]]) & 0xf000_0000;
        let bits = ((width - 1) & 0x3fff) | ((height - 1) & 0x3fff) << 14 | rest;
        out[i + 9..i + 13].copy_from_slice(&bits.to_le_bytes());
    }
    out
}

/// An OpenEXR file whose data and display windows claim `side × side` pixels.
pub(crate) fn exr_with_window(exr: &[u8], side: i32) -> Vec<u8> {
    let mut out = exr.to_vec();
    for key in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
        if let Some(i) = out.windows(key.len()).position(|w| w == key) {
            let at = i + key.len() + 4 + 8; // size (4), xmin, ymin, then xmax, ymax
            if at + 8 <= out.len() {
                out[at..at + 4].copy_from_slice(&(side - 1).to_le_bytes());
                out[at + 4..at + 8].copy_from_slice(&(side - 1).to_le_bytes());
            }
        }
    }
    out
}

/// An OpenEXR file whose `chunkCount` attribute claims `count` chunks (the offset table the
/// reader would allocate).
pub(crate) fn exr_with_chunk_count(exr: &[u8], count: i32) -> Vec<u8> {
    let mut out = exr.to_vec();
    let key = b"chunkCount\0int\0";
    if let Some(i) = out.windows(key.len()).position(|w| w == key) {
        let at = i + key.len() + 4;
        if at + 4 <= out.len() {
            out[at..at + 4].copy_from_slice(&count.to_le_bytes());
        }
    }
    out
}

/// Deterministic junk bytes (xorshift).
pub(crate) fn junk(len: usize, seed: u64) -> Vec<u8> {
    let mut x = seed | 1;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 24) as u8
        })
        .collect()
}

/// The first `num / den` of `bytes`.
pub(crate) fn cut(bytes: &[u8], num: usize, den: usize) -> Vec<u8> {
    bytes[..bytes.len() * num / den].to_vec()
}

/// A safetensors file with its values changed: the first value of tensor `key` set to NaN
/// (or +∞), in the tensor's own dtype; `None` when the key or its dtype is not found.
pub(crate) fn safetensors_poison(bytes: &[u8], key: Option<&str>, infinite: bool) -> Option<Vec<u8>> {
    let n = u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?) as usize;
    let header: Value = serde_json::from_slice(bytes.get(8..8 + n)?).ok()?;
    let map = header.as_object()?;
    let (_, entry) = match key {
        Some(k) => (k, map.get(k)?),
        None => map.iter().find(|(k, _)| *k != "__metadata__").map(|(k, v)| (k.as_str(), v))?,
    };
    let start = 8 + n + entry["data_offsets"][0].as_u64()? as usize;
    let value: Vec<u8> = match (entry["dtype"].as_str()?, infinite) {
        ("F16", false) => 0x7e00u16.to_le_bytes().to_vec(),
        ("F16", true) => 0x7c00u16.to_le_bytes().to_vec(),
        ("BF16", false) => 0x7fc0u16.to_le_bytes().to_vec(),
        ("BF16", true) => 0x7f80u16.to_le_bytes().to_vec(),
        ("F32", false) => f32::NAN.to_le_bytes().to_vec(),
        ("F32", true) => f32::INFINITY.to_le_bytes().to_vec(),
        _ => return None,
    };
    let mut out = bytes.to_vec();
    out.get_mut(start..start + value.len())?.copy_from_slice(&value);
    Some(out)
}

/// The first tensor name of a safetensors file.
pub(crate) fn safetensors_first_key(bytes: &[u8]) -> Option<String> {
    let n = u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?) as usize;
    let header: Value = serde_json::from_slice(bytes.get(8..8 + n)?).ok()?;
    header.as_object()?.keys().find(|k| *k != "__metadata__").cloned()
}

/// A safetensors file whose header is edited by `edit` (the JSON re-serialised, the length
/// prefix updated).
pub(crate) fn safetensors_edit(bytes: &[u8], edit: impl FnOnce(&mut Value)) -> Option<Vec<u8>> {
    let n = u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?) as usize;
    let mut header: Value = serde_json::from_slice(bytes.get(8..8 + n)?).ok()?;
    edit(&mut header);
    let mut text = header.to_string().into_bytes();
    while !text.len().is_multiple_of(8) {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend(&bytes[8 + n..]);
    Some(out)
}

/// An RGBA disc (opaque, shaded left to right) on a transparent background, or, with
/// `photo`, on an opaque grey background with a faint texture.
fn disc_rgba(w: u32, h: u32, photo: bool) -> image::RgbaImage {
    let (cx, cy, r) = (w as f32 / 2.0, h as f32 / 2.0, w.min(h) as f32 * 0.35);
    image::RgbaImage::from_fn(w, h, |x, y| {
        let (dx, dy) = (x as f32 - cx, y as f32 - cy);
        if dx * dx + dy * dy < r * r {
            image::Rgba([(80.0 + 150.0 * x as f32 / w as f32) as u8, 128, 180, 255])
        } else if photo {
            let g = 200 + ((x * 7 + y * 13) % 9) as u8;
            image::Rgba([g, g, g, 255])
        } else {
            image::Rgba([0, 0, 0, 0])
        }
    })
}

/// The RGBA disc as an 8-bit PNG.
fn disc_png() -> Vec<u8> {
    encode(&disc_rgba(48, 40, false), image::ImageFormat::Png).unwrap_or_default()
}

/// An image encoded in memory.
fn encode(img: &(impl Into<image::DynamicImage> + Clone), format: image::ImageFormat) -> Result<Vec<u8>, String> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.clone().into().write_to(&mut out, format).map_err(|e| format!("encoding a {format:?} seed: {e}"))?;
    Ok(out.into_inner())
}
