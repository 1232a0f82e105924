//! A training set rendered from meshes: per object, several randomly rotated samples, each a
//! 6-view [`ViewSet`] folder (normals, masks, colours) of the Wonder3D rig, plus one
//! `dataset.json` listing every sample with its camera type, background, rotation and
//! colouring. `wonder3d dataset` is a thin shell over [`Dataset`]; the layout and the rules
//! a training loader follows (compositing the background) are in `docs/training.md`.
//!
//! The folder `DIR` written by [`Dataset::write`]:
//!
//! | path | what |
//! |---|---|
//! | `DIR/dataset.json` | [`DatasetManifest`]: format, version, size, seed, view names, one [`Sample`] per sample |
//! | `DIR/<id>/` | a view-set folder exactly as [`ViewSet::save`] writes it (`cameras.json`, `normal_<view>.png` / `.exr`, `mask_<view>.png`, `colour_<view>.png` RGBA with alpha = mask; no depth) |
//!
//! Each sample folder loads with [`ViewSet::load`] and reconstructs with `wonder3d
//! reconstruct DIR/<id>`: it is the exact truth of that sample.
//!
//! **Per sample** (everything drawn from [`sample_draw`], a pure function of the dataset
//! seed, the object's id stem and the sample index):
//! - the object is rotated by a yaw about +y uniform in ±60° after a pitch about +x uniform
//!   in −15…30° (Wonder3D's render-time rotation, z ±60° and x −15…30° in Blender's z-up;
//!   `docs/training.md`, "Per sample"), then normalised as `wonder3d render` does (bbox centred,
//!   longest side 1), then scaled so its front-view silhouette spans [`INPUT_FRACTION`] of
//!   the image — the framing inference gives a photo — within [`MAX_VIEW_FRACTION`] in every
//!   view ([`framing_scale`]);
//! - the camera type is orthographic or perspective with p = 0.5 (or fixed by
//!   [`DatasetOptions::with_camera`]); the rig is `w3d-core`'s 6-view rig of that type;
//! - the background is white, black or grey (1, 0, 0.5) with p = 1/3 each. It is **not**
//!   composited into the files (they carry alpha = mask); the loader composites it into the
//!   input and the targets alike: `model = rgb·alpha + bg·(1 − alpha)`, for normals applied
//!   to the encoded `(n + 1) / 2`.
//!
//! **Normals** are unit vectors in the canonical frame, which is the front camera's OpenGL
//! frame (+x right, +y up, +z toward the viewer) for all six views, as `wonder3d render`
//! writes them for the rotated mesh; inference decodes generated views with the same rig.
//!
//! **Colour**: the mesh's own texture or vertex colours when it has them (`"mesh"`);
//! otherwise a procedural colouring per object ([`procedural_colours`]): a smooth,
//! low-frequency blend of three saturated hues over the normalised, *unrotated* position, so
//! the object looks the same in every sample and the input view's colours predict the other
//! views (`"procedural"`).
//!
//! ```no_run
//! use wonder3d::dataset::{Dataset, DatasetOptions};
//!
//! let options = DatasetOptions::default().with_samples(4).with_size(256).with_seed(7);
//! let dataset = Dataset::prepare(&["assets/spot.obj", "assets/torus.obj"], &options)?;
//! let manifest = dataset.write("/tmp/train", &mut |p| eprintln!("{}/{}", p.done, p.total))?;
//! assert_eq!(manifest.samples.len(), 8); // spot_000 … spot_003, torus_000 … torus_003
//! # Ok::<(), wonder3d::Error>(())
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use w3d_core::io::write_dir_atomic;
use w3d_core::{Error, Mesh, Result, ViewRig, ViewSet};

use crate::progress::{Progress, Stage};

pub use w3d_core::dataset::FORMAT;

/// The `version` of the layout written here.
pub const VERSION: u32 = 2;

/// The manifest's file name inside the dataset folder.
pub const MANIFEST_FILE: &str = "dataset.json";

/// Smallest view side in pixels.
pub const MIN_SIZE: u32 = 16;

/// Largest view side in pixels.
pub const MAX_SIZE: u32 = 2048;

/// Largest number of samples per object.
pub const MAX_SAMPLES: usize = 10_000;

