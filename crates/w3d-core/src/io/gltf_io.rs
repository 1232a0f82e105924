//! glTF 2.0: reading `.gltf` / `.glb`, writing self-contained `.glb`.

use std::io::Write;
use std::path::Path;

use glam::{Mat3, Mat4, Vec3};
use serde_json::json;

use crate::error::{Error, Result};
use crate::files::write_atomic;
use crate::image::{Image, linear_to_srgb, srgb_to_linear};
use crate::mesh::Mesh;

/// Reads every triangle primitive of the default scene (or of all scenes' nodes if no
/// default is set) with node transforms applied, concatenated into one mesh. Normals,
/// the first uv set (v flipped to the OBJ convention), `COLOR_0` (converted to sRGB) and
/// the first primitive's base-colour texture are kept when every primitive has them.
pub fn read_gltf(path: impl AsRef<Path>) -> Result<Mesh> {
    let path = path.as_ref();
    let bytes = crate::files::read_input(path)?;
    let is_glb = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    import(path, &bytes, is_glb, Some(path.parent().unwrap_or(Path::new("."))))
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
    import(name, bytes, bytes.starts_with(b"glTF"), None)
}

/// Parses and checks a glTF document, loads its buffers and images (external files
/// relative to `base`; none when `base` is `None`) and builds the mesh. Before anything is
/// read through an accessor, the GLB container (when `glb`) and every byte range the
/// triangle primitives use are checked against the data really present, so a damaged file
/// is an error naming the part instead of a panic, a huge allocation or silently missing
/// data.
fn import(path: &Path, bytes: &[u8], glb: bool, base: Option<&Path>) -> Result<Mesh> {
    if bytes.is_empty() {
        return Err(Error::format(path, "file", "a glTF file, got an empty file"));
    }
    let json = if glb || bytes.starts_with(b"glTF") { check_glb_container(path, bytes)? } else { bytes };
    check_json_references(path, json)?;
    // The glTF crate still has panics on some malformed documents (unchecked indices,
    // `unwrap`s on optional fields); the checks above cover the known ones, and a panic
    // left is turned into an error here rather than taking the process down.
    let imported = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| -> Result<Mesh> {
        let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| {
            let what =
                if bytes.starts_with(b"glTF") { "a valid binary glTF 2.0 (GLB) file" } else { "valid glTF 2.0 JSON" };
            Error::format(path, "glTF data", format!("{what} ({e})"))
        })?;
        let gltf::Gltf { document, blob } = gltf;
        check_external_files(path, &document, base)?;
        let buffers = gltf::import_buffers(&document, base, blob).map_err(|e| gltf_error(path, "buffers", e))?;
        check_image_views(path, &document, &buffers)?;
        let images = gltf::import_images(&document, base, &buffers).map_err(|e| gltf_error(path, "images", e))?;
        mesh_from_document(path, (document, buffers, images))
    }));
    imported.unwrap_or_else(|_| {
        Err(Error::format(path, "glTF data", "a glTF 2.0 document the reader can process (it failed on this one)"))
    })
}

