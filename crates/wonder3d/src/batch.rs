//! Many objects in one process: a [`Manifest`] of items (images, or view-set folders), each
//! turned into a textured mesh in its own output folder, with one item's failure recorded
//! and the batch going on, resumable after a crash, and split into shards across machines
//! by the scheduler that starts them (Kubernetes Indexed Jobs, Slurm job arrays).
//!
//! The layout of the output folder `OUT` (several shards may share it):
//!
//! | path | what |
//! |---|---|
//! | `OUT/<id>/mesh.glb` | the textured mesh of item `<id>` |
//! | `OUT/<id>/report.json` | the [`Report`] of its run (stage timings, reconstruction, texture) |
//! | `OUT/<id>/views/` | the generated views (image items, with [`BatchOptions::with_keep_views`]) |
//! | `OUT/<id>/done.json` | written last: every file of the folder with its size and FNV-1a hash |
//! | `OUT/reports/<shard>.jsonl` | one [`ItemRecord`] per line, appended as items finish |
//! | `OUT/reports/<shard>.summary.json` | the [`BatchSummary`] of the shard's last run |
//!
//! An item's folder is written into a staging folder and renamed into place whole
//! ([`w3d_core::io::write_dir_atomic`]), so it is either absent or complete; `--resume`
//! skips the items whose `done.json` matches their files and runs the others again.
//!
//! ```
//! use wonder3d::batch::{Batch, BatchOptions, Manifest, Shard};
//! use wonder3d::{Preset, ViewRig};
//!
//! # let dir = tempfile::tempdir().unwrap();
//! let spot = wonder3d::demo::bundled_spot()?;
//! wonder3d::raster::render_oracle_views(&spot, &ViewRig::wonder3d_ortho(), 64)?.save(dir.path().join("spot"))?;
//! // One item per line: an image file or a view-set folder (or a JSON object with options),
//! // relative to the manifest's folder.
//! let manifest = Manifest::parse("spot\n{\"input\": \"spot\", \"id\": \"spot-fast\", \"preset\": \"fast\"}\n", dir.path(), "items.txt")?;
//! let options = BatchOptions::new(dir.path().join("out")).with_preset(Preset::Fast).with_texture_size(256);
//! let summary = Batch::new(options).run(&manifest, &|_event| {})?;
//! assert_eq!((summary.ok, summary.failed), (2, 0));
//! assert!(dir.path().join("out/spot-fast/mesh.glb").is_file());
//! # assert_eq!(Shard::parse("1/4")?.owns(5), true);
//! # Ok::<(), wonder3d::Error>(())
//! ```

use std::collections::{HashMap, HashSet};
use std::fs::File;
use std::io::Write;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant, SystemTime};

use serde::{Deserialize, Serialize};
use w3d_core::io::{fnv1a64, write_atomic, write_dir_atomic};
use w3d_core::{Error, Result, ViewSet};
use w3d_recon::Preset;

use crate::outputs::{check_out_folder, resolved};
use crate::pipeline::{Pipeline, Report, Seconds};
use crate::progress::Progress;

/// Where the output folders of `mine` (replaced whole when their item is written) and the
/// report folder (appended to) lie, resolved through the file system where they exist, so
/// inputs can be checked against them in one lookup each, whatever the manifest's size.
struct BatchOutputs {
    out: PathBuf,
    ids: HashSet<String>,
}

impl BatchOutputs {
    fn new(options: &BatchOptions, mine: &[&Item]) -> BatchOutputs {
        BatchOutputs { out: resolved(&options.out), ids: mine.iter().map(|i| i.id.clone()).collect() }
    }

    /// The output folder or report folder that `path` lies in (`None` when outside all).
    fn holding(&self, path: &Path) -> Option<PathBuf> {
        let rest = resolved(path).strip_prefix(&self.out).ok()?.to_path_buf();
        let first = rest.components().next()?.as_os_str().to_string_lossy().into_owned();
        (first == REPORTS_DIR || self.ids.contains(&first)).then(|| self.out.join(first))
    }
}

/// Fails when an input of any item, or the manifest file itself, lies inside an output
/// folder this shard replaces as a whole (an item's `OUT/ID`), or inside the report folder:
/// the input would be deleted with the folder's old contents, or overwritten, before or while
/// it is read (a rerun would find the manifest gone or appended to); and when the output
/// folder lies inside an input (a view folder would fill with results).
fn check_inputs_outside_outputs(options: &BatchOptions, manifest: &Manifest, mine: &[&Item]) -> Result<()> {
    let outputs = BatchOutputs::new(options, mine);
    if let Some(path) = &manifest.path
        && let Some(folder) = outputs.holding(path)
    {
        return Err(Error::invalid(
            "MANIFEST",
            format!(
                "a file outside the batch's output folders, but {} lies in {}, which this batch writes",
                path.display(),
                folder.display()
            ),
        ));
    }
    for item in &manifest.items {
        if outputs.out.starts_with(resolved(&item.input)) {
            return Err(Error::invalid(
                format!("output folder {}", options.out.display()),
                format!(
                    "a folder outside the inputs, but it lies in {} (manifest line {}), which would fill with \
                     results",
                    item.input.display(),
                    item.line
                ),
            ));
        }
        if let Some(folder) = outputs.holding(&item.input) {
            return Err(Error::invalid(
                format!("manifest line {} input", item.line),
                format!(
                    "a path outside the batch's output folders, but {} lies in {}, which this batch writes (item \
                     folders are replaced as a whole)",
                    item.input.display(),
                    folder.display()
                ),
            ));
        }
    }
    Ok(())
}

/// An item folder's record of a finished item, written last: what a resumed batch checks.
const DONE_FILE: &str = "done.json";