/// Yaw range (degrees, about +y): uniform in `[-YAW_DEG, YAW_DEG]`.
pub const YAW_DEG: f64 = 60.0;

/// Pitch range (degrees, about +x): uniform in `[PITCH_DEG.0, PITCH_DEG.1]`.
pub const PITCH_DEG: (f64, f64) = (-15.0, 30.0);

/// The camera type of a sample: which of `w3d-core`'s 6-view Wonder3D rigs renders it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraKind {
    /// [`ViewRig::wonder3d_ortho`] (`"ortho"`).
    Ortho,
    /// [`ViewRig::wonder3d_persp`] (`"persp"`).
    Persp,
}

impl CameraKind {
    /// The 6-view rig of this camera type. It must stay the rig that
    /// `w3d_diffusion::CameraType::rig` gives the same type (that crate needs Burn, so it is
    /// not called here): training data and inference decode views with one rig.
    pub fn rig(self) -> ViewRig {
        match self {
            CameraKind::Ortho => ViewRig::wonder3d_ortho(),
            CameraKind::Persp => ViewRig::wonder3d_persp(),
        }
    }

    /// `"ortho"` or `"persp"`, as in `dataset.json`.
    pub fn name(self) -> &'static str {
        match self {
            CameraKind::Ortho => "ortho",
            CameraKind::Persp => "persp",
        }
    }
}

pub use w3d_core::dataset::Background;

/// Where a sample's colour views come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Colouring {
    /// The mesh's own texture (with uvs) or vertex colours (`"mesh"`).
    Mesh,
    /// [`procedural_colours`] of the object, applied as vertex colours (`"procedural"`).
    Procedural,
}

/// One sample as `dataset.json` lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct Sample {
    /// The sample's folder name under the dataset folder: `<stem>_<index>` with the index
    /// written with at least 3 digits (`spot_000`).
    pub id: String,
    /// The mesh file as given to [`Dataset::prepare`].
    pub source: String,
    /// The sample's index among its object's samples (0-based).
    pub sample: usize,
    /// The camera type of its rig.
    pub camera: CameraKind,
    /// The background the loader composites it over.
    pub background: Background,
    /// Yaw of the object about +y (degrees), applied after the pitch.
    pub yaw_deg: f64,
    /// Pitch of the object about +x (degrees), applied first.
    pub pitch_deg: f64,
    /// Where its colours come from.
    pub colouring: Colouring,
}

/// `dataset.json`: what a training loader reads first.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct DatasetManifest {
    /// Always [`FORMAT`].
    pub format: String,
    /// The layout version ([`VERSION`]).
    pub version: u32,
    /// View side in pixels (every image is `size × size`).
    pub size: u32,
    /// The dataset seed every draw derives from.
    pub seed: u64,
    /// The view names in rig order (`front`, `front_right`, `right`, `back`, `left`,
    /// `front_left`); view 0 is the input (condition) view.
    pub views: Vec<String>,
    /// Every sample, object by object in the order the meshes were given, then by index.
    pub samples: Vec<Sample>,
}

impl DatasetManifest {
    /// Reads `DIR/dataset.json` and checks its format and version; errors name the file.
    pub fn read(dir: impl AsRef<Path>) -> Result<DatasetManifest> {
        let path = dir.as_ref().join(MANIFEST_FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let manifest: DatasetManifest = serde_json::from_str(&text)
            .map_err(|e| Error::format(&path, "JSON", format!("a wonder3d-rs dataset manifest ({e})")))?;
        if manifest.format != FORMAT {
            return Err(Error::format(&path, "format", format!("{FORMAT:?}, got {:?}", manifest.format)));
        }
        if manifest.version != VERSION {
            return Err(Error::format(&path, "version", format!("{VERSION}, got {}", manifest.version)));
        }
        Ok(manifest)
    }
}

/// Options of a [`Dataset`]. Build with the setters; [`DatasetOptions::validate`] checks
/// the ranges (as [`Dataset::prepare`] does).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct DatasetOptions {
    /// Samples per object, 1 to [`MAX_SAMPLES`] (default 4).
    pub samples: usize,
    /// View side in pixels, [`MIN_SIZE`] to [`MAX_SIZE`] (default 256, the model's size).
    pub size: u32,
    /// The dataset seed (default 0): the same seed gives byte-identical folders.
    pub seed: u64,
    /// A fixed camera type, or `None` (default) for ortho or persp with p = 0.5 per sample.
    pub camera: Option<CameraKind>,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        DatasetOptions { samples: 4, size: 256, seed: 0, camera: None }
    }
}

