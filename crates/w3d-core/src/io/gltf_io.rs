//! glTF 2.0: reading `.gltf` / `.glb`, writing self-contained `.glb`.

use std::io::Write;
use std::path::Path;

use glam::{Mat3, Mat4, Vec3};
use serde_json::json;

use crate::image::{Image, linear_to_srgb, srgb_to_linear};
use crate::io::write_atomic;
use crate::{Error, Mesh, Result};

/// Reads every triangle primitive of the default scene (or of all scenes' nodes if no
/// default is set) with node transforms applied, concatenated into one mesh. Normals,
/// the first uv set (v flipped to the OBJ convention), `COLOR_0` (converted to sRGB) and
/// the first primitive's base-colour texture are kept when every primitive has them.
pub fn read_gltf(path: impl AsRef<Path>) -> Result<Mesh> {
    let path = path.as_ref();
    std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let imported = gltf::import(path).map_err(|e| match e {
        gltf::Error::Io(io) => Error::io(path, io),
        other => Error::format(path, "glTF data", format!("a valid glTF 2.0 file ({other})")),
    })?;
    mesh_from_document(path, imported)
}

/// Reads a self-contained `.glb` (or `.gltf` with data-URI buffers and images) from memory,
/// as [`read_gltf`] reads a file: for meshes embedded in a program (`include_bytes!`) or
/// received over a network. `name` stands for the file in error messages.
///
/// ```
/// let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../wonder3d/assets/spot.glb"))?;
/// let spot = w3d_core::io::read_glb_bytes("spot.glb", &bytes)?;
/// assert!(spot.texture().is_some());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn read_glb_bytes(name: impl AsRef<Path>, bytes: &[u8]) -> Result<Mesh> {
    let name = name.as_ref();
    let imported = gltf::import_slice(bytes)
        .map_err(|e| Error::format(name, "glTF data", format!("a valid self-contained glTF 2.0 binary ({e})")))?;
    mesh_from_document(name, imported)
}

/// The mesh of an imported glTF document (see [`read_gltf`]); `path` names it in errors.
fn mesh_from_document(
    path: &Path,
    (doc, buffers, images): (gltf::Document, Vec<gltf::buffer::Data>, Vec<gltf::image::Data>),
) -> Result<Mesh> {
    let mut acc = Accumulator::default();
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => scene.nodes().collect(),
        None => doc.nodes().collect(),
    };
    let mut stack: Vec<(gltf::Node, Mat4)> = roots.into_iter().map(|n| (n, Mat4::IDENTITY)).collect();
    while let Some((node, parent)) = stack.pop() {
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            for (p, primitive) in mesh.primitives().enumerate() {
                if primitive.mode() != gltf::mesh::Mode::Triangles {
                    continue;
                }
                acc.add(
                    path,
                    &primitive,
                    &buffers,
                    &images,
                    world,
                    &format!("meshes[{}].primitives[{p}]", mesh.index()),
                )?;
            }
        }
        stack.extend(node.children().map(|c| (c, world)));
    }
    acc.finish(path)
}

#[derive(Default)]
struct Accumulator {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    uvs: Option<Vec<[f32; 2]>>,
    colours: Option<Vec<[f32; 3]>>,
    texture: Option<Image>,
    primitives: usize,
}