/// The largest manifest read (bytes): far above a million items, small enough that a wrong
/// file (a video, `/dev/zero`) is refused instead of read.
pub const MAX_MANIFEST_BYTES: u64 = 256 << 20;

/// The longest item id (characters).
pub const MAX_ID_LEN: usize = 128;

/// The folder under `OUT` holding the reports; no item may take this id.
pub const REPORTS_DIR: &str = "reports";

/// What an item's input is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputKind {
    /// An image file (a photo, or RGBA with the object masked by alpha): needs a model.
    Image,
    /// A view-set folder (`cameras.json` + normal, mask and colour images), as written by
    /// `wonder3d render` or `wonder3d generate`: reconstruction and texture only.
    Views,
}

/// Per-item settings a manifest line may give; what it leaves out comes from the
/// [`BatchOptions`] (reconstruction, texture) or the model's options (sampling).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
#[non_exhaustive]
pub struct ItemOptions {
    /// Reconstruction preset.
    pub preset: Option<Preset>,
    /// Side of the baked texture (texels).
    pub texture_size: Option<u32>,
    /// Sampling noise seed.
    pub seed: Option<u64>,
    /// Sampling steps.
    pub steps: Option<usize>,
    /// Classifier-free guidance scale.
    pub guidance: Option<f64>,
    /// Sampler name (`ddim`, `dpmpp-2m` or `unipc`).
    pub sampler: Option<String>,
    /// Camera type of the generated views (`ortho` or `persp`).
    pub camera: Option<String>,
}

/// One line of a [`Manifest`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Item {
    /// The item's name: its output folder under `OUT` and its key in the reports.
    pub id: String,
    /// The input file or folder (relative paths resolved against the manifest's folder).
    pub input: PathBuf,
    /// Image or view folder.
    pub kind: InputKind,
    /// Settings of this item.
    pub options: ItemOptions,
    /// 1-based line number in the manifest (for messages).
    pub line: usize,
}

/// A JSON line of a manifest, as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ItemLine {
    input: PathBuf,
    id: Option<String>,
    kind: Option<InputKind>,
    preset: Option<String>,
    texture_size: Option<u32>,
    seed: Option<u64>,
    steps: Option<usize>,
    guidance: Option<f64>,
    sampler: Option<String>,
    camera: Option<String>,
}

/// The items of a batch, in order. Each non-empty line that does not start with `#` is one
/// item: either a path (an image file or a view-set folder), or a JSON object
/// `{"input": PATH, "id": ..., "kind": "image"|"views", "preset": "fast"|"default"|"quality",
/// "texture_size": N, "seed": N, "steps": N, "guidance": G, "sampler": "ddim"|"dpmpp-2m"|"unipc",
/// "camera": "ortho"|"persp"}` where only `input` is required (JSON lines). Ids default to
/// the input path as written, without its extension, with every character outside
/// `A-Z a-z 0-9 . _ -` replaced by `_`; they must be unique. The kind defaults to
/// `views` for a folder and `image` otherwise.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Manifest {
    /// The items, in manifest order (the order shards are dealt from).
    pub items: Vec<Item>,
    /// The file the manifest was read from ([`Manifest::read`]); `None` when parsed from text.
    /// [`Batch::check`] refuses a manifest inside a folder the batch writes.
    pub path: Option<PathBuf>,
}

impl Manifest {
    /// Reads a manifest file; relative inputs are resolved against its folder. The whole
    /// manifest is checked before anything runs; errors name the file and line.
    pub fn read(path: impl AsRef<Path>) -> Result<Manifest> {
        let path = path.as_ref();
        let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        if !meta.is_file() {
            return Err(Error::format(path, "manifest", "a text file with one item per line"));
        }
        if meta.len() > MAX_MANIFEST_BYTES {
            return Err(Error::format(
                path,
                "manifest",
                format!("at most {MAX_MANIFEST_BYTES} bytes, got {}: split it into several batches", meta.len()),
            ));
        }
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let text = String::from_utf8(bytes).map_err(|e| {
            Error::format(
                path,
                "manifest",
                format!("UTF-8 text (invalid byte at offset {})", e.utf8_error().valid_up_to()),
            )
        })?;
        let base = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let manifest = Manifest::parse(&text, base, &path.display().to_string())?;
        Ok(Manifest { path: Some(path.to_path_buf()), ..manifest })
    }

    /// Parses manifest text; relative inputs are resolved against `base`, and `source` names
    /// the manifest in errors.
    pub fn parse(text: &str, base: &Path, source: &str) -> Result<Manifest> {
        let mut items = Vec::new();
        let mut seen: HashMap<String, usize> = HashMap::new();
        for (index, raw) in text.lines().enumerate() {
            let line = index + 1;
            let trimmed = raw.trim();
            if trimmed.is_empty() || trimmed.starts_with('#') {
                continue;
            }
            let field = |what: &str| format!("{source} line {line}: {what}");
            if trimmed.contains('\0') {
                return Err(Error::invalid(field("input"), "a line without NUL bytes (is this a text file?)"));
            }
            let (written, parsed) = if trimmed.starts_with('{') {
                let parsed: ItemLine = serde_json::from_str(trimmed)
                    .map_err(|e| Error::invalid(field("JSON item"), format!("{{\"input\": PATH, …}} ({e})")))?;
                (parsed.input.clone(), Some(parsed))
            } else {
                (PathBuf::from(trimmed), None)
            };
            if written.as_os_str().is_empty() {
                return Err(Error::invalid(field("input"), "a file or folder path, got an empty one"));
            }
            let input = if written.is_absolute() { written.clone() } else { base.join(&written) };
            let id = match parsed.as_ref().and_then(|p| p.id.clone()) {
                Some(id) => {
                    check_id(&id).map_err(|why| Error::invalid(field("id"), why))?;
                    id
                }
                None => {
                    let id = derived_id(&written);
                    check_id(&id).map_err(|why| {
                        Error::invalid(field("input"), format!("{why} (give the item an explicit \"id\")"))
                    })?;
                    id
                }
            };
            if let Some(first) = seen.insert(id.clone(), line) {
                return Err(Error::invalid(
                    field("id"),
                    format!("a unique item id, but {id:?} is also the id of line {first}: give one an explicit \"id\""),
                ));
            }
            let kind = parsed.as_ref().and_then(|p| p.kind).unwrap_or(if input.is_dir() {
                InputKind::Views
            } else {
                InputKind::Image
            });
            let options = match parsed {
                Some(p) => item_options(p).map_err(|(name, why)| Error::invalid(field(name), why))?,
                None => ItemOptions::default(),
            };
            items.push(Item { id, input, kind, options, line });
        }
        if items.is_empty() {
            return Err(Error::invalid(source, "at least one item (a path or a JSON object per line)"));
        }
        Ok(Manifest { items, path: None })
    }
}