impl DatasetOptions {
    w3d_core::setters! {
        /// With `samples` samples per object.
        with_samples(samples: usize);
        /// With `size × size` views.
        with_size(size: u32);
        /// With another seed.
        with_seed(seed: u64);
        /// With the camera type fixed (`Some`) or drawn per sample (`None`).
        with_camera(camera: Option<CameraKind>);
    }

    /// Checks the ranges: samples 1 to [`MAX_SAMPLES`], size [`MIN_SIZE`] to [`MAX_SIZE`].
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_SAMPLES).contains(&self.samples) {
            return Err(Error::invalid(
                "samples",
                format!("1 to {MAX_SAMPLES} samples per object, got {}", self.samples),
            ));
        }
        if !(MIN_SIZE..=MAX_SIZE).contains(&self.size) {
            return Err(Error::invalid("size", format!("{MIN_SIZE} to {MAX_SIZE} pixels, got {}", self.size)));
        }
        Ok(())
    }
}

/// The random choices of one sample ([`sample_draw`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct Draw {
    /// Camera type.
    pub camera: CameraKind,
    /// Background.
    pub background: Background,
    /// Yaw about +y, degrees, in ±[`YAW_DEG`].
    pub yaw_deg: f64,
    /// Pitch about +x, degrees, in [`PITCH_DEG`].
    pub pitch_deg: f64,
}

/// 64-bit FNV-1a over `parts`, one after the other.
fn fnv1a(parts: &[&[u8]]) -> u64 {
    parts
        .iter()
        .flat_map(|p| p.iter())
        .fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3))
}

/// SplitMix64: a small, well-mixed generator; every draw of a sample comes from one.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`: the top 53 bits.
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// `deg` rounded to 10⁻⁶ degrees (an integer over 10⁶), so that the value written to
/// `dataset.json` reads back as the same `f64` in any correctly rounding JSON parser: the
/// angles recorded are exactly the angles rendered.
fn micro(deg: f64) -> f64 {
    (deg * 1e6).round() / 1e6
}

/// The draws of sample `index` of the object with id stem `stem` in a dataset with `seed`.
///
/// A SplitMix64 generator is seeded with the 64-bit FNV-1a hash of the bytes
/// `"wonder3d-rs dataset\0" ‖ seed (u64 little-endian) ‖ stem (UTF-8) ‖ "\0" ‖ index (u64
/// little-endian)`; four uniforms `u ∈ [0, 1)` (top 53 bits of each output) are drawn in
/// this order: camera (`persp` when `u ≥ 0.5`; drawn even when `camera` fixes it, so the
/// other draws do not depend on it), background (`⌊3u⌋` → white, black, grey), yaw
/// (`−60 + 120u`°), pitch (`−15 + 45u`°); both angles are rounded to 10⁻⁶ degrees.
pub fn sample_draw(seed: u64, stem: &str, index: usize, camera: Option<CameraKind>) -> Draw {
    let hash =
        fnv1a(&[b"wonder3d-rs dataset\0", &seed.to_le_bytes(), stem.as_bytes(), b"\0", &(index as u64).to_le_bytes()]);
    let mut rng = SplitMix64(hash);
    let drawn = if rng.uniform() < 0.5 { CameraKind::Ortho } else { CameraKind::Persp };
    let background = match (rng.uniform() * 3.0) as u32 {
        0 => Background::White,
        1 => Background::Black,
        _ => Background::Grey,
    };
    let yaw_deg = micro(-YAW_DEG + 2.0 * YAW_DEG * rng.uniform());
    let pitch_deg = micro(PITCH_DEG.0 + (PITCH_DEG.1 - PITCH_DEG.0) * rng.uniform());
    Draw { camera: camera.unwrap_or(drawn), background, yaw_deg, pitch_deg }
}