/// Checks the references of a glTF JSON document that the glTF crate follows without
/// checking (and panics on): every primitive attribute and index accessor must exist,
/// and every image must have a `uri` or a `bufferView` (with a `mimeType`) that exists.
/// The whole document must be valid JSON in UTF-8: the glTF crate skips the values of
/// unknown keys without checking them, so a damaged key (`"ac*essors"`) would hide its
/// damaged contents from the reader and leave the references to it dangling.
fn check_json_references(path: &Path, json: &[u8]) -> Result<()> {
    let root = serde_json::from_slice::<serde_json::Value>(json)
        .map_err(|e| Error::format(path, "glTF JSON", format!("valid JSON in UTF-8 ({e})")))?;
    let count = |key: &str| root.get(key).and_then(|v| v.as_array()).map_or(0, Vec::len);
    let (accessors, views) = (count("accessors"), count("bufferViews"));
    let index_below = |v: &serde_json::Value, n: usize| v.as_u64().is_some_and(|i| i < n as u64);
    let bad = |field: String, expected: String| Err(Error::format(path, field, expected));
    let empty = Vec::new();
    let list = |v: Option<&serde_json::Value>| v.and_then(|v| v.as_array()).unwrap_or(&empty).clone();
    for (m, mesh) in list(root.get("meshes")).iter().enumerate() {
        for (p, primitive) in list(mesh.get("primitives")).iter().enumerate() {
            let field = format!("meshes[{m}].primitives[{p}]");
            if let Some(attributes) = primitive.get("attributes").and_then(|a| a.as_object()) {
                for (name, index) in attributes {
                    if !index_below(index, accessors) {
                        return bad(
                            format!("{field}.attributes.{name}"),
                            format!("an accessor index below {accessors}, got {index}"),
                        );
                    }
                }
            }
            if let Some(index) = primitive.get("indices")
                && !index_below(index, accessors)
            {
                return bad(format!("{field}.indices"), format!("an accessor index below {accessors}, got {index}"));
            }
        }
    }
    for (i, image) in list(root.get("images")).iter().enumerate() {
        let field = format!("images[{i}]");
        match (image.get("uri"), image.get("bufferView")) {
            (Some(uri), None) if uri.is_string() => {}
            (None, Some(view)) => {
                if !index_below(view, views) {
                    return bad(format!("{field}.bufferView"), format!("a bufferView index below {views}, got {view}"));
                }
                if !image.get("mimeType").is_some_and(|m| m.is_string()) {
                    return bad(format!("{field}.mimeType"), "a mimeType for an image in a bufferView".into());
                }
            }
            _ => return bad(field, "either a uri or a bufferView".into()),
        }
    }
    Ok(())
}

fn gltf_error(path: &Path, field: &str, e: gltf::Error) -> Error {
    match e {
        gltf::Error::Io(io) => Error::io(path, io),
        other => Error::format(path, field, format!("data a glTF 2.0 reader can load ({other})")),
    }
}

/// The 12-byte GLB header and the chunk headers: magic `glTF`, version 2, the total length
/// equal to the file's, chunks inside the file.
fn check_glb_container<'a>(path: &Path, bytes: &'a [u8]) -> Result<&'a [u8]> {
    let bad = |field: &str, expected: String| Err(Error::format(path, field, expected));
    if bytes.len() < 12 {
        return bad("GLB header", format!("12 bytes (magic, version, length), got a {}-byte file", bytes.len()));
    }
    let word = |at: usize| u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    if &bytes[..4] != b"glTF" {
        return bad("GLB magic", format!("the bytes `glTF` that start a binary glTF file, got {:?}", &bytes[..4]));
    }
    if word(4) != 2 {
        return bad("GLB version", format!("2, got {}", word(4)));
    }
    if word(8) as usize != bytes.len() {
        return bad(
            "GLB length",
            format!("the file's size, {} bytes, got {} (a truncated or padded file)", bytes.len(), word(8)),
        );
    }
    let mut at = 12;
    let mut chunk = 0;
    let mut json: &[u8] = &[];
    while at < bytes.len() {
        if bytes.len() - at < 8 {
            return bad(
                &format!("GLB chunk {chunk}"),
                format!("an 8-byte chunk header, got {} bytes", bytes.len() - at),
            );
        }
        let len = word(at) as usize;
        if len > bytes.len() - at - 8 {
            return bad(
                &format!("GLB chunk {chunk}"),
                format!("a length within the file ({} bytes left), got {len}", bytes.len() - at - 8),
            );
        }
        if chunk == 0 {
            json = &bytes[at + 8..at + 8 + len];
        }
        at += 8 + len;
        chunk += 1;
    }
    if chunk == 0 {
        return bad("GLB chunks", "a JSON chunk after the header, got none".into());
    }
    Ok(json)
}