/// Checks and converts a JSON line's settings; errors are (field, what was expected).
fn item_options(p: ItemLine) -> std::result::Result<ItemOptions, (&'static str, String)> {
    let preset = p.preset.map(|s| Preset::from_str(&s).map_err(|e| ("preset", e.to_string()))).transpose()?;
    if let Some(size) = p.texture_size {
        w3d_texture::TextureOptions::default()
            .with_size(size)
            .validate()
            .map_err(|e| ("texture_size", e.to_string()))?;
    }
    if p.steps.is_some_and(|s| !(1..=1000).contains(&s)) {
        return Err(("steps", "a step count in 1..=1000".into()));
    }
    if p.guidance.is_some_and(|g| !(g.is_finite() && (0.0..=100.0).contains(&g))) {
        return Err(("guidance", "a finite guidance scale in [0, 100]".into()));
    }
    #[cfg(feature = "diffusion")]
    {
        if let Some(s) = &p.sampler {
            w3d_diffusion::SamplerKind::from_str(s).map_err(|e| ("sampler", e.to_string()))?;
        }
        if let Some(c) = &p.camera {
            w3d_diffusion::CameraType::from_str(c).map_err(|e| ("camera", e.to_string()))?;
        }
    }
    Ok(ItemOptions {
        preset,
        texture_size: p.texture_size,
        seed: p.seed,
        steps: p.steps,
        guidance: p.guidance,
        sampler: p.sampler,
        camera: p.camera,
    })
}

/// The id of an item given by path: the path as written, without extension, with unsafe
/// characters replaced.
fn derived_id(written: &Path) -> String {
    let without_ext = match written.extension() {
        Some(_) if !written.is_dir() => written.with_extension(""),
        _ => written.to_path_buf(),
    };
    let s = without_ext.to_string_lossy();
    let s = s.trim_start_matches("./").trim_matches('/');
    let id: String = s.chars().map(|c| if c.is_ascii_alphanumeric() || "._-".contains(c) { c } else { '_' }).collect();
    id.trim_start_matches('.').to_string()
}

/// Why `id` cannot name an output folder, if it cannot.
fn check_id(id: &str) -> std::result::Result<(), String> {
    if id.is_empty() || id.len() > MAX_ID_LEN {
        return Err(format!("an id of 1 to {MAX_ID_LEN} characters, got {} characters", id.len()));
    }
    if !id.chars().all(|c| c.is_ascii_alphanumeric() || "._-".contains(c)) || id.starts_with('.') {
        return Err(format!("an id of letters, digits, `.`, `_` and `-` not starting with `.`, got {id:?}"));
    }
    if id == REPORTS_DIR {
        return Err(format!("an id other than {REPORTS_DIR:?} (the reports folder)"));
    }
    Ok(())
}

/// Which part of a manifest one process runs: item `i` (0-based, manifest order) belongs to
/// shard `i mod count`, so shards get interleaved items and similar costs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    index: usize,
    count: usize,
}

impl Default for Shard {
    fn default() -> Self {
        Shard::ALL
    }
}

impl Shard {
    /// The whole manifest (shard 0 of 1).
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Shard `index` (0-based) of `count`.
    pub fn new(index: usize, count: usize) -> Result<Shard> {
        if count == 0 || index >= count {
            return Err(Error::invalid("shard", format!("an index below the shard count, got {index}/{count}")));
        }
        Ok(Shard { index, count })
    }