/// HSV (all in `[0, 1]`, hue wrapping) to RGB.
fn hsv(h: f64, s: f64, v: f64) -> [f64; 3] {
    let h = h.rem_euclid(1.0) * 6.0;
    let f = |n: f64| {
        let k = (n + h).rem_euclid(6.0);
        v - v * s * k.min(4.0 - k).clamp(0.0, 1.0)
    };
    [f(5.0), f(3.0), f(1.0)]
}

/// A deterministic colouring of an object, per vertex (sRGB in `[0, 1]`), from its
/// positions and its id stem alone (no dataset seed, no sample), so it is the same in every
/// sample of the object.
///
/// `positions` should be the object's normalised, unrotated positions (the unit cube, as
/// [`Mesh::normalize_unit_cube`] gives them). A SplitMix64 generator seeded with the FNV-1a
/// hash of `"wonder3d-rs colouring\0" ‖ stem` picks three saturated hues about a third of
/// the hue circle apart (saturation 0.65–0.9, value 0.75–0.95) and for each a plane wave
/// `sin(2π f d·p + φ)` (random unit direction `d`, 1 to 2 cycles across the unit cube,
/// random phase); each vertex gets the softmax blend of the three hues weighted by
/// `exp(3 · wave)`: smooth regions of one hue with soft borders.
pub fn procedural_colours(positions: &[[f32; 3]], stem: &str) -> Vec<[f32; 3]> {
    let mut rng = SplitMix64(fnv1a(&[b"wonder3d-rs colouring\0", stem.as_bytes()]));
    let base = rng.uniform();
    let mut waves = Vec::with_capacity(3);
    for k in 0..3 {
        let hue = base + k as f64 / 3.0 + (rng.uniform() - 0.5) * 0.12;
        let colour = hsv(hue, 0.65 + 0.25 * rng.uniform(), 0.75 + 0.2 * rng.uniform());
        // A uniform direction on the sphere.
        let z = 2.0 * rng.uniform() - 1.0;
        let a = std::f64::consts::TAU * rng.uniform();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let direction = [r * a.cos(), r * a.sin(), z];
        let frequency = 1.0 + rng.uniform();
        let phase = std::f64::consts::TAU * rng.uniform();
        waves.push((colour, direction, frequency, phase));
    }
    positions
        .iter()
        .map(|p| {
            let mut sum = [0.0f64; 3];
            let mut total = 0.0;
            for (colour, d, f, phase) in &waves {
                let t = d[0] * f64::from(p[0]) + d[1] * f64::from(p[1]) + d[2] * f64::from(p[2]);
                let w = (3.0 * (std::f64::consts::TAU * f * t + phase).sin()).exp();
                for (s, c) in sum.iter_mut().zip(colour) {
                    *s += w * c;
                }
                total += w;
            }
            sum.map(|s| (s / total) as f32)
        })
        .collect()
}

/// The id stem of a mesh file: its file stem with every character outside
/// `A-Z a-z 0-9 . _ -` replaced by `_` and leading dots removed.
pub fn id_stem(path: &Path) -> String {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let stem: String =
        stem.chars().map(|c| if c.is_ascii_alphanumeric() || "._-".contains(c) { c } else { '_' }).collect();
    stem.trim_start_matches('.').to_string()
}

/// One object of a [`Dataset`]: its mesh, loaded, oriented outward, normalised into the unit
/// cube (unrotated) and coloured.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct DatasetObject {
    /// The mesh file as given.
    pub source: PathBuf,
    /// The id stem its samples are named by ([`id_stem`]).
    pub stem: String,
    /// Where its colours come from.
    pub colouring: Colouring,
    /// Whether it was a closed mesh wound inward, flipped outward on loading (as `wonder3d
    /// render` does).
    pub flipped_outward: bool,
    /// The mesh, normalised into the unit cube, unrotated, with its colours.
    pub mesh: Mesh,
}

