//! Damaged single files: meshes (OBJ, PLY ASCII and binary, GLB, glTF) through every command
//! that reads a mesh, and images (PNG, JPEG, WebP) through every command that reads one.

use super::case::Case;
use super::ctx::{Ctx, args, replace_arg, s, with_flag};
use super::inputs::{
    CUBE_POSITIONS as P, CUBE_TRIANGLES as T, base64, cut, glb, gltf_cube, gltf_embedded, jpeg_with_size, junk, obj,
    ply_ascii, ply_binary, ply_binary_body, ply_binary_header, png_with_size, webp_with_size,
};

/// What a damaged mesh is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mesh {
    /// Not a readable mesh: every command must refuse it, naming the file.
    Bad,
    /// A valid mesh (hostile-looking): every command must accept it.
    Good,
    /// A valid file whose triangles have no area: `info` reports it; `eval`, `texture`,
    /// `refine` and `dataset` must refuse it by name; `render` may render empty views.
    Flat,
    /// A valid open surface: refused by `refine` (MESH must be closed), otherwise fine.
    Open,
    /// Accepting or refusing by name are both fine.
    Either,
}

/// A damaged mesh file: its file name, path and kind, and extra tokens its error may name.
struct MeshFile {
    /// File name (unique; the token every error must name, unless `tokens` adds others).
    name: String,
    /// Path as an argument.
    path: String,
    /// What it is.
    kind: Mesh,
    /// Further names the error may give instead of the file name.
    tokens: Vec<String>,
    /// Part of the `--quick` subset.
    quick: bool,
}

/// Text with its first line starting `v -0.5 -0.5 -0.5` changed to `v X -0.5 -0.5`.
fn obj_with_first_x(x: &str) -> Vec<u8> {
    obj(&P, &T).replacen("v -0.5 -0.5 -0.5", &format!("v {x} -0.5 -0.5"), 1).into_bytes()
}

/// The cube as OBJ with the last face replaced.
fn obj_with_last_face(face: &str) -> Vec<u8> {
    let text = obj(&P, &T);
    let mut lines: Vec<&str> = text.lines().collect();
    lines.pop();
    format!("{}\n{face}\n", lines.join("\n")).into_bytes()
}

/// The binary PLY of the cube with the first float of the body replaced.
fn ply_binary_first_x(x: f32) -> Vec<u8> {
    let mut pos = P;
    pos[0][0] = x;
    ply_binary(&pos, &T)
}

/// The cube's GLB with its document edited.
fn glb_edit(edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let (mut doc, bin) = gltf_cube();
    edit(&mut doc);
    glb(doc.to_string().as_bytes(), &bin)
}

/// The cube's glTF (embedded buffer) with its document edited.
fn gltf_edit(edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let (doc, bin) = gltf_cube();
    let mut doc = gltf_embedded(doc, &bin);
    edit(&mut doc);
    doc.to_string().into_bytes()
}

/// The cube's binary buffer with the first position's x set to `x`.
fn bin_with_first_x(x: f32) -> Vec<u8> {
    let (_, mut bin) = gltf_cube();
    bin[..4].copy_from_slice(&x.to_le_bytes());
    bin
}