    /// Parses `I/N` (0-based index `I` of `N` shards), as `--shard` takes it.
    pub fn parse(s: &str) -> Result<Shard> {
        let bad = || Error::invalid("--shard", format!("I/N with 0 ≤ I < N (e.g. 0/4), got {s:?}"));
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (i, n) = (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        Shard::new(i, n).map_err(|_| bad())
    }

    /// The shard a scheduler assigned through the environment, if any:
    /// - Slurm job arrays: `SLURM_ARRAY_TASK_ID` − `SLURM_ARRAY_TASK_MIN` (0 when unset) of
    ///   `SLURM_ARRAY_TASK_COUNT`;
    /// - Kubernetes Indexed Jobs: `JOB_COMPLETION_INDEX` of `W3D_SHARD_COUNT` (Kubernetes
    ///   does not pass the completion count to pods: set it in the Job's `env` to the Job's
    ///   `completions`, as `docs/scale.md`'s manifest does).
    pub fn from_env() -> Result<Option<Shard>> {
        Shard::from_vars(|name| std::env::var(name).ok())
    }

    /// [`Shard::from_env`] over any variable lookup (for tests and wrappers).
    pub fn from_vars(var: impl Fn(&str) -> Option<String>) -> Result<Option<Shard>> {
        let number = |name: &str| -> Result<Option<usize>> {
            var(name)
                .map(|v| {
                    v.trim().parse::<usize>().map_err(|_| {
                        Error::invalid(format!("environment variable {name}"), format!("a whole number, got {v:?}"))
                    })
                })
                .transpose()
        };
        if let Some(id) = number("SLURM_ARRAY_TASK_ID")? {
            let count = number("SLURM_ARRAY_TASK_COUNT")?.ok_or_else(|| {
                Error::invalid("environment variable SLURM_ARRAY_TASK_COUNT", "set beside SLURM_ARRAY_TASK_ID")
            })?;
            let min = number("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let index = id.checked_sub(min).ok_or_else(|| {
                Error::invalid("SLURM_ARRAY_TASK_ID", format!("at least SLURM_ARRAY_TASK_MIN ({min}), got {id}"))
            })?;
            return Shard::new(index, count).map(Some).map_err(|_| {
                Error::invalid(
                    "Slurm array",
                    format!(
                        "a contiguous array (--array=0-{}): task {id} − min {min} ≥ count {count}",
                        count.max(1) - 1
                    ),
                )
            });
        }
        if let Some(index) = number("JOB_COMPLETION_INDEX")? {
            let count = number("W3D_SHARD_COUNT")?.ok_or_else(|| {
                Error::invalid(
                    "environment variable W3D_SHARD_COUNT",
                    "the Job's completion count beside JOB_COMPLETION_INDEX (Kubernetes does not pass it; see docs/scale.md), or --shard I/N",
                )
            })?;
            return Shard::new(index, count).map(Some).map_err(|_| {
                Error::invalid("JOB_COMPLETION_INDEX", format!("below W3D_SHARD_COUNT ({count}), got {index}"))
            });
        }
        Ok(None)
    }

    /// 0-based index of this shard.
    pub fn index(self) -> usize {
        self.index
    }

    /// Number of shards.
    pub fn count(self) -> usize {
        self.count
    }

    /// Whether the item at `position` (0-based, manifest order) belongs to this shard.
    pub fn owns(self, position: usize) -> bool {
        position % self.count == self.index
    }

    /// The shard's name in report file names: `all`, or `shard-0003-of-0016`.
    pub fn tag(self) -> String {
        if self.count == 1 { "all".into() } else { format!("shard-{:04}-of-{:04}", self.index, self.count) }
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// How a batch runs. Built with chained setters so new options never break callers.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct BatchOptions {
    /// Output folder (created if missing; its parent must exist).
    pub out: PathBuf,
    /// The part of the manifest this process runs.
    pub shard: Shard,
    /// Skip items whose outputs are complete and valid, run the rest (failed, missing or
    /// damaged ones) again; without it, earlier results of this shard in `out` are an error.
    pub resume: bool,
    /// Items processed at once in this process (each on its own thread; generation is one
    /// at a time, reconstruction and texturing overlap). At least 1.
    pub jobs: usize,
    /// Wall-clock limit per item, checked at every progress event (each optimisation or
    /// sampling step); an item past it is recorded as timed out.
    pub timeout: Option<Duration>,
    /// Keep the generated views of image items in `OUT/<id>/views/`.
    pub keep_views: bool,
    /// Reconstruction preset of items that give none.
    pub preset: Preset,
    /// Texture side (texels) of items that give none.
    pub texture_size: u32,
    /// Texture the meshes (else `mesh.glb` is the closed untextured mesh).
    pub texture: bool,
    /// Fits tried on the generated views of image items, the best kept (default
    /// [`crate::pipeline::GENERATED_VIEW_STARTS`]; [`Pipeline::with_generated_view_starts`]). View
    /// items get their preset's one.
    pub generated_view_starts: usize,
}

impl BatchOptions {
    /// Defaults: the whole manifest, no resume, one job, no timeout, the default preset and
    /// texture size, generated views not kept.
    pub fn new(out: impl Into<PathBuf>) -> BatchOptions {
        BatchOptions {
            out: out.into(),
            shard: Shard::ALL,
            resume: false,
            jobs: 1,
            timeout: None,
            keep_views: false,
            preset: Preset::Default,
            texture_size: w3d_texture::TextureOptions::default().size,
            texture: true,
            generated_view_starts: crate::pipeline::GENERATED_VIEW_STARTS,
        }
    }

    w3d_core::setters! {
        /// Textures the meshes or not.
        with_texture(texture: bool);
        /// Runs only `shard`.
        with_shard(shard: Shard);
        /// Resumes an earlier run (see [`BatchOptions::resume`]).
        with_resume(resume: bool);
        /// Items at once in this process.
        with_jobs(jobs: usize);
        /// Wall-clock limit per item.
        with_timeout(timeout: Option<Duration>);
        /// Keeps generated views.
        with_keep_views(keep_views: bool);
        /// Default reconstruction preset.
        with_preset(preset: Preset);
        /// Default texture size.
        with_texture_size(texture_size: u32);
        /// Fits tried on the generated views of image items.
        with_generated_view_starts(generated_view_starts: usize);
    }

    /// The report of this shard's items, one JSON object per line.
    pub fn report_path(&self) -> PathBuf {
        self.out.join(REPORTS_DIR).join(format!("{}.jsonl", self.shard.tag()))
    }