impl DatasetObject {
    /// Loads `path` and prepares it: oriented outward when it is a closed mesh wound inward
    /// ([`Mesh::orient_outward`]), normalised into the unit cube, given procedural vertex
    /// colours when it has neither a texture nor vertex colours. Errors name the file.
    pub fn load(path: impl AsRef<Path>) -> Result<DatasetObject> {
        let path = path.as_ref();
        let stem = id_stem(path);
        if stem.is_empty() {
            return Err(Error::invalid(
                format!("mesh {}", path.display()),
                "a file name with letters or digits (it names the samples)",
            ));
        }
        // A mesh without area renders as empty masks: samples a trainer cannot use.
        let mut mesh = crate::input::load_mesh_with_surface(path, "mesh")?;
        let flipped_outward = mesh.orient_outward();
        mesh.normalize_unit_cube();
        // The renderer computes normals from the geometry; stored ones would go stale under
        // the rotation, so they are dropped.
        let (positions, triangles, _normals, uvs, colours, texture) = mesh.into_parts();
        let has_texture = texture.is_some() && uvs.is_some();
        let colouring = if has_texture || colours.is_some() { Colouring::Mesh } else { Colouring::Procedural };
        let colours = match colouring {
            Colouring::Mesh => colours,
            Colouring::Procedural => Some(procedural_colours(&positions, &stem)),
        };
        let in_file = |e: Error| e.in_file(path);
        let mut mesh = Mesh::new(positions, triangles).map_err(in_file)?;
        if let Some(uvs) = uvs {
            mesh = mesh.with_uvs(uvs).map_err(in_file)?;
        }
        if let Some(colours) = colours {
            mesh = mesh.with_colours(colours).map_err(in_file)?;
        }
        if let (Some(texture), true) = (texture, mesh.uvs().is_some()) {
            mesh = mesh.with_texture(texture).map_err(in_file)?;
        }
        Ok(DatasetObject { source: path.to_path_buf(), stem, colouring, flipped_outward, mesh })
    }

    /// This object's mesh as sample `draw` renders it: rotated by the draw's pitch about +x,
    /// then its yaw about +y, normalised into the unit cube again (bbox centred, longest
    /// side 1), then scaled about the origin by [`framing_scale`] so that the front view
    /// frames it as [`INPUT_FRACTION`] says.
    pub fn posed(&self, draw: &Draw) -> Result<Mesh> {
        pose(&self.mesh, draw).map_err(|e| e.in_file(&self.source))
    }
}

/// `mesh` (normalised into the unit cube) as a sample with `draw` renders it: rotated by the
/// draw's pitch about +x, then its yaw about +y, normalised into the unit cube again, then
/// scaled about the origin by [`framing_scale`] ([`DatasetObject::posed`] for a mesh that is
/// not a file, e.g. the demo's bundled spot).
pub fn pose(mesh: &Mesh, draw: &Draw) -> Result<Mesh> {
    let (yaw, pitch) = (draw.yaw_deg.to_radians(), draw.pitch_deg.to_radians());
    let (sy, cy, sp, cp) = (yaw.sin(), yaw.cos(), pitch.sin(), pitch.cos());
    // R = Ry(yaw) · Rx(pitch), in f64.
    let r = [[cy, sy * sp, sy * cp], [0.0, cp, -sp], [-sy, cy * sp, cy * cp]];
    let mut mesh = mesh.clone();
    mesh.map_positions(|p| {
        let p = [f64::from(p.x), f64::from(p.y), f64::from(p.z)];
        let row = |k: usize| (r[k][0] * p[0] + r[k][1] * p[1] + r[k][2] * p[2]) as f32;
        w3d_core::glam::Vec3::new(row(0), row(1), row(2))
    })?;
    mesh.normalize_unit_cube();
    let scale = framing_scale(&mesh);
    mesh.map_positions(|p| p * scale)?;
    Ok(mesh)
}

/// Fraction of the image side that the longest side of the object's front-view silhouette
/// spans in a sample (at the origin's depth): the framing that inference gives a photo
/// (`w3d_diffusion::OBJECT_FRACTION`, Wonder3D's 192 of 256 px), so a model trained on these
/// samples sees its condition image at the scale of its targets.
pub const INPUT_FRACTION: f32 = 0.75;

/// Largest fraction of the image side the object may span in any of the six views (its
/// diameter about the vertical axis and its height), which bounds [`framing_scale`] for
/// objects deep along the front view's axis.
pub const MAX_VIEW_FRACTION: f32 = 0.9;