/// The damaged meshes, written into `bad/`.
fn meshes(ctx: &Ctx) -> Vec<MeshFile> {
    use Mesh::*;
    let mut v = Vec::new();
    let mut add = |name: &str, kind: Mesh, tokens: &[&str], quick: bool, make: &dyn Fn() -> Vec<u8>| {
        let path = ctx.bad_file(name, || Ok(make()));
        let tokens = tokens.iter().map(|t| t.to_string()).collect();
        v.push(MeshFile { name: name.to_string(), path, kind, tokens, quick });
    };
    let cube = || obj(&P, &T);
    // OBJ.
    add("obj-empty.obj", Bad, &[], true, &|| Vec::new());
    add("obj-half.obj", Bad, &[], false, &|| cut(cube().as_bytes(), 1, 2));
    add("obj-cut-face.obj", Bad, &[], false, &|| {
        let t = cube();
        t.as_bytes()[..t.len() - 2].to_vec()
    });
    add("obj-junk.obj", Bad, &[], false, &|| junk(300, 1));
    add("obj-nan.obj", Bad, &[], true, &|| obj_with_first_x("nan"));
    add("obj-inf.obj", Bad, &[], false, &|| obj_with_first_x("inf"));
    add("obj-1e39.obj", Bad, &[], false, &|| obj_with_first_x("1e39"));
    add("obj-long-number.obj", Bad, &[], false, &|| obj_with_first_x(&"1".repeat(100_000)));
    add("obj-3e38.obj", Either, &[], false, &|| {
        let pos: Vec<[f32; 3]> = P.iter().map(|p| p.map(|c| c * 2.0 * 3e38)).collect();
        obj(&pos, &T).into_bytes()
    });
    add("obj-index-99.obj", Bad, &[], false, &|| obj_with_last_face("f 2 7 99"));
    add("obj-index-0.obj", Bad, &[], false, &|| obj_with_last_face("f 0 7 6"));
    add("obj-index-2e32.obj", Bad, &[], false, &|| obj_with_last_face("f 2 7 4294967296"));
    add("obj-index-neg.obj", Bad, &[], false, &|| obj_with_last_face("f -100 7 6"));
    add("obj-no-faces.obj", Bad, &[], false, &|| {
        cube().lines().filter(|l| l.starts_with('v')).collect::<Vec<_>>().join("\n").into_bytes()
    });
    add("obj-point.obj", Flat, &[], false, &|| b"v 0.5 0.5 0.5\nv 0.5 0.5 0.5\nv 0.5 0.5 0.5\nf 1 2 3\n".to_vec());
    add("obj-line.obj", Flat, &[], false, &|| b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n".to_vec());
    add("obj-open.obj", Open, &[], false, &|| b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".to_vec());
    add("obj-missing-mtl.obj", Bad, &["absent.mtl"], false, &|| {
        format!("mtllib absent.mtl\nusemtl m\n{}", cube()).into_bytes()
    });
    add("obj-nul.obj", Bad, &[], false, &|| cube().replacen("v 0.5 -0.5", "v 0.5\0 -0.5", 1).into_bytes());
    add("obj-invalid-utf8.obj", Either, &[], false, &|| {
        let mut b = b"v -0.5 \xff\xfe -0.5\n".to_vec();
        b.extend(cube().lines().skip(1).flat_map(|l| format!("{l}\n").into_bytes()));
        b
    });
    add("obj-huge-polygon.obj", Either, &[], false, &|| {
        let face: String = (0..200_000).map(|i| format!(" {}", i % 8 + 1)).collect();
        format!("{}f{face}\n", cube()).into_bytes()
    });
    add("obj-crlf.obj", Good, &[], false, &|| cube().replace('\n', "\r\n").into_bytes());
    add("obj-bom.obj", Either, &[], false, &|| [&b"\xef\xbb\xbf"[..], cube().as_bytes()].concat());
    // PLY (ASCII).
    let ascii = || ply_ascii(&P, &T);
    add("ply-empty.ply", Bad, &[], false, &|| Vec::new());
    add("ply-half.ply", Bad, &[], false, &|| cut(ascii().as_bytes(), 1, 2));
    add("ply-junk.ply", Bad, &[], false, &|| [&b"ply\n"[..], &junk(300, 2)].concat());
    add("ply-vertex-1e18.ply", Bad, &["element vertex"], true, &|| {
        ascii().replacen("element vertex 8", "element vertex 1000000000000000000", 1).into_bytes()
    });
    add("ply-face-1e18.ply", Bad, &["element face"], false, &|| {
        ascii().replacen("element face 12", "element face 1000000000000000000", 1).into_bytes()
    });
    add("ply-vertex-2e64.ply", Bad, &["element vertex"], false, &|| {
        ascii().replacen("element vertex 8", "element vertex 18446744073709551616", 1).into_bytes()
    });
    add("ply-vertex-neg.ply", Bad, &["element vertex"], false, &|| {
        ascii().replacen("element vertex 8", "element vertex -1", 1).into_bytes()
    });
    add("ply-nan.ply", Bad, &[], false, &|| ascii().replacen("-0.5 -0.5 -0.5", "nan -0.5 -0.5", 1).into_bytes());
    add("ply-index-99.ply", Bad, &[], false, &|| ascii().replacen("3 0 2 1", "3 0 2 99", 1).into_bytes());
    add("ply-list-255.ply", Bad, &[], false, &|| ascii().replacen("3 0 2 1", "255 0 2 1", 1).into_bytes());
    add("ply-list-0.ply", Either, &[], false, &|| ascii().replacen("3 0 2 1", "0", 1).into_bytes());
    add("ply-no-end-header.ply", Bad, &[], false, &|| ascii().replacen("end_header\n", "", 1).into_bytes());
    add("ply-format-2.ply", Either, &[], false, &|| ascii().replacen("ascii 1.0", "ascii 2.0", 1).into_bytes());
    add("ply-point.ply", Flat, &[], false, &|| ply_ascii(&[[0.5; 3]; 3], &[[0, 1, 2]]).into_bytes());
    // PLY (binary).
    let body = || ply_binary_body(&P, &T);
    add("plyb-half.ply", Bad, &[], false, &|| cut(&ply_binary(&P, &T), 3, 5));
    add("plyb-vertex-1e18.ply", Bad, &["element vertex"], false, &|| {
        [ply_binary_header("1000000000000000000", "12").into_bytes(), body()].concat()
    });
    add("plyb-vertex-2e32.ply", Bad, &["element vertex"], false, &|| {
        [ply_binary_header("4294967296", "12").into_bytes(), body()].concat()
    });
    add("plyb-face-1e9.ply", Bad, &["element face"], false, &|| {
        [ply_binary_header("8", "1000000000").into_bytes(), body()].concat()
    });
    add("plyb-nan.ply", Bad, &[], true, &|| ply_binary_first_x(f32::NAN));
    add("plyb-inf.ply", Bad, &[], false, &|| ply_binary_first_x(f32::NEG_INFINITY));
    add("plyb-index-max.ply", Bad, &[], false, &|| {
        let mut t = T;
        t[0][2] = u32::MAX;
        ply_binary(&P, &t)
    });
    add("plyb-list-255.ply", Bad, &[], false, &|| {
        let mut b = ply_binary(&P, &T);
        let at = b.len() - 12 * 13;
        b[at] = 255;
        b
    });
    add("plyb-list-uint-max.ply", Bad, &[], false, &|| {
        // Index lists counted by a uint: the first face claims 2^32 - 1 indices.
        let h = ply_binary_header("8", "12").replace("list uchar int", "list uint int");
        let mut b = h.into_bytes();
        for p in P {
            for c in p {
                b.extend(c.to_le_bytes());
            }
        }
        for (k, t) in T.iter().enumerate() {
            b.extend(if k == 0 { u32::MAX } else { 3 }.to_le_bytes());
            for i in t {
                b.extend(i.to_le_bytes());
            }
        }
        b
    });
    add("plyb-double-claimed.ply", Bad, &[], false, &|| {
        let h = ply_binary_header("8", "12").replace("property float", "property double");
        [h.into_bytes(), body()].concat()
    });
    add("plyb-big-endian.ply", Good, &[], false, &|| {
        let h = ply_binary_header("8", "12").replace("binary_little_endian", "binary_big_endian");
        let mut b = h.into_bytes();
        for p in P {
            for c in p {
                b.extend(c.to_be_bytes());
            }
        }
        for t in T {
            b.push(3);
            for i in t {
                b.extend(i.to_be_bytes());
            }
        }
        b
    });
    add("plyb-trailing-junk.ply", Either, &[], false, &|| [ply_binary(&P, &T), junk(100, 3)].concat());
    add("plyb-no-faces.ply", Bad, &["face"], false, &|| {
        let b = body();
        [ply_binary_header("8", "0").into_bytes(), b[..8 * 12].to_vec()].concat()
    });
    // GLB.
    let cube_glb = || glb_edit(|_| {});
    add("glb-empty.glb", Bad, &[], true, &|| Vec::new());
    add("glb-half.glb", Bad, &[], false, &|| cut(&cube_glb(), 1, 2));
    add("glb-junk.glb", Bad, &[], false, &|| junk(400, 4));
    add("glb-magic.glb", Bad, &["magic"], false, &|| {
        let mut b = cube_glb();
        b[3] = b'X';
        b
    });
    add("glb-length-max.glb", Bad, &[], false, &|| {
        let mut b = cube_glb();
        b[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        b
    });
    add("glb-json-chunk-huge.glb", Bad, &[], false, &|| {
        let mut b = cube_glb();
        b[12..16].copy_from_slice(&0x7fff_fff0u32.to_le_bytes());
        b
    });
    add("glb-count-1e9.glb", Bad, &["accessors[0]"], false, &|| {
        glb_edit(|d| d["accessors"][0]["count"] = 1_000_000_000.into())
    });
    add("glb-view-huge.glb", Bad, &["bufferViews[0]"], false, &|| {
        glb_edit(|d| d["bufferViews"][0]["byteLength"] = u32::MAX.into())
    });
    add("glb-buffer-1e12.glb", Bad, &["buffers[0]"], false, &|| {
        glb_edit(|d| d["buffers"][0]["byteLength"] = 1_000_000_000_000u64.into())
    });
    add("glb-nan.glb", Bad, &[], true, &|| glb(gltf_cube().0.to_string().as_bytes(), &bin_with_first_x(f32::NAN)));
    add("glb-index-99.glb", Bad, &[], false, &|| {
        let (doc, mut bin) = gltf_cube();
        let at = bin.len() - 4;
        bin[at..].copy_from_slice(&99u32.to_le_bytes());
        glb(doc.to_string().as_bytes(), &bin)
    });
    add("glb-accessor-7.glb", Bad, &["accessor"], false, &|| {
        glb_edit(|d| d["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 7.into())
    });
    add("glb-float-indices.glb", Bad, &["indices", "accessors[1]"], false, &|| {
        glb_edit(|d| d["accessors"][1]["componentType"] = 5126.into())
    });
    add("glb-json-not-utf8.glb", Bad, &[], false, &|| {
        let (doc, bin) = gltf_cube();
        let mut text = doc.to_string().into_bytes();
        // The version string "2.0" becomes "2\xff0": the rest of the document is intact.
        if let Some(i) = text.windows(5).position(|w| w == b"\"2.0\"") {
            text[i + 2] = 0xff;
        }
        glb(&text, &bin)
    });
    add("glb-uri-devzero.glb", Bad, &["buffers[0]", "/dev/zero"], false, &|| {
        glb_edit(|d| d["buffers"][0]["uri"] = "/dev/zero".into())
    });
    add("glb-no-meshes.glb", Bad, &["mesh"], false, &|| {
        glb_edit(|d| {
            d["meshes"] = serde_json::json!([]);
            d["nodes"] = serde_json::json!([{}]);
        })
    });
    add("glb-node-cycle.glb", Bad, &["nodes", "node"], true, &|| {
        glb_edit(|d| d["nodes"][0]["children"] = serde_json::json!([0]))
    });
    add("glb-points.glb", Either, &["mode"], false, &|| {
        glb_edit(|d| d["meshes"][0]["primitives"][0]["mode"] = 0.into())
    });
    // glTF.
    add("gltf-empty.gltf", Bad, &[], false, &|| Vec::new());
    add("gltf-half.gltf", Bad, &[], false, &|| cut(&gltf_edit(|_| {}), 1, 2));
    add("gltf-not-json.gltf", Bad, &[], false, &|| b"hello, I am not JSON".to_vec());
    add("gltf-deep.gltf", Bad, &[], true, &|| super::ctx::deep_json(100_000));
    add("gltf-uri-missing.gltf", Bad, &["cube.bin"], false, &|| {
        gltf_edit(|d| d["buffers"][0]["uri"] = "cube.bin".into())
    });
    add("gltf-uri-dir.gltf", Bad, &["buffers[0]"], false, &|| gltf_edit(|d| d["buffers"][0]["uri"] = ".".into()));
    add("gltf-uri-devzero.gltf", Bad, &["buffers[0]", "/dev/zero"], false, &|| {
        gltf_edit(|d| d["buffers"][0]["uri"] = "/dev/zero".into())
    });
    add("gltf-uri-traversal.gltf", Bad, &["buffers[0]", "hostname"], false, &|| {
        gltf_edit(|d| d["buffers"][0]["uri"] = "../../../../../../../../../etc/hostname".into())
    });
    add("gltf-base64-cut.gltf", Bad, &["buffers[0]"], false, &|| {
        let (doc, bin) = gltf_cube();
        let mut doc = gltf_embedded(doc, &bin);
        let uri = doc["buffers"][0]["uri"].as_str().unwrap_or("").to_string();
        doc["buffers"][0]["uri"] = uri[..uri.len() / 2].into();
        doc.to_string().into_bytes()
    });
    add("gltf-base64-junk.gltf", Bad, &["buffers[0]"], false, &|| {
        gltf_edit(|d| {
            d["buffers"][0]["uri"] = format!("data:application/octet-stream;base64,{}", "!@#$".repeat(100)).into()
        })
    });
    add("gltf-count-1e9.gltf", Bad, &["accessors[0]"], false, &|| {
        gltf_edit(|d| d["accessors"][0]["count"] = 1_000_000_000.into())
    });
    add("gltf-nan.gltf", Bad, &[], false, &|| {
        let bin = bin_with_first_x(f32::INFINITY);
        let (mut doc, _) = gltf_cube();
        doc["buffers"][0]["uri"] = format!("data:application/octet-stream;base64,{}", base64(&bin)).into();
        doc.to_string().into_bytes()
    });
    add("gltf-node-cycle.gltf", Bad, &["nodes", "node"], false, &|| {
        gltf_edit(|d| {
            d["nodes"] = serde_json::json!([{"children": [1]}, {"mesh": 0, "children": [0]}]);
        })
    });
    add("gltf-deep-nodes.gltf", Either, &["nodes", "node"], false, &|| {
        gltf_edit(|d| {
            let n = 100_000;
            let nodes: Vec<serde_json::Value> =
                (0..n)
                    .map(|i| {
                        if i + 1 < n {
                            serde_json::json!({"children": [i + 1]})
                        } else {
                            serde_json::json!({"mesh": 0})
                        }
                    })
                    .collect();
            d["nodes"] = serde_json::Value::Array(nodes);
        })
    });
    add("gltf-many-nodes.gltf", Either, &["nodes", "node"], false, &|| {
        gltf_edit(|d| {
            // 10 000 copies of the cube in one place: 120 000 coincident triangles.
            let nodes: Vec<serde_json::Value> = (0..10_000).map(|_| serde_json::json!({"mesh": 0})).collect();
            d["nodes"] = serde_json::Value::Array(nodes);
            d["scenes"][0]["nodes"] = serde_json::Value::Array((0..10_000).map(|i| i.into()).collect());
        })
    });
    add("gltf-version-1.gltf", Either, &["version", "asset"], false, &|| {
        gltf_edit(|d| d["asset"]["version"] = "1.0".into())
    });
    v
}

/// The cases of the damaged meshes: `info`, `render`, `eval` (as PRED; a few as GT),
/// `texture`, `refine` (as MESH and as the oracle), `dataset`.
pub(crate) fn mesh_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let cube = s(&ctx.seeds.cube_obj);
    for m in meshes(ctx) {
        let mut tokens: Vec<&str> = vec![&m.name];
        tokens.extend(m.tokens.iter().map(String::as_str));
        let id = m.name.replace('.', "-");
        // The expectation of a command by the mesh's kind: (fails, may succeed).
        let add =
            |out: &mut Vec<Case>, command: &'static str, what: &str, a: Vec<String>, fails: bool, either: bool| {
                let case = Case::new(command, &format!("{what}{id}"), a, &tokens);
                let case = if !fails {
                    case.succeeds()
                } else if either {
                    case.either()
                } else {
                    case
                };
                out.push(case.quick_if(m.quick && command == "info"));
            };
        let (bad, either) = (m.kind == Mesh::Bad, m.kind == Mesh::Either);
        let (flat, open) = (m.kind == Mesh::Flat, m.kind == Mesh::Open);
        // info reports flat and open meshes; render may render empty views of a flat one.
        add(out, "info", "", replace_arg(&ctx.base("info"), &cube, &m.path), bad || either, either);
        add(out, "render", "", replace_arg(&ctx.base("render"), &cube, &m.path), bad || either || flat, either || flat);
        let eval = ctx.base("eval");
        let pred = [&eval[..1], std::slice::from_ref(&m.path), &eval[2..]].concat();
        add(out, "eval", "pred-", pred, bad || either || flat || open, either || open);
        if m.quick || flat {
            let gt = [&eval[..2], std::slice::from_ref(&m.path), &eval[3..]].concat();
            add(out, "eval", "gt-", gt, bad || either || flat || open, either || open);
        }
        let texture = replace_arg(&ctx.base("texture"), &cube, &m.path);
        add(out, "texture", "", texture, bad || either || flat || open, either || open);
        if m.kind != Mesh::Good {
            let refine = ctx.base("refine");
            let as_mesh = [&refine[..1], std::slice::from_ref(&m.path), &refine[2..]].concat();
            out.push({
                let c = Case::new("refine", &format!("mesh-{id}"), as_mesh, &tokens).timeout(60);
                if either { c.either() } else { c }
            });
            if !open {
                let oracle = with_flag(&refine, "--enhancer", &format!("oracle:{}", m.path));
                out.push({
                    let c = Case::new("refine", &format!("oracle-{id}"), oracle, &tokens).timeout(60);
                    if either { c.either() } else { c }
                });
            }
        }
        let dataset = replace_arg(&ctx.base("dataset"), &cube, &m.path);
        add(out, "dataset", "", dataset, bad || either || flat, either);
    }
}

/// A damaged image: file name, path, whether it is still a valid input.
struct ImageFile {
    /// File name (the token).
    name: String,
    /// Path as an argument.
    path: String,
    /// A valid input (`prepare` and `generate` must accept it).
    good: bool,
    /// Accepting or refusing by name are both fine.
    either: bool,
    /// Part of the `--quick` subset.
    quick: bool,
}

/// The damaged images, written into `bad/`.
fn images(ctx: &Ctx) -> Vec<ImageFile> {
    let mut v = Vec::new();
    let sd = &ctx.seeds;
    let mut add = |name: &str, good: bool, either: bool, quick: bool, make: &dyn Fn() -> Result<Vec<u8>, String>| {
        let path = ctx.bad_file(name, make);
        v.push(ImageFile { name: name.to_string(), path, good, either, quick });
    };
    let png = || ctx.read(&sd.disc_png);
    let jpg = || ctx.read(&sd.photo_jpg);
    let webp = || ctx.read(&sd.disc_webp);
    add("png-empty.png", false, false, false, &|| Ok(Vec::new()));
    add("png-half.png", false, false, false, &|| Ok(cut(&png()?, 1, 2)));
    add("png-junk.png", false, false, false, &|| Ok([&b"\x89PNG\r\n\x1a\n"[..], &junk(200, 5)].concat()));
    add("png-60000.png", false, false, true, &|| Ok(png_with_size(&png()?, 60000, 60000)));
    add("png-0x0.png", false, false, false, &|| Ok(png_with_size(&png()?, 0, 0)));
    add("png-1x100000.png", false, false, false, &|| Ok(png_with_size(&png()?, 1, 100_000)));
    add("png-bad-crc.png", false, false, false, &|| {
        let mut b = png()?;
        b[29] ^= 0xff;
        Ok(b)
    });
    add("png-text.png", false, false, false, &|| Ok(b"this is a text file named like a PNG\n".to_vec()));
    add("png-is-glb.png", false, false, false, &|| ctx.read(&sd.cube_glb));
    add("png-transparent.png", false, false, false, &|| {
        let img = image::RgbaImage::from_pixel(48, 40, image::Rgba([10, 20, 30, 0]));
        encode_png(img)
    });
    add("png-1x1.png", false, true, false, &|| {
        encode_png(image::RgbaImage::from_pixel(1, 1, image::Rgba([200, 0, 0, 255])))
    });
    add("png-20000x1.png", false, true, false, &|| {
        encode_png(image::RgbaImage::from_fn(20000, 1, |x, _| {
            image::Rgba([200, 0, 0, if x % 3 == 0 { 255 } else { 0 }])
        }))
    });
    add("png-grey.png", false, true, false, &|| {
        let img = image::GrayImage::from_fn(48, 40, |x, y| image::Luma([if (x + y) % 7 == 0 { 30 } else { 220 }]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png).map_err(|e| e.to_string())?;
        Ok(out.into_inner())
    });
    add("png-16bit.png", true, false, false, &|| ctx.read(&sd.disc16_png));
    add("jpg-empty.jpg", false, false, false, &|| Ok(Vec::new()));
    add("jpg-half.jpg", false, false, false, &|| Ok(cut(&jpg()?, 1, 2)));
    add("jpg-junk.jpg", false, false, false, &|| Ok([&b"\xff\xd8\xff"[..], &junk(300, 6), &b"\xff\xd9"[..]].concat()));
    add("jpg-65535.jpg", false, false, true, &|| Ok(jpeg_with_size(&jpg()?, 65535, 65535)));
    add("jpg-0x0.jpg", false, false, false, &|| Ok(jpeg_with_size(&jpg()?, 0, 0)));
    add("webp-empty.webp", false, false, false, &|| Ok(Vec::new()));
    add("webp-half.webp", false, false, false, &|| Ok(cut(&webp()?, 1, 2)));
    add("webp-16384.webp", false, false, false, &|| Ok(webp_with_size(&webp()?, 16384, 16384)));
    add("webp-riff-huge.webp", false, true, false, &|| {
        let mut b = webp()?;
        b[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        Ok(b)
    });
    add("webp-good.webp", true, false, false, &webp);
    add("exr-as-image.exr", false, false, false, &|| ctx.read(&sd.views.join("normal_front.exr")));
    v
}

/// An RGBA PNG in memory.
fn encode_png(img: image::RgbaImage) -> Result<Vec<u8>, String> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// The cases of the damaged images: `prepare`, `generate` (the tiny model), `run` and
/// `batch` (a few, with the tiny model).
pub(crate) fn image_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let disc = s(&ctx.seeds.disc_png);
    for img in images(ctx) {
        let id = img.name.replace('.', "-");
        let tokens = [img.name.as_str()];
        let expect = |c: Case| {
            if img.good {
                c.succeeds()
            } else if img.either {
                c.either()
            } else {
                c
            }
        };
        let prepare = replace_arg(&ctx.base("prepare"), &disc, &img.path);
        out.push(expect(Case::new("prepare", &id, prepare, &tokens)).quick_if(img.quick));
        let generate = replace_arg(&ctx.base("generate"), &disc, &img.path);
        out.push(expect(Case::new("generate", &id, generate, &tokens)));
        if !img.good && !img.either && (img.quick || img.name.ends_with("empty.png")) {
            let run = replace_arg(&ctx.base("run"), &disc, &img.path);
            out.push(Case::new("run", &id, run, &tokens).timeout(60));
            let manifest = format!("{}\n", img.path);
            let batch = [
                &args(&["batch", "{case}/items.txt", "--out", "{case}/b", "--weights"])[..],
                &[s(&ctx.seeds.tiny)],
                &args(&["--steps", "1", "--preset", "fast", "--no-texture", "--starts", "1", "--quiet"])[..],
            ]
            .concat();
            out.push(
                Case::new("batch", &format!("image-{id}"), batch, &tokens)
                    .with(super::case::Setup::Write("items.txt".into(), manifest.into_bytes()))
                    .timeout(60),
            );
        }
    }
}