    /// The summary of this shard's last run.
    pub fn summary_path(&self) -> PathBuf {
        self.out.join(REPORTS_DIR).join(format!("{}.summary.json", self.shard.tag()))
    }
}

/// How an item ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ItemStatus {
    /// Its folder was written.
    Ok,
    /// It failed (the error says why); no folder was written.
    Failed,
    /// It ran past [`BatchOptions::timeout`]; no folder was written.
    TimedOut,
    /// `--resume` found its outputs complete and valid.
    Skipped,
}

/// One line of the batch report.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct ItemRecord {
    /// The item's id.
    pub id: String,
    /// Its manifest line.
    pub line: usize,
    /// Its input path.
    pub input: PathBuf,
    /// Image or views.
    pub kind: InputKind,
    /// How it ended.
    pub status: ItemStatus,
    /// The error, for failed and timed-out items.
    pub error: Option<String>,
    /// Stage timings of a finished run.
    pub seconds: Option<Seconds>,
    /// Wall-clock seconds the item took in this process, whatever its status.
    pub wall_seconds: f64,
    /// Triangles of the untextured mesh.
    pub triangles: Option<usize>,
    /// The item's output folder, when it has one.
    pub folder: Option<PathBuf>,
    /// The shard that ran it (`I/N`).
    pub shard: String,
    /// When it ended, in seconds since the Unix epoch.
    pub finished_unix: f64,
}

/// Counts and rates of one run of a shard.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct BatchSummary {
    /// The shard (`I/N`).
    pub shard: String,
    /// Items of this shard.
    pub items: usize,
    /// Items written.
    pub ok: usize,
    /// Items that failed.
    pub failed: usize,
    /// Items past the timeout.
    pub timed_out: usize,
    /// Items skipped by `--resume`.
    pub skipped: usize,
    /// Jobs (items at once).
    pub jobs: usize,
    /// Wall-clock seconds of the run.
    pub seconds: f64,
    /// Items processed (not skipped) per hour of this run.
    pub items_per_hour: f64,
}

/// Events of a running batch, for progress bars and logs (called from the job threads).
#[derive(Debug, Clone, Copy)]
#[non_exhaustive]
pub enum BatchEvent<'a> {
    /// The shard's items are known: `total` to run, `skipped` already done.
    Planned {
        /// Items this run will process.
        total: usize,
        /// Items `--resume` skips.
        skipped: usize,
    },
    /// An item started.
    Started {
        /// Its id.
        id: &'a str,
    },
    /// Progress inside an item.
    Progress {
        /// Its id.
        id: &'a str,
        /// The pipeline event.
        progress: Progress,
    },
    /// An item ended (also sent for skipped items).
    Finished(&'a ItemRecord),
}

/// A file an item folder's `done.json` lists.
#[derive(Debug, Serialize, Deserialize)]
struct DoneFile {
    name: String,
    bytes: u64,
    fnv1a64: String,
}

/// `OUT/<id>/done.json`.
#[derive(Debug, Serialize, Deserialize)]
struct Done {
    id: String,
    files: Vec<DoneFile>,
}

/// The payload that unwinds an item past its deadline (never shown: `resume_unwind` does
/// not run the panic hook).
struct TimedOut;

/// A batch runner: options plus, for image items, a model (feature `diffusion`).
pub struct Batch {
    options: BatchOptions,
    #[cfg(feature = "diffusion")]
    model: Option<Mutex<crate::generate::Generator>>,
}

impl std::fmt::Debug for Batch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Batch").field("options", &self.options).field("model", &self.has_model()).finish()
    }
}

impl Batch {
    /// A batch without a model: view-set items only.
    pub fn new(options: BatchOptions) -> Batch {
        Batch {
            options,
            #[cfg(feature = "diffusion")]
            model: None,
        }
    }

    /// Uses `model` for image items (loaded once for the whole batch).
    #[cfg(feature = "diffusion")]
    pub fn with_model(mut self, model: crate::generate::Generator) -> Batch {
        self.model = Some(Mutex::new(model));
        self
    }

    /// The options.
    pub fn options(&self) -> &BatchOptions {
        &self.options
    }

    /// Whether image items can run.
    pub fn has_model(&self) -> bool {
        #[cfg(feature = "diffusion")]
        return self.model.is_some();
        #[cfg(not(feature = "diffusion"))]
        false
    }