/// The factor that scales `mesh` (centred at the origin, e.g. normalised into the unit cube)
/// so that its front-view silhouette (the x–y extent of its bounding box, +z toward the
/// front camera) spans [`INPUT_FRACTION`] of the Wonder3D image (`2 ×`
/// [`w3d_core::rig::WONDER3D_HALF_EXTENT`] world units at the origin) — unless then its
/// diameter about the y axis or its height would exceed [`MAX_VIEW_FRACTION`] of it in some
/// view, in which case the largest factor within that bound. 1 for an empty mesh.
pub fn framing_scale(mesh: &Mesh) -> f32 {
    let positions = mesh.positions();
    if positions.is_empty() {
        return 1.0;
    }
    let (mut lo, mut hi, mut radius) = ([f32::MAX; 3], [f32::MIN; 3], 0.0f32);
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
        radius = radius.max((p[0] * p[0] + p[2] * p[2]).sqrt());
    }
    let image = 2.0 * w3d_core::rig::WONDER3D_HALF_EXTENT;
    let front = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let widest = (2.0 * radius).max(hi[1] - lo[1]);
    if front <= 0.0 || widest <= 0.0 {
        return 1.0;
    }
    (INPUT_FRACTION * image / front).min(MAX_VIEW_FRACTION * image / widest)
}

/// A planned training set: the prepared objects and every sample's draws, checked and ready
/// to render ([`Dataset::write`]).
#[derive(Debug, Clone)]
pub struct Dataset {
    options: DatasetOptions,
    objects: Vec<DatasetObject>,
    samples: Vec<(usize, Sample)>,
}

impl Dataset {
    /// Checks the options, loads and prepares every mesh ([`DatasetObject::load`]; a missing
    /// or damaged file is an error naming it) and draws every sample, before anything is
    /// rendered. Id stems must be distinct across the meshes.
    pub fn prepare<P: AsRef<Path>>(meshes: &[P], options: &DatasetOptions) -> Result<Dataset> {
        options.validate()?;
        if meshes.is_empty() {
            return Err(Error::invalid("meshes", "at least one mesh file"));
        }
        let mut objects: Vec<DatasetObject> = Vec::with_capacity(meshes.len());
        for path in meshes {
            let path = path.as_ref();
            let stem = id_stem(path);
            if let Some(other) = objects.iter().find(|o| o.stem == stem) {
                return Err(Error::invalid(
                    format!("mesh {}", path.display()),
                    format!(
                        "a file name of its own: {} has the same name {stem:?}, and names the samples; rename one",
                        other.source.display()
                    ),
                ));
            }
            objects.push(DatasetObject::load(path)?);
        }
        let samples = objects
            .iter()
            .enumerate()
            .flat_map(|(o, object)| {
                (0..options.samples).map(move |index| {
                    let draw = sample_draw(options.seed, &object.stem, index, options.camera);
                    let sample = Sample {
                        id: format!("{}_{index:03}", object.stem),
                        source: object.source.to_string_lossy().into_owned(),
                        sample: index,
                        camera: draw.camera,
                        background: draw.background,
                        yaw_deg: draw.yaw_deg,
                        pitch_deg: draw.pitch_deg,
                        colouring: object.colouring,
                    };
                    (o, sample)
                })
            })
            .collect();
        Ok(Dataset { options: *options, objects, samples })
    }

    /// The options it was prepared with.
    pub fn options(&self) -> &DatasetOptions {
        &self.options
    }

    /// The prepared objects, in the order the meshes were given.
    pub fn objects(&self) -> &[DatasetObject] {
        &self.objects
    }

    /// Every sample, as `dataset.json` will list them.
    pub fn samples(&self) -> impl ExactSizeIterator<Item = &Sample> {
        self.samples.iter().map(|(_, s)| s)
    }

    /// The manifest of this dataset (what [`Dataset::write`] writes as `dataset.json`).
    pub fn manifest(&self) -> DatasetManifest {
        DatasetManifest {
            format: FORMAT.to_string(),
            version: VERSION,
            size: self.options.size,
            seed: self.options.seed,
            views: CameraKind::Ortho.rig().views.iter().map(|v| v.name.clone()).collect(),
            samples: self.samples().cloned().collect(),
        }
    }