impl Accumulator {
    fn add(
        &mut self,
        path: &Path,
        primitive: &gltf::Primitive,
        buffers: &[gltf::buffer::Data],
        images: &[gltf::image::Data],
        world: Mat4,
        field: &str,
    ) -> Result<()> {
        let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or_else(|| Error::format(path, format!("{field}.attributes"), "a POSITION accessor"))?
            .map(|p| world.transform_point3(Vec3::from(p)).to_array())
            .collect();
        let n = positions.len() as u32;
        let base = self.positions.len() as u32;
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..n).collect(),
        };
        if !indices.len().is_multiple_of(3) {
            return Err(Error::format(path, format!("{field}.indices"), "a multiple of 3 indices for triangles"));
        }
        for (k, t) in indices.chunks_exact(3).enumerate() {
            if t.iter().any(|&i| i >= n) {
                return Err(Error::format(path, format!("{field}.indices[{}]", 3 * k), format!("indices below {n}")));
            }
            self.triangles.push([t[0] + base, t[1] + base, t[2] + base]);
        }
        let first = self.primitives == 0;
        let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
        let normals = reader
            .read_normals()
            .map(|it| it.map(|v| (normal_matrix * Vec3::from(v)).normalize_or_zero().to_array()).collect::<Vec<_>>());
        merge(&mut self.normals, normals, first);
        let uvs = reader.read_tex_coords(0).map(|t| t.into_f32().map(|[u, v]| [u, 1.0 - v]).collect::<Vec<_>>());
        merge(&mut self.uvs, uvs, first);
        let colours = reader
            .read_colors(0)
            .map(|c| c.into_rgb_f32().map(|rgb| rgb.map(|v| linear_to_srgb(v.clamp(0.0, 1.0)))).collect::<Vec<_>>());
        merge(&mut self.colours, colours, first);
        if first && let Some(info) = primitive.material().pbr_metallic_roughness().base_color_texture() {
            let data = &images[info.texture().source().index()];
            self.texture = Some(decode_image(path, data)?);
        }
        self.positions.extend(positions);
        self.primitives += 1;
        Ok(())
    }

    fn finish(self, path: &Path) -> Result<Mesh> {
        let mut mesh = Mesh::new(self.positions, self.triangles).map_err(|e| e.in_file(path))?;
        if let Some(n) = self.normals {
            mesh = mesh.with_normals(n).map_err(|e| e.in_file(path))?;
        }
        if let Some(c) = self.colours {
            mesh = mesh.with_colours(c).map_err(|e| e.in_file(path))?;
        }
        if let Some(t) = self.uvs {
            mesh = mesh.with_uvs(t).map_err(|e| e.in_file(path))?;
            if let Some(texture) = self.texture {
                mesh = mesh.with_texture(texture).map_err(|e| e.in_file(path))?;
            }
        }
        Ok(mesh)
    }
}

/// Keeps an attribute only while every primitive has it.
fn merge<T>(acc: &mut Option<Vec<T>>, new: Option<Vec<T>>, first: bool) {
    match (acc.as_mut(), new) {
        (Some(a), Some(n)) => a.extend(n),
        (None, Some(n)) if first => *acc = Some(n),
        _ => *acc = None,
    }
}

fn decode_image(path: &Path, data: &gltf::image::Data) -> Result<Image> {
    use gltf::image::Format;
    let (channels, bytes_per) = match data.format {
        Format::R8G8B8 => (3, 1),
        Format::R8G8B8A8 => (4, 1),
        Format::R16G16B16 => (3, 2),
        Format::R16G16B16A16 => (4, 2),
        other => {
            return Err(Error::format(path, "base-colour texture", format!("an 8/16-bit RGB(A) image, got {other:?}")));
        }
    };
    let values: Vec<f32> = if bytes_per == 1 {
        data.pixels.iter().map(|&v| v as f32 / 255.0).collect()
    } else {
        data.pixels.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0).collect()
    };
    Image::new(data.width, data.height, channels, values).map_err(|e| e.in_file(path))
}

/// Builds the binary chunk of a GLB, keeping every buffer view 4-byte aligned.
#[derive(Default)]
struct BinBuilder {
    bytes: Vec<u8>,
    views: Vec<serde_json::Value>,
    accessors: Vec<serde_json::Value>,
}

impl BinBuilder {
    fn view(&mut self, data: &[u8], target: Option<u32>) -> usize {
        let offset = self.bytes.len();
        self.bytes.extend_from_slice(data);
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
        let mut view = json!({ "buffer": 0, "byteOffset": offset, "byteLength": data.len() });
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        self.views.push(view);
        self.views.len() - 1
    }