/// External buffers and images must be regular files (not a folder or a device that never
/// ends, such as `/dev/zero`), buffers at least as long as they claim.
fn check_external_files(path: &Path, document: &gltf::Document, base: Option<&Path>) -> Result<()> {
    let Some(base) = base else { return Ok(()) };
    let external = |uri: &str| -> Option<std::path::PathBuf> {
        let uri = uri.strip_prefix("file://").or_else(|| uri.strip_prefix("file:")).unwrap_or(uri);
        (!uri.starts_with("data:") && !uri.contains("://")).then(|| base.join(uri))
    };
    let check = |field: String, file: std::path::PathBuf, min_len: u64| -> Result<()> {
        // A name that does not resolve here (percent-encoded, say) is left to the reader.
        let Ok(meta) = std::fs::metadata(&file) else { return Ok(()) };
        if !meta.is_file() {
            return Err(Error::format(path, field, format!("a regular file, {} is not one", file.display())));
        }
        if meta.len() < min_len {
            return Err(Error::format(
                path,
                field,
                format!("{min_len} bytes in {}, it has {}", file.display(), meta.len()),
            ));
        }
        Ok(())
    };
    for buffer in document.buffers() {
        if let gltf::buffer::Source::Uri(uri) = buffer.source()
            && let Some(file) = external(uri)
        {
            check(format!("buffers[{}].uri", buffer.index()), file, buffer.length() as u64)?;
        }
    }
    for image in document.images() {
        if let gltf::image::Source::Uri { uri, .. } = image.source()
            && let Some(file) = external(uri)
        {
            check(format!("images[{}].uri", image.index()), file, 0)?;
        }
    }
    Ok(())
}

/// A buffer view's byte range, which must lie inside its loaded buffer.
fn view_range(
    path: &Path,
    view: &gltf::buffer::View,
    buffers: &[gltf::buffer::Data],
) -> Result<std::ops::Range<usize>> {
    let available = buffers.get(view.buffer().index()).map_or(0, |b| b.len());
    let start = view.offset();
    match start.checked_add(view.length()) {
        Some(end) if end <= available => Ok(start..end),
        _ => Err(Error::format(
            path,
            format!("bufferViews[{}]", view.index()),
            format!(
                "a byte range inside buffer {} ({available} bytes), got {} bytes from offset {start}",
                view.buffer().index(),
                view.length()
            ),
        )),
    }
}

/// Images stored in buffer views must lie inside their buffer (the glTF reader slices
/// them without checking).
fn check_image_views(path: &Path, document: &gltf::Document, buffers: &[gltf::buffer::Data]) -> Result<()> {
    for image in document.images() {
        if let gltf::image::Source::View { view, .. } = image.source() {
            view_range(path, &view, buffers)?;
        }
    }
    Ok(())
}