    /// Renders sample `i` (in [`Dataset::samples`] order) with `w3d-raster`'s oracle views
    /// (smooth normals, colours, anti-aliased masks), without depth.
    pub fn render_sample(&self, i: usize) -> Result<ViewSet> {
        let (o, sample) = self
            .samples
            .get(i)
            .ok_or_else(|| Error::invalid("sample", format!("an index below {}, got {i}", self.samples.len())))?;
        let object = &self.objects[*o];
        let draw = Draw {
            camera: sample.camera,
            background: sample.background,
            yaw_deg: sample.yaw_deg,
            pitch_deg: sample.pitch_deg,
        };
        let mesh = object.posed(&draw)?;
        let views = w3d_raster::render_oracle_views(&mesh, &sample.camera.rig(), self.options.size)
            .map_err(|e| e.in_file(&object.source))?;
        let (rig, mut images) = views.into_parts();
        for image in &mut images {
            image.depth = None;
        }
        ViewSet::new(rig, images)
    }

    /// Renders every sample into `dir`, written whole: into a staging folder beside it, then
    /// renamed into place (an earlier dataset there is replaced only once the new one is
    /// complete; on any error `dir` is left as it was). `dir` must pass
    /// [`check_dataset_dir`], checked first. `progress` gets one [`Stage::Render`] event
    /// per finished sample.
    pub fn write(&self, dir: impl AsRef<Path>, progress: &mut dyn FnMut(Progress)) -> Result<DatasetManifest> {
        let dir = dir.as_ref();
        check_dataset_dir(dir)?;
        let manifest = self.manifest();
        let json = serde_json::to_vec_pretty(&manifest).map_err(|e| Error::invalid("dataset.json", e.to_string()))?;
        let total = self.samples.len();
        write_dir_atomic(dir, MANIFEST_FILE, |staging| {
            progress(Progress::new(Stage::Render, 0, total, None));
            for (i, (_, sample)) in self.samples.iter().enumerate() {
                self.render_sample(i)?.save(staging.join(&sample.id))?;
                progress(Progress::new(Stage::Render, i + 1, total, None));
            }
            let path = staging.join(MANIFEST_FILE);
            std::fs::write(&path, &json).map_err(|e| Error::io(&path, e))
        })?;
        Ok(manifest)
    }
}

/// Fails unless `dir` can receive a dataset without losing anything: a folder name whose
/// parent exists, and either absent, an empty folder, or an earlier dataset (a
/// `dataset.json` of this format, and otherwise only the sample folders it lists, holding
/// only view-set files), which the new one replaces as a whole. Commands call it before
/// any work.
pub fn check_dataset_dir(dir: impl AsRef<Path>) -> Result<()> {
    let dir = dir.as_ref();
    let field = || format!("output folder {}", dir.display());
    if !w3d_core::io::replaceable_folder(dir)? {
        return Ok(());
    }
    let entries: Vec<std::fs::DirEntry> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .collect::<std::io::Result<_>>()
        .map_err(|e| Error::io(dir, e))?;
    if entries.is_empty() {
        return Ok(());
    }
    let refuse = |what: String| {
        Err(Error::invalid(
            field(),
            format!("a new or empty folder, or an earlier dataset (which is replaced); {what}: choose another --out"),
        ))
    };
    if !dir.join(MANIFEST_FILE).is_file() {
        return refuse(format!("it holds {} and no {MANIFEST_FILE}", entries[0].path().display()));
    }
    let manifest = match DatasetManifest::read(dir) {
        Ok(m) => m,
        Err(e) => return refuse(format!("its {MANIFEST_FILE} is not one ({e})")),
    };
    for entry in entries {
        let name = entry.file_name();
        let path = entry.path();
        let kind = entry.file_type().map_err(|e| Error::io(&path, e))?;
        if kind.is_file() && name == MANIFEST_FILE {
            continue;
        }
        let listed = name.to_str().is_some_and(|n| manifest.samples.iter().any(|s| s.id == n));
        if !(kind.is_dir() && listed) {
            return refuse(format!("{} is not one of its samples", path.display()));
        }
        if let Err(e) = ViewSet::check_output_dir(&path) {
            return refuse(format!("sample folder {} holds other files ({e})", path.display()));
        }
    }
    Ok(())
}