    /// A float accessor of `N`-component vectors (`type_name` VEC2 / VEC3).
    fn float_accessor<const N: usize>(&mut self, values: &[[f32; N]], type_name: &str, bounds: bool) -> usize {
        let bytes: Vec<u8> = values.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(34962));
        let mut acc = json!({ "bufferView": view, "componentType": 5126, "count": values.len(), "type": type_name });
        if bounds {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for v in values {
                for k in 0..N {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
            acc["min"] = json!(lo.to_vec());
            acc["max"] = json!(hi.to_vec());
        }
        self.accessors.push(acc);
        self.accessors.len() - 1
    }
}

/// Writes a self-contained binary glTF 2.0 file: positions, normals (computed when the
/// mesh has none), uvs (v flipped to glTF's top-left origin), `COLOR_0` (linear) from
/// vertex colours, u32 indices, and the texture embedded as PNG as the material's base
/// colour. Written atomically.
pub fn write_glb(path: impl AsRef<Path>, mesh: &Mesh) -> Result<()> {
    let path = path.as_ref();
    let glb = encode_glb(mesh)?;
    write_atomic(path, |w| w.write_all(&glb).map_err(|e| Error::io(path, e)))
}

/// Encodes a mesh as GLB bytes (see [`write_glb`]).
pub(crate) fn encode_glb(mesh: &Mesh) -> Result<Vec<u8>> {
    let mut bin = BinBuilder::default();
    let index_bytes: Vec<u8> = mesh.triangles().iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    let index_view = bin.view(&index_bytes, Some(34963));
    bin.accessors.push(json!({
        "bufferView": index_view, "componentType": 5125, "count": mesh.triangle_count() * 3, "type": "SCALAR"
    }));
    let mut attributes = serde_json::Map::new();
    attributes.insert("POSITION".into(), json!(bin.float_accessor(mesh.positions(), "VEC3", true)));
    let computed;
    let normals = match mesh.normals() {
        Some(n) => n,
        None => {
            computed = mesh.vertex_normals();
            &computed
        }
    };
    // glTF requires unit normals; vertices without faces get +y rather than a zero vector.
    let normals: Vec<[f32; 3]> =
        normals.iter().map(|n| Vec3::from(*n).try_normalize().unwrap_or(Vec3::Y).to_array()).collect();
    attributes.insert("NORMAL".into(), json!(bin.float_accessor(&normals, "VEC3", false)));
    if let Some(uvs) = mesh.uvs() {
        let flipped: Vec<[f32; 2]> = uvs.iter().map(|[u, v]| [*u, 1.0 - v]).collect();
        attributes.insert("TEXCOORD_0".into(), json!(bin.float_accessor(&flipped, "VEC2", false)));
    }
    if let Some(colours) = mesh.colours() {
        let linear: Vec<[f32; 3]> = colours.iter().map(|c| c.map(|v| srgb_to_linear(v.clamp(0.0, 1.0)))).collect();
        attributes.insert("COLOR_0".into(), json!(bin.float_accessor(&linear, "VEC3", false)));
    }
    let mut root = json!({
        "asset": { "version": "2.0", "generator": concat!("wonder3d-rs ", env!("CARGO_PKG_VERSION")) },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": [{ "attributes": attributes, "indices": 0, "material": 0, "mode": 4 }] }],
    });
    let mut material =
        json!({ "pbrMetallicRoughness": { "metallicFactor": 0.0, "roughnessFactor": 1.0 }, "doubleSided": false });
    if let (Some(texture), Some(_)) = (mesh.texture(), mesh.uvs()) {
        let png = texture.encode_png()?;
        let view = bin.view(&png, None);
        root["images"] = json!([{ "bufferView": view, "mimeType": "image/png" }]);
        root["samplers"] = json!([{ "magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497 }]);
        root["textures"] = json!([{ "sampler": 0, "source": 0 }]);
        material["pbrMetallicRoughness"]["baseColorTexture"] = json!({ "index": 0 });
    }
    root["materials"] = json!([material]);
    root["bufferViews"] = json!(bin.views);
    root["accessors"] = json!(bin.accessors);
    root["buffers"] = json!([{ "byteLength": bin.bytes.len() }]);

    let mut json_bytes = serde_json::to_vec(&root).expect("glTF JSON always serialises");
    while !json_bytes.len().is_multiple_of(4) {
        json_bytes.push(b' ');
    }
    let total = 12 + 8 + json_bytes.len() + 8 + bin.bytes.len();
    let total32 = u32::try_from(total).map_err(|_| Error::invalid("mesh", "a GLB smaller than 4 GiB"))?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json_bytes);
    out.extend_from_slice(&(bin.bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin.bytes);
    Ok(out)
}