    /// Checks everything that can be checked before work (and before loading a model):
    /// the options, the output folder, image items when `with_model` is false, and earlier
    /// results of this shard when not resuming. Returns the items of this shard.
    pub fn check<'m>(options: &BatchOptions, manifest: &'m Manifest, with_model: bool) -> Result<Vec<&'m Item>> {
        if options.jobs == 0 {
            return Err(Error::invalid("jobs", "at least 1 item at a time"));
        }
        crate::pipeline::check_generated_view_starts(options.generated_view_starts)?;
        w3d_texture::TextureOptions::default().with_size(options.texture_size).validate()?;
        check_out_folder(&options.out)?;
        let mine: Vec<&Item> =
            manifest.items.iter().enumerate().filter(|(i, _)| options.shard.owns(*i)).map(|(_, item)| item).collect();
        // Without a model a missing input would be taken for an image and blamed on the
        // missing model: name the path instead.
        if !with_model && let Some(item) = mine.iter().find(|i| i.kind == InputKind::Image && !i.input.exists()) {
            return Err(Error::invalid(
                format!("manifest line {} input", item.line),
                format!("an existing image file or view-set folder ({} does not exist)", item.input.display()),
            ));
        }
        if !with_model && let Some(item) = mine.iter().find(|i| i.kind == InputKind::Image) {
            let images = mine.iter().filter(|i| i.kind == InputKind::Image).count();
            return Err(Error::invalid(
                "model",
                format!(
                    "a model for the {images} image item(s) of this shard (first: line {}, {}): pass --weights DIR \
                         (docs/weights.md), or list view-set folders only",
                    item.line,
                    item.input.display()
                ),
            ));
        }
        check_inputs_outside_outputs(options, manifest, &mine)?;
        if !options.resume {
            let report = options.report_path();
            let earlier = report
                .exists()
                .then(|| report.clone())
                .or_else(|| mine.iter().map(|i| options.out.join(&i.id)).find(|p| p.exists()));
            if let Some(path) = earlier {
                return Err(Error::invalid(
                    format!("output folder {}", options.out.display()),
                    format!(
                        "no earlier results of shard {} ({} exists): pass --resume to continue that run, or choose \
                         another --out",
                        options.shard,
                        path.display()
                    ),
                ));
            }
        }
        Ok(mine)
    }

    /// Runs this process's shard of `manifest`: every item not already done (with
    /// [`BatchOptions::resume`]) is processed on one of [`BatchOptions::jobs`] threads, its
    /// folder written atomically and its [`ItemRecord`] appended to the report; a failing
    /// item is recorded and the batch goes on. Errors only for what stops the whole batch
    /// (options, output folder, the report file).
    pub fn run(&self, manifest: &Manifest, events: &(dyn Fn(BatchEvent<'_>) + Sync)) -> Result<BatchSummary> {
        let start = Instant::now();
        let options = &self.options;
        let mine = Batch::check(options, manifest, self.has_model())?;
        let reports = options.out.join(REPORTS_DIR);
        std::fs::create_dir_all(&reports).map_err(|e| Error::io(&reports, e))?;
        let report_path = options.report_path();
        let report = Mutex::new(
            File::options().create(true).append(true).open(&report_path).map_err(|e| Error::io(&report_path, e))?,
        );
        let shard = options.shard.to_string();
        let (mut todo, mut skipped) = (Vec::new(), 0);
        for item in mine.iter().copied() {
            remove_stale_staging(&options.out, &item.id);
            if options.resume && is_done(&options.out.join(&item.id), &item.id) {
                let record = ItemRecord {
                    status: ItemStatus::Skipped,
                    folder: Some(options.out.join(&item.id)),
                    ..record_of(item, &shard)
                };
                append(&report, &report_path, &record)?;
                events(BatchEvent::Finished(&record));
                skipped += 1;
            } else {
                todo.push(item);
            }
        }
        events(BatchEvent::Planned { total: todo.len(), skipped });
        let next = AtomicUsize::new(0);
        let counts = Mutex::new((0usize, 0usize, 0usize));
        let failure: Mutex<Option<Error>> = Mutex::new(None);
        let worker = || {
            loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(item) = todo.get(i) else { break };
                if failure.lock().unwrap_or_else(|e| e.into_inner()).is_some() {
                    break;
                }
                events(BatchEvent::Started { id: &item.id });
                let record = self.run_item(item, &shard, events);
                {
                    let mut c = counts.lock().unwrap_or_else(|e| e.into_inner());
                    match record.status {
                        ItemStatus::Ok => c.0 += 1,
                        ItemStatus::Failed => c.1 += 1,
                        ItemStatus::TimedOut => c.2 += 1,
                        ItemStatus::Skipped => {}
                    }
                }
                if let Err(e) = append(&report, &report_path, &record) {
                    failure.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(e);
                    break;
                }
                events(BatchEvent::Finished(&record));
            }
        };
        let jobs = options.jobs.min(todo.len()).max(1);
        std::thread::scope(|scope| {
            for _ in 1..jobs {
                scope.spawn(worker);
            }
            worker();
        });
        if let Some(e) = failure.into_inner().unwrap_or_else(|e| e.into_inner()) {
            return Err(e);
        }
        let (ok, failed, timed_out) = counts.into_inner().unwrap_or_else(|e| e.into_inner());
        let seconds = start.elapsed().as_secs_f64();
        let processed = ok + failed + timed_out;
        let summary = BatchSummary {
            shard,
            items: mine.len(),
            ok,
            failed,
            timed_out,
            skipped,
            jobs,
            seconds,
            items_per_hour: if seconds > 0.0 { processed as f64 * 3600.0 / seconds } else { 0.0 },
        };
        let json = serde_json::to_vec_pretty(&summary).map_err(|e| Error::invalid("batch summary", e.to_string()))?;
        let summary_path = options.summary_path();
        write_atomic(&summary_path, |w| w.write_all(&json).map_err(|e| Error::io(&summary_path, e)))?;
        Ok(summary)
    }

    /// Runs one item to its record: errors, timeouts and panics become the record's status.
    fn run_item(&self, item: &Item, shard: &str, events: &(dyn Fn(BatchEvent<'_>) + Sync)) -> ItemRecord {
        let start = Instant::now();
        let deadline = self.options.timeout.map(|t| start + t);
        let folder = self.options.out.join(&item.id);
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
            let mut progress = |p: Progress| {
                if deadline.is_some_and(|d| Instant::now() > d) {
                    std::panic::resume_unwind(Box::new(TimedOut));
                }
                events(BatchEvent::Progress { id: &item.id, progress: p });
            };
            self.process(item, &folder, &mut progress)
        }));
        let base = ItemRecord { wall_seconds: start.elapsed().as_secs_f64(), ..record_of(item, shard) };
        match outcome {
            Ok(Ok(report)) => ItemRecord {
                status: ItemStatus::Ok,
                seconds: Some(report.seconds),
                triangles: Some(report.triangles),
                folder: Some(folder),
                ..base
            },
            Ok(Err(e)) => ItemRecord { status: ItemStatus::Failed, error: Some(e.to_string()), ..base },
            Err(payload) if payload.is::<TimedOut>() => ItemRecord {
                status: ItemStatus::TimedOut,
                error: Some(format!(
                    "stopped after {:.1} s: over the per-item timeout of {:.1} s",
                    base.wall_seconds,
                    self.options.timeout.unwrap_or_default().as_secs_f64()
                )),
                ..base
            },
            Err(payload) => {
                let message = payload
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| payload.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic".into());
                ItemRecord {
                    status: ItemStatus::Failed,
                    error: Some(format!("internal error (panic): {message}")),
                    ..base
                }
            }
        }
    }

    /// The work of one item: views (loaded or generated) → mesh → texture → its folder.
    fn process(&self, item: &Item, folder: &Path, progress: &mut dyn FnMut(Progress)) -> Result<Report> {
        let o = &item.options;
        let pipeline = Pipeline::new()
            .with_preset(o.preset.unwrap_or(self.options.preset))
            .with_generated_view_starts(self.options.generated_view_starts);
        let pipeline = match self.options.texture {
            true => pipeline.with_texture_size(o.texture_size.unwrap_or(self.options.texture_size)),
            false => pipeline.without_texture(),
        };
        let (output, generated) = match item.kind {
            InputKind::Views => {
                let views = ViewSet::load(&item.input)?;
                (pipeline.from_views(&views, progress)?, None)
            }
            InputKind::Image => self.generate_and_extract(&pipeline, item, progress)?,
        };
        if output.mesh.positions().iter().flatten().any(|c| !c.is_finite()) {
            return Err(Error::invalid("mesh", "finite vertex positions (the reconstruction produced NaN)"));
        }
        let report = output.report.clone();
        let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::invalid("report", e.to_string()))?;
        write_dir_atomic(folder, DONE_FILE, |staging| {
            output.save(staging.join("mesh.glb"))?;
            std::fs::write(staging.join("report.json"), &json)
                .map_err(|e| Error::io(staging.join("report.json"), e))?;
            if let Some(generated) = &generated {
                save_views(generated, &staging.join("views"))?;
            }
            write_done(staging, &item.id)
        })?;
        Ok(report)
    }

    /// Generates the views of an image item with the batch's model and runs the pipeline on
    /// them; the generated views come back when they are to be kept.
    #[cfg(feature = "diffusion")]
    fn generate_and_extract(
        &self,
        pipeline: &Pipeline,
        item: &Item,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<(crate::pipeline::Output, Option<crate::generate::Generated>)> {
        let model = self.model.as_ref().ok_or_else(|| Error::invalid("model", "a model for image items"))?;
        let image = w3d_core::Image::read(&item.input)?;
        let start = Instant::now();
        let (generated, sample) = {
            // Generation uses every core; one item generates at a time while others reconstruct.
            let model = model.lock().unwrap_or_else(|e| e.into_inner());
            let mut sample = *model.options();
            let o = &item.options;
            sample.seed = o.seed.unwrap_or(sample.seed);
            sample.steps = o.steps.unwrap_or(sample.steps);
            sample.guidance = o.guidance.unwrap_or(sample.guidance);
            if let Some(s) = &o.sampler {
                sample.sampler = s.parse()?;
            }
            if let Some(c) = &o.camera {
                sample.camera = c.parse()?;
            }
            let generated = model.generate_with(&image, &sample, progress).map_err(|e| e.in_file(&item.input))?;
            (generated, sample)
        };
        let keep = self.options.keep_views.then(|| generated.clone());
        let output = pipeline.extract_generated(generated, &sample, start.elapsed().as_secs_f64(), progress)?;
        Ok((output, keep))
    }

    #[cfg(not(feature = "diffusion"))]
    fn generate_and_extract(
        &self,
        _: &Pipeline,
        _: &Item,
        _: &mut dyn FnMut(Progress),
    ) -> Result<(crate::pipeline::Output, Option<std::convert::Infallible>)> {
        Err(Error::invalid("model", "a build with the diffusion model (feature `diffusion`) for image items"))
    }
}