/// Checks that `accessor` can be read in full: it has a buffer view (or is sparse), and
/// `count` elements at its offset and stride fit inside that view, which fits inside its
/// buffer. The glTF reader silently returns nothing for an accessor that overruns its
/// view (an overlong index accessor was read as an unindexed triangle soup).
fn check_accessor(path: &Path, field: &str, accessor: &gltf::Accessor, buffers: &[gltf::buffer::Data]) -> Result<()> {
    let bad =
        |expected: String| Err(Error::format(path, format!("{field} (accessors[{}])", accessor.index()), expected));
    let (count, size) = (accessor.count(), accessor.size());
    if count == 0 {
        return bad("at least one element, got count 0".into());
    }
    match accessor.view() {
        Some(view) => {
            let range = view_range(path, &view, buffers)?;
            let stride = view.stride().unwrap_or(size);
            if stride < size {
                return bad(format!("a byteStride of at least the element size {size}, got {stride}"));
            }
            let needed = (count - 1)
                .checked_mul(stride)
                .and_then(|n| n.checked_add(size))
                .and_then(|n| n.checked_add(accessor.offset()));
            if needed.is_none_or(|n| n > range.len()) {
                return bad(format!(
                    "{count} elements of {size} bytes (stride {stride}) from offset {} inside bufferViews[{}] of {} \
                     bytes (an accessor longer than its view: a damaged or truncated file)",
                    accessor.offset(),
                    view.index(),
                    range.len()
                ));
            }
        }
        None if accessor.sparse().is_none() => {
            return bad("a bufferView (or sparse values) holding its data, got neither".into());
        }
        None => {
            // All-zero base values plus sparse substitutions: a count the file cannot back
            // would only allocate zeros.
            let file_bytes: usize = buffers.iter().map(|b| b.len()).sum();
            if count > file_bytes {
                return bad(format!("at most as many elements as the buffers have bytes ({file_bytes}), got {count}"));
            }
        }
    }
    if let Some(sparse) = accessor.sparse() {
        let indices = sparse.indices();
        let values = sparse.values();
        let parts = [
            ("sparse.indices", indices.view(), indices.offset(), indices.index_type().size()),
            ("sparse.values", values.view(), values.offset(), size),
        ];
        for (what, view, offset, elem) in parts {
            let range = view_range(path, &view, buffers)?;
            let stride = view.stride().unwrap_or(elem).max(elem);
            let needed = sparse
                .count()
                .checked_sub(1)
                .and_then(|c| c.checked_mul(stride))
                .and_then(|n| n.checked_add(elem))
                .and_then(|n| n.checked_add(offset));
            if needed.is_none_or(|n| n > range.len()) {
                return bad(format!(
                    "{what}: {} elements inside bufferViews[{}] of {} bytes",
                    sparse.count(),
                    view.index(),
                    range.len()
                ));
            }
        }
    }
    Ok(())
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
    // glTF nodes form strict trees: a node met twice is a cycle (which would never end) or a
    // shared child, both invalid.
    let mut seen = vec![false; doc.nodes().len()];
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(Error::format(
                path,
                format!("nodes[{}]", node.index()),
                "a node hierarchy of strict trees (no cycles, no node with two parents)",
            ));
        }
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

/// The component types and element types an accessor may have.
type Kinds = (&'static [gltf::accessor::DataType], &'static [gltf::accessor::Dimensions]);

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
        let position = primitive
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| Error::format(path, format!("{field}.attributes"), "a POSITION accessor"))?;
        // Every accessor read below, with the types the reader handles (it panics on others).
        use gltf::Semantic as S;
        use gltf::accessor::{DataType as T, Dimensions as D};
        let float_vec3: Kinds = (&[T::F32], &[D::Vec3]);
        let checks: [(String, Option<gltf::Accessor>, Kinds); 5] = [
            ("attributes.POSITION".into(), Some(position), float_vec3),
            ("indices".into(), primitive.indices(), (&[T::U8, T::U16, T::U32], &[D::Scalar])),
            ("attributes.NORMAL".into(), primitive.get(&S::Normals), float_vec3),
            ("attributes.TEXCOORD_0".into(), primitive.get(&S::TexCoords(0)), (&[T::U8, T::U16, T::F32], &[D::Vec2])),
            (
                "attributes.COLOR_0".into(),
                primitive.get(&S::Colors(0)),
                (&[T::U8, T::U16, T::F32], &[D::Vec3, D::Vec4]),
            ),
        ];
        for (name, accessor, (types, dims)) in checks {
            let Some(accessor) = accessor else { continue };
            let name = format!("{field}.{name}");
            if !types.contains(&accessor.data_type()) || !dims.contains(&accessor.dimensions()) {
                return Err(Error::format(
                    path,
                    format!("{name} (accessors[{}])", accessor.index()),
                    format!(
                        "component type one of {types:?} and type one of {dims:?}, got {:?} {:?}",
                        accessor.data_type(),
                        accessor.dimensions()
                    ),
                ));
            }
            check_accessor(path, &name, &accessor, buffers)?;
        }
        let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or_else(|| Error::format(path, format!("{field}.attributes"), "a POSITION accessor"))?
            // Untransformed nodes keep their positions bit for bit: `x·1 + y·0 + z·0 + 0` turns
            // -0.0 into +0.0, and a mesh written and read back should be the same mesh.
            .map(|p| if world == Mat4::IDENTITY { p } else { world.transform_point3(Vec3::from(p)).to_array() })
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