#[cfg(feature = "diffusion")]
fn save_views(generated: &crate::generate::Generated, dir: &Path) -> Result<()> {
    generated.save(dir)
}

#[cfg(not(feature = "diffusion"))]
fn save_views(never: &std::convert::Infallible, _: &Path) -> Result<()> {
    match *never {}
}

/// A record of `item` with nothing measured yet (failed, no folder).
fn record_of(item: &Item, shard: &str) -> ItemRecord {
    ItemRecord {
        id: item.id.clone(),
        line: item.line,
        input: item.input.clone(),
        kind: item.kind,
        status: ItemStatus::Failed,
        error: None,
        seconds: None,
        wall_seconds: 0.0,
        triangles: None,
        folder: None,
        shard: shard.to_string(),
        finished_unix: SystemTime::now().duration_since(SystemTime::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64()),
    }
}

/// Appends one record as a JSON line (one write, so lines of several threads never mix).
fn append(report: &Mutex<File>, path: &Path, record: &ItemRecord) -> Result<()> {
    let mut line = serde_json::to_vec(record).map_err(|e| Error::invalid("batch report", e.to_string()))?;
    line.push(b'\n');
    let mut file = report.lock().unwrap_or_else(|e| e.into_inner());
    file.write_all(&line).and_then(|()| file.flush()).map_err(|e| Error::io(path, e))
}

/// Writes `done.json` into an item's staging folder: every file below it (recursively) with
/// size and hash.
fn write_done(dir: &Path, id: &str) -> Result<()> {
    let mut files = Vec::new();
    list_files(dir, dir, &mut files)?;
    files.sort_by(|a, b| a.name.cmp(&b.name));
    let json = serde_json::to_vec_pretty(&Done { id: id.to_string(), files })
        .map_err(|e| Error::invalid(DONE_FILE, e.to_string()))?;
    std::fs::write(dir.join(DONE_FILE), json).map_err(|e| Error::io(dir.join(DONE_FILE), e))
}

fn list_files(root: &Path, dir: &Path, out: &mut Vec<DoneFile>) -> Result<()> {
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let path = entry.map_err(|e| Error::io(dir, e))?.path();
        if path.is_dir() {
            list_files(root, &path, out)?;
        } else {
            let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
            let name = path.strip_prefix(root).unwrap_or(&path).to_string_lossy().replace('\\', "/");
            out.push(DoneFile { name, bytes: bytes.len() as u64, fnv1a64: fnv1a64(&bytes) });
        }
    }
    Ok(())
}

/// Whether `folder` holds a finished item `id`: a `done.json` whose every file is present
/// with its recorded size and hash.
fn is_done(folder: &Path, id: &str) -> bool {
    let Ok(text) = std::fs::read(folder.join(DONE_FILE)) else { return false };
    let Ok(done) = serde_json::from_slice::<Done>(&text) else { return false };
    done.id == id
        && !done.files.is_empty()
        && done.files.iter().all(|f| {
            let path = folder.join(&f.name);
            !f.name.contains("..")
                && std::fs::metadata(&path).is_ok_and(|m| m.len() == f.bytes)
                && std::fs::read(&path).is_ok_and(|b| fnv1a64(&b) == f.fnv1a64)
        })
}

/// Removes staging and backup folders an interrupted run of this item left in `out`
/// (`.<id>.partial-*`, `.<id>.old-*`).
fn remove_stale_staging(out: &Path, id: &str) {
    let Ok(entries) = std::fs::read_dir(out) else { return };
    let (partial, old) = (format!(".{id}.partial-"), format!(".{id}.old-"));
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with(&partial) || name.starts_with(&old) {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_partition_the_manifest() {
        for count in 1..6 {
            for position in 0..20 {
                let owners = (0..count).filter(|&i| Shard::new(i, count).unwrap().owns(position)).count();
                assert_eq!(owners, 1);
            }
        }
        assert_eq!(Shard::parse("3/16").unwrap().tag(), "shard-0003-of-0016");
        assert_eq!(Shard::ALL.tag(), "all");
        for bad in ["4/4", "1", "a/2", "-1/3", "0/0", ""] {
            assert!(Shard::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn shards_come_from_slurm_and_kubernetes() {
        fn vars<'a>(pairs: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
            move |name: &str| pairs.iter().find(|(k, _)| *k == name).map(|(_, v)| v.to_string())
        }
        assert_eq!(Shard::from_vars(vars(&[])).unwrap(), None);
        let slurm = [("SLURM_ARRAY_TASK_ID", "5"), ("SLURM_ARRAY_TASK_COUNT", "4"), ("SLURM_ARRAY_TASK_MIN", "2")];
        assert_eq!(Shard::from_vars(vars(&slurm)).unwrap(), Some(Shard::new(3, 4).unwrap()));
        let k8s = [("JOB_COMPLETION_INDEX", "7"), ("W3D_SHARD_COUNT", "8")];
        assert_eq!(Shard::from_vars(vars(&k8s)).unwrap(), Some(Shard::new(7, 8).unwrap()));
        let no_count = Shard::from_vars(vars(&[("JOB_COMPLETION_INDEX", "0")])).unwrap_err().to_string();
        assert!(no_count.contains("W3D_SHARD_COUNT"), "{no_count}");
        let outside = [("SLURM_ARRAY_TASK_ID", "9"), ("SLURM_ARRAY_TASK_COUNT", "4")];
        assert!(Shard::from_vars(vars(&outside)).unwrap_err().to_string().contains("contiguous"));
        assert!(Shard::from_vars(vars(&[("JOB_COMPLETION_INDEX", "x")])).unwrap_err().to_string().contains("whole"));
    }

    #[test]
    fn manifests_are_checked_line_by_line() {
        let base = Path::new("/data");
        let m = Manifest::parse(
            "# catalogue\nphotos/mug 1.jpg\n\n{\"input\": \"/abs/views\", \"id\": \"v\", \"kind\": \"views\", \"preset\": \"fast\"}\n",
            base,
            "m.txt",
        )
        .unwrap();
        assert_eq!(m.items.len(), 2);
        assert_eq!((m.items[0].id.as_str(), m.items[0].line, m.items[0].kind), ("photos_mug_1", 2, InputKind::Image));
        assert_eq!(m.items[0].input, Path::new("/data/photos/mug 1.jpg"));
        assert_eq!((m.items[1].kind, m.items[1].options.preset), (InputKind::Views, Some(Preset::Fast)));
        let err = |text: &str| Manifest::parse(text, base, "m.txt").unwrap_err().to_string();
        assert!(err("a.jpg\nb/a.png\na.png\n").contains("line 3"), "{}", err("a.jpg\na.png"));
        assert!(err("{\"input\": \"a\", \"colour\": 1}").contains("line 1"));
        assert!(err("{\"input\": \"a\", \"preset\": \"slow\"}").contains("preset"));
        assert!(err("{\"input\": \"a\", \"id\": \"../x\"}").contains("id"));
        assert!(err("{\"input\": \"a\", \"texture_size\": 0}").contains("texture_size"));
        assert!(err("{\"input\": \"a\", \"guidance\": 1e9}").contains("guidance"));
        assert!(err("reports.png").contains("reports"));
        assert!(err("# nothing\n\n").contains("at least one item"));
    }
}
