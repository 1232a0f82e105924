//! Model weights by Hugging Face Hub id (feature `diffusion`): wherever a checkpoint folder is
//! accepted, `owner/name[@revision][:sub/folder]` names one on the Hub instead, downloaded
//! once into the standard Hugging Face cache and read from there ever after.
//!
//! ```no_run
//! # fn main() -> wonder3d::Result<()> {
//! use wonder3d::weights::{self, Layout};
//!
//! // A local folder is returned as it is; a Hub id becomes the cached snapshot folder,
//! // downloading what is missing (`Stage::Download` events, in bytes).
//! let dir = weights::resolve("flamehaze1115/Wonder3D_plus", &mut |p| eprintln!("{}/{} bytes", p.done, p.total))?;
//! let generator = wonder3d::Generator::load(&dir)?;
//! // A revision and a folder inside the repository; the enhancer's layout.
//! let id: weights::HubId = "me/wonder3d-enhancer@v1:sd15".parse()?;
//! let enhancer = weights::resolve_layout(&id.to_string(), Layout::Enhancer, &mut |_| {})?;
//! # let _ = (generator, enhancer);
//! # Ok(())
//! # }
//! ```
//!
//! **The syntax** ([`HubId`]): `owner/name` (the repository, revision `main`), then optionally
//! `@revision` (a branch, tag or 40-hex commit; `/` allowed, as in `refs/pr/3`), then optionally
//! `:sub/folder` (the model folder inside the repository, where it is not the root). Names are
//! letters, digits, `.`, `_` and `-`; `..`, empty parts and absolute paths are refused. An
//! existing local directory always wins: `ckpts/model` that exists is read as that folder.
//!
//! **Where and how** ([`HubSettings::from_env`]): the endpoint is `HF_ENDPOINT` (default
//! `https://huggingface.co`); the cache is `HF_HUB_CACHE`, else `HF_HOME/hub`, else
//! `~/.cache/huggingface/hub` (`XDG_CACHE_HOME/huggingface/hub` where that is set), the layout
//! `huggingface_hub` (Python) shares: `models--owner--name/{blobs,snapshots,refs}`. A private
//! or gated repository needs `HF_TOKEN` (or the token file of `huggingface-cli login`).
//! `HF_HUB_OFFLINE=1` makes no request: the snapshot must be complete in the cache.
//!
//! **What is downloaded** ([`Layout`]): only the files the loader reads — configs,
//! `model_index.json`, and for each model its `.safetensors` weights (the `.fp16.safetensors`
//! variant where the repository has only that); never `.bin` / `.ckpt` pickles (a model with
//! only those is an error that says so). A revision whose snapshot is complete in the cache
//! is used with no request at all: to pick up a newer commit of a branch, name the commit
//! (`@<sha>`) or delete `refs/<branch>` in the repository's cache folder. A download cut off
//! midway leaves only a `blobs/*.incomplete` file, which no snapshot points to; the next call
//! downloads that file again from its start.

use std::fmt;
use std::path::{Component, Path, PathBuf};
use std::str::FromStr;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::Duration;

use hf_hub::progress::{DownloadEvent, ProgressEvent, ProgressHandler};
use hf_hub::repository::RepoTreeEntry;
use hf_hub::{HFClient, HFError, HFRepositorySync, RepoTypeModel};
use w3d_core::{Error, Result};

use crate::progress::{Progress, Stage};

/// The Hub used when `HF_ENDPOINT` is not set.
pub const DEFAULT_ENDPOINT: &str = "https://huggingface.co";

/// The revision of a [`HubId`] without `@revision`.
pub const DEFAULT_REVISION: &str = "main";

/// Which loader a checkpoint folder is for: what [`resolve_with`] downloads and checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Layout {
    /// The multi-view model ([`Generator::load`](crate::Generator::load),
    /// `MultiViewPipeline::from_dir`): `unet/`, `vae/`, `image_encoder/`, `scheduler/`, plus
    /// `model_index.json` and `feature_extractor/` where the repository has them.
    MultiView,
    /// The refinement enhancer ([`DiffusionEnhancer::load`](crate::refine::DiffusionEnhancer::load),
    /// `docs/weights.md`, "The enhancer"): `unet/`, `controlnet/`, `vae/`, `text_encoder/`,
    /// `tokenizer/`, `image_encoder/`, `ip_adapter/`, `scheduler/`.
    Enhancer,
}

/// A file of a layout: one of `names` in `folder` (the first the repository has is taken).
#[derive(Clone, Copy)]
struct Wanted {
    folder: &'static str,
    names: &'static [&'static str],
    required: bool,
}

const fn needed(folder: &'static str, names: &'static [&'static str]) -> Wanted {
    Wanted { folder, names, required: true }
}

const fn optional(folder: &'static str, names: &'static [&'static str]) -> Wanted {
    Wanted { folder, names, required: false }
}

/// What `MultiViewPipeline::from_dir` reads (`docs/weights.md`, "What the directory must
/// hold"), plus the two files of a diffusers folder it does not need but that describe it.
const MULTIVIEW_FILES: &[Wanted] = &[
    optional("", &["model_index.json"]),
    needed("unet", &["config.json"]),
    needed("unet", &["diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.fp16.safetensors"]),
    needed("vae", &["config.json"]),
    needed("vae", &["diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.fp16.safetensors"]),
    needed("image_encoder", &["config.json"]),
    needed("image_encoder", &["model.safetensors", "model.fp16.safetensors"]),
    needed("scheduler", &["scheduler_config.json"]),
    optional("feature_extractor", &["preprocessor_config.json"]),
];

/// The tokenizer files the enhancer reads when present.
const ENHANCER_OPTIONAL: &[Wanted] =
    &[optional("tokenizer", &["special_tokens_map.json"]), optional("tokenizer", &["tokenizer_config.json"])];

impl Layout {
    /// The files of the layout, required ones and optional ones.
    fn files(self) -> Vec<Wanted> {
        match self {
            Layout::MultiView => MULTIVIEW_FILES.to_vec(),
            Layout::Enhancer => w3d_diffusion::pipelines::enhancer::ENHANCER_FILES
                .iter()
                .map(|&(folder, names)| needed(folder, names))
                .chain(ENHANCER_OPTIONAL.iter().copied())
                .collect(),
        }
    }

    /// What the layout is, for messages.
    fn describe(self) -> &'static str {
        match self {
            Layout::MultiView => "a multi-view model folder (docs/weights.md)",
            Layout::Enhancer => "an enhancer folder (docs/weights.md, \"The enhancer\")",
        }
    }

    /// The first required file `dir` lacks (as `unet/a or unet/b`), `None` when it is complete.
    pub fn first_missing(self, dir: &Path) -> Option<String> {
        self.files()
            .into_iter()
            .filter(|w| w.required)
            .find(|w| !w.names.iter().any(|n| dir.join(w.folder).join(n).is_file()))
            .map(|w| w.describe())
    }

    /// The first required file (as `unet/a or unet/b`).
    fn first_required(self) -> String {
        self.files().into_iter().find(|w| w.required).map(|w| w.describe()).unwrap_or_default()
    }
}

impl Wanted {
    /// `folder/a or folder/b`.
    fn describe(&self) -> String {
        self.names.iter().map(|n| join_repo_path(self.folder, n)).collect::<Vec<_>>().join(" or ")
    }
}

/// A repository on the Hugging Face Hub, a revision of it and a folder inside it:
/// `owner/name[@revision][:sub/folder]` (see the [module](self) documentation).
///
/// ```
/// use wonder3d::weights::HubId;
///
/// let id: HubId = "flamehaze1115/Wonder3D_plus@main:mv_controlnet".parse()?;
/// assert_eq!((id.repo().as_str(), id.revision(), id.subfolder.as_deref()), ("flamehaze1115/Wonder3D_plus", "main", Some("mv_controlnet")));
/// assert_eq!(id.to_string(), "flamehaze1115/Wonder3D_plus@main:mv_controlnet");
/// assert!("a/../b".parse::<HubId>().is_err() && "owner/name@".parse::<HubId>().is_err());
/// # Ok::<(), wonder3d::Error>(())
/// ```
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub struct HubId {
    /// The user or organisation.
    pub owner: String,
    /// The repository's name.
    pub name: String,
    /// The branch, tag or commit; `None` is [`DEFAULT_REVISION`].
    pub revision: Option<String>,
    /// The folder inside the repository that holds the model (`/`-separated), `None` for the root.
    pub subfolder: Option<String>,
}

impl HubId {
    /// `owner/name`.
    pub fn repo(&self) -> String {
        format!("{}/{}", self.owner, self.name)
    }

    /// The revision, [`DEFAULT_REVISION`] when none was given.
    pub fn revision(&self) -> &str {
        self.revision.as_deref().unwrap_or(DEFAULT_REVISION)
    }

    /// The folder of the repository in the cache under `cache_dir`: `models--owner--name`.
    pub fn cache_folder(&self, cache_dir: &Path) -> PathBuf {
        cache_dir.join(format!("models--{}--{}", self.owner, self.name))
    }

    /// `path` (relative to the model folder) relative to the repository's root.
    fn in_repo(&self, path: &str) -> String {
        match &self.subfolder {
            Some(sub) => join_repo_path(sub, path),
            None => path.to_owned(),
        }
    }

    /// `owner/name@revision` for messages (the revision always shown).
    fn at(&self) -> String {
        format!("{}@{}", self.repo(), self.revision())
    }
}

impl fmt::Display for HubId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.owner, self.name)?;
        if let Some(revision) = &self.revision {
            write!(f, "@{revision}")?;
        }
        if let Some(sub) = &self.subfolder {
            write!(f, ":{sub}")?;
        }
        Ok(())
    }
}

/// The syntax, for messages.
const SYNTAX: &str = "a Hub id owner/name[@revision][:sub/folder]";

/// Checks one `/`-free part of an id: letters, digits, `.`, `_`, `-` (and `+` in revisions),
/// not `.` or `..`.
fn check_part(what: &str, part: &str, extra: &[char]) -> std::result::Result<(), String> {
    if part.is_empty() {
        return Err(format!("the {what} has an empty part"));
    }
    if part == "." || part == ".." {
        return Err(format!("the {what} has a {part:?} part: only plain names are allowed"));
    }
    if let Some(c) =
        part.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') || extra.contains(c)))
    {
        return Err(format!("the {what} {part:?} has the character {c:?}: use letters, digits, '.', '_', '-'"));
    }
    Ok(())
}

impl FromStr for HubId {
    type Err = Error;

    /// Parses `owner/name[@revision][:sub/folder]`, refusing anything else with an error
    /// that names the part at fault (no file system or network access).
    fn from_str(spec: &str) -> Result<HubId> {
        parse_id(spec).map_err(|why| {
            Error::invalid(format!("Hub id {spec:?}"), format!("{SYNTAX} ({why}; docs/weights.md, \"By Hub id\")"))
        })
    }
}

/// The id `spec` spells, or why it is none.
fn parse_id(spec: &str) -> std::result::Result<HubId, String> {
    if spec.trim().is_empty() {
        return Err(String::from("found an empty value"));
    }
    let (rest, subfolder) = match spec.split_once(':') {
        Some((rest, sub)) => (rest, Some(sub)),
        None => (spec, None),
    };
    let (repo, revision) = match rest.split_once('@') {
        Some((repo, revision)) => (repo, Some(revision)),
        None => (rest, None),
    };
    let parts: Vec<&str> = repo.split('/').collect();
    if parts.contains(&"..") {
        return Err(String::from("'..' is not allowed"));
    }
    let [owner, name] = parts[..] else {
        return Err(format!(
            "the repository must be owner/name, found {} part(s) in {repo:?}; a folder inside the repository goes \
                 after ':', as in owner/name:sub/folder",
            parts.len()
        ));
    };
    for (what, part) in [("owner", owner), ("repository name", name)] {
        check_part(what, part, &[])?;
        if part.starts_with(['-', '.'])
            || part.ends_with(['-', '.'])
            || part.contains("--")
            || part.contains("..")
            || part.len() > 96
        {
            return Err(format!(
                "the {what} {part:?} is not a Hub name (no leading or trailing '-' or '.', no '--' or '..', at most 96 characters)"
            ));
        }
    }
    if let Some(revision) = revision {
        if revision.is_empty() {
            return Err(String::from("the revision after '@' is empty"));
        }
        if revision.len() > 256 {
            return Err(String::from("the revision is longer than 256 characters"));
        }
        for part in revision.split('/') {
            check_part("revision", part, &['+'])?;
        }
    }
    if let Some(sub) = subfolder {
        if sub.is_empty() {
            return Err(String::from("the folder after ':' is empty"));
        }
        for part in sub.split('/') {
            check_part("folder", part, &['+'])?;
        }
    }
    Ok(HubId {
        owner: owner.to_owned(),
        name: name.to_owned(),
        revision: revision.map(str::to_owned),
        subfolder: subfolder.map(str::to_owned),
    })
}

/// What a weights argument names: an existing local folder, or a folder on the Hub.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum WeightsSpec {
    /// An existing local directory (always wins over a Hub id of the same spelling).
    Local(PathBuf),
    /// A folder of a Hub repository.
    Hub(HubId),
}

impl WeightsSpec {
    /// Reads `spec` without any network access: an existing directory is [`WeightsSpec::Local`];
    /// something path-like that does not exist (absolute, `./…`, `../…`, `~…`, backslashes),
    /// an existing file and an ill-formed id are errors that say which; the rest is a
    /// [`HubId`].
    pub fn parse(spec: &str) -> Result<WeightsSpec> {
        let path = Path::new(spec);
        if !spec.is_empty() && path.is_dir() {
            return Ok(WeightsSpec::Local(path.to_path_buf()));
        }
        if !spec.is_empty() && path.exists() {
            return Err(Error::invalid(format!("weights {spec:?}"), "a model folder or a Hub id (this is a file)"));
        }
        let path_like = path.is_absolute()
            || spec.starts_with(['.', '~', '/'])
            || spec.contains('\\')
            || path.components().any(|c| matches!(c, Component::Prefix(_) | Component::RootDir));
        if path_like {
            return Err(Error::invalid(
                format!("weights {spec:?}"),
                "an existing model folder (no such directory; a Hub id is owner/name[@revision][:sub/folder]; \
                 docs/weights.md)",
            ));
        }
        parse_id(spec).map(WeightsSpec::Hub).map_err(|why| {
            Error::invalid(
                format!("weights {spec:?}"),
                format!(
                    "an existing model folder or {SYNTAX} (no such directory, and as a Hub id: {why}; docs/weights.md, \
                     \"By Hub id\")"
                ),
            )
        })
    }
}

/// Where Hub downloads come from and go to.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct HubSettings {
    /// The Hub's base URL (`https://huggingface.co`, a mirror, or a test server).
    pub endpoint: String,
    /// The Hugging Face hub cache folder (the one holding `models--owner--name/`).
    pub cache_dir: PathBuf,
    /// No network: resolve from the cache only.
    pub offline: bool,
}

impl HubSettings {
    /// Online settings with this endpoint and cache folder.
    pub fn new(endpoint: impl Into<String>, cache_dir: impl Into<PathBuf>) -> HubSettings {
        HubSettings { endpoint: endpoint.into(), cache_dir: cache_dir.into(), offline: false }
    }

    /// The same settings, offline or not.
    pub fn with_offline(mut self, offline: bool) -> HubSettings {
        self.offline = offline;
        self
    }

    /// The settings of the environment, as `huggingface_hub` reads them: `HF_ENDPOINT`
    /// (default [`DEFAULT_ENDPOINT`]); the cache `HF_HUB_CACHE`, else `HUGGINGFACE_HUB_CACHE`,
    /// else `HF_HOME/hub`, else `XDG_CACHE_HOME/huggingface/hub`, else
    /// `~/.cache/huggingface/hub`; offline when `HF_HUB_OFFLINE` is `1`, `true`, `yes` or `on`.
    pub fn from_env() -> HubSettings {
        let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
        let endpoint = std::env::var("HF_ENDPOINT")
            .ok()
            .filter(|v| !v.trim().is_empty())
            .unwrap_or_else(|| DEFAULT_ENDPOINT.to_owned());
        let cache_dir =
            var("HF_HUB_CACHE").or_else(|| var("HUGGINGFACE_HUB_CACHE")).map(PathBuf::from).unwrap_or_else(|| {
                let home = var("HF_HOME").map(PathBuf::from).unwrap_or_else(|| {
                    let cache = var("XDG_CACHE_HOME")
                        .map(PathBuf::from)
                        .unwrap_or_else(|| PathBuf::from(var("HOME").unwrap_or_else(|| "/tmp".into())).join(".cache"));
                    cache.join("huggingface")
                });
                home.join("hub")
            });
        let offline = std::env::var("HF_HUB_OFFLINE")
            .is_ok_and(|v| matches!(v.trim().to_ascii_lowercase().as_str(), "1" | "true" | "yes" | "on"));
        HubSettings { endpoint: endpoint.trim().trim_end_matches('/').to_owned(), cache_dir, offline }
    }
}

/// The local folder of the multi-view model `spec` names (a local directory, returned as is,
/// or a Hub id, downloaded as needed), with the settings of the environment
/// ([`HubSettings::from_env`]). Download progress comes as [`Stage::Download`] events in
/// bytes over all the files still to fetch.
pub fn resolve(spec: &str, progress: &mut dyn FnMut(Progress)) -> Result<PathBuf> {
    resolve_layout(spec, Layout::MultiView, progress)
}

/// [`resolve`] for the folder of another loader (the enhancer's).
pub fn resolve_layout(spec: &str, layout: Layout, progress: &mut dyn FnMut(Progress)) -> Result<PathBuf> {
    resolve_with(spec, layout, &HubSettings::from_env(), progress)
}

/// [`resolve_layout`] with explicit settings instead of the environment's: a local directory
/// is returned as is; a Hub id gives `<cache>/models--owner--name/snapshots/<commit>[/sub/folder]`.
/// A snapshot that already holds every required file is returned with no request; otherwise
/// (unless offline) the revision is resolved to its commit, the repository listed, the files
/// of `layout` chosen (safetensors only) and those not yet cached downloaded one by one.
pub fn resolve_with(
    spec: &str,
    layout: Layout,
    settings: &HubSettings,
    progress: &mut dyn FnMut(Progress),
) -> Result<PathBuf> {
    let id = match WeightsSpec::parse(spec)? {
        WeightsSpec::Local(dir) => return Ok(dir),
        WeightsSpec::Hub(id) => id,
    };
    let repo_dir = id.cache_folder(&settings.cache_dir);
    let commit = if is_commit(id.revision()) {
        Some(id.revision().to_owned())
    } else {
        std::fs::read_to_string(repo_dir.join("refs").join(id.revision()))
            .ok()
            .map(|s| s.trim().to_owned())
            .filter(|s| is_commit(s))
    };
    if let Some(commit) = &commit {
        let dir = snapshot_dir(&repo_dir, commit, &id);
        if layout.first_missing(&dir).is_none() {
            return Ok(dir);
        }
    }
    if settings.offline {
        let missing = match &commit {
            Some(commit) => layout.first_missing(&snapshot_dir(&repo_dir, commit, &id)).unwrap_or_default(),
            None => layout.first_required(),
        };
        let missing = id.in_repo(&missing);
        return Err(Error::invalid(
            format!("Hub id {id}"),
            format!(
                "{missing} of {} in the Hugging Face cache {} (HF_HUB_OFFLINE is set, so nothing is downloaded{}): \
                 unset HF_HUB_OFFLINE to download it, or pass a local model folder",
                id.at(),
                settings.cache_dir.display(),
                if commit.is_none() {
                    format!("; the cache knows no commit of revision {}", id.revision())
                } else {
                    String::new()
                }
            ),
        ));
    }
    download(&id, layout, settings, &repo_dir, progress)
}

/// Whether `s` is a full commit hash (40 hex digits).
fn is_commit(s: &str) -> bool {
    s.len() == 40 && s.bytes().all(|b| b.is_ascii_hexdigit())
}

/// `a/b` from a folder (maybe empty) and a name.
fn join_repo_path(folder: &str, name: &str) -> String {
    if folder.is_empty() { name.to_owned() } else { format!("{folder}/{name}") }
}

/// The model folder inside the snapshot of `commit`.
fn snapshot_dir(repo_dir: &Path, commit: &str, id: &HubId) -> PathBuf {
    let snapshot = repo_dir.join("snapshots").join(commit);
    match &id.subfolder {
        Some(sub) => sub.split('/').fold(snapshot, |p, part| p.join(part)),
        None => snapshot,
    }
}

/// The error for a failed Hub call about `file` (`None`: the repository itself).
fn hub_error(id: &HubId, settings: &HubSettings, file: Option<&str>, error: HFError) -> Error {
    let what = match file {
        Some(file) => format!("{file} of {}", id.at()),
        None => id.at(),
    };
    let endpoint = &settings.endpoint;
    let expected = match &error {
        HFError::RepoNotFound { .. } | HFError::RevisionNotFound { .. } => format!(
            "a repository and revision that exist on {endpoint}: it answered 404 Not Found for {what} (check the \
             spelling and the revision; a private or gated repository needs HF_TOKEN)"
        ),
        HFError::EntryNotFound { .. } => {
            format!("{what} on {endpoint}: it answered 404 Not Found for that file (a revision that has it?)")
        }
        HFError::AuthRequired { .. } | HFError::Forbidden { .. } => format!(
            "access to {what} on {endpoint} ({error}): a private or gated repository needs HF_TOKEN set to an access \
             token that may read it (and the model's terms accepted on its page)"
        ),
        HFError::Request { source, .. } if source.is_connect() || source.is_timeout() => format!(
            "a connection to {endpoint} for {what} ({error}): check the network and HF_ENDPOINT, or set HF_HUB_OFFLINE=1 \
             to use what the cache {} holds",
            settings.cache_dir.display()
        ),
        HFError::Http { context } if context.status.as_u16() == 404 => {
            format!("{what} on {endpoint}: it answered 404 Not Found (a folder the repository has at that revision?)")
        }
        HFError::Request { .. } if file.is_some() => format!(
            "{what} downloaded whole from {endpoint}, but the transfer broke off ({error}); nothing partial is used: \
             run again to download it again"
        ),
        HFError::Io(e) => format!(
            "{what} written into the Hugging Face cache {} ({e}): check that the folder is writable and has space \
             (HF_HOME / HF_HUB_CACHE choose another)",
            settings.cache_dir.display()
        ),
        _ => format!("{what} from {endpoint} ({error})"),
    };
    Error::invalid(format!("Hub id {id}"), expected)
}

/// Forwards one file's byte count to the resolving thread.
struct Forward(mpsc::Sender<u64>);

impl ProgressHandler for Forward {
    fn on_progress(&self, event: &ProgressEvent) {
        match event {
            ProgressEvent::Download(DownloadEvent::Progress { files }) => {
                for f in files {
                    let _ = self.0.send(f.bytes_completed);
                }
            }
            ProgressEvent::Download(DownloadEvent::AggregateProgress { bytes_completed, .. }) => {
                let _ = self.0.send(*bytes_completed);
            }
            _ => {}
        }
    }
}

/// One file to download: its path in the repository and size.
struct Fetch {
    path: String,
    size: u64,
}

/// Lists the repository at the revision's commit, picks the files of `layout`, downloads those
/// the snapshot lacks and records the revision's commit once the snapshot is complete.
fn download(
    id: &HubId,
    layout: Layout,
    settings: &HubSettings,
    repo_dir: &Path,
    progress: &mut dyn FnMut(Progress),
) -> Result<PathBuf> {
    let client = HFClient::builder()
        .endpoint(settings.endpoint.clone())
        .cache_dir(settings.cache_dir.clone())
        .build_sync()
        .map_err(|e| hub_error(id, settings, None, e))?;
    let repo: HFRepositorySync<RepoTypeModel> = client.model(id.owner.clone(), id.name.clone());
    let info = repo
        .info()
        .revision(id.revision().to_owned())
        // Only the commit: the rest of a model's card is not needed (and is the part of the
        // answer whose shape changes).
        .expand(vec!["sha".to_owned()])
        .send()
        .map_err(|e| hub_error(id, settings, None, e))?;
    let commit = info.sha.filter(|s| is_commit(s)).ok_or_else(|| {
        Error::invalid(
            format!("Hub id {id}"),
            format!("the commit of {} from {} (its answer had no 40-hex sha)", id.at(), settings.endpoint),
        )
    })?;
    let tree = repo
        .list_tree()
        .revision(commit.clone())
        .maybe_path_in_repo(id.subfolder.clone())
        .recursive(true)
        .send()
        .map_err(|e| match &e {
            // The Hub answers 404 for a folder the commit does not have.
            HFError::Http { context } if context.status.as_u16() == 404 => {
                hub_error(id, settings, id.subfolder.as_deref(), e)
            }
            _ => hub_error(id, settings, None, e),
        })?;
    let listed: Vec<(String, u64)> = tree
        .into_iter()
        .filter_map(|entry| match entry {
            RepoTreeEntry::File { path, size, .. } => Some((path, size)),
            RepoTreeEntry::Directory { .. } => None,
        })
        .collect();
    let dir = snapshot_dir(repo_dir, &commit, id);
    let mut fetch = Vec::new();
    for wanted in layout.files() {
        let found = wanted.names.iter().find_map(|name| {
            let path = id.in_repo(&join_repo_path(wanted.folder, name));
            listed.iter().find(|(p, _)| *p == path).map(|(p, size)| (name, p.clone(), *size))
        });
        match found {
            Some((name, path, size)) if !dir.join(wanted.folder).join(name).is_file() => {
                fetch.push(Fetch { path, size })
            }
            Some(_) => {}
            None if wanted.required => return Err(missing_in_repo(id, settings, &commit, layout, &wanted, &listed)),
            None => {}
        }
    }
    let total: u64 = fetch.iter().map(|f| f.size).sum();
    let expected_root = repo_dir.join("snapshots").join(&commit);
    if !fetch.is_empty() {
        fetch_all(id, settings, &repo, &commit, &fetch, &expected_root, total, progress)?;
    }
    if let Some(missing) = layout.first_missing(&dir) {
        return Err(Error::invalid(
            format!("Hub id {id}"),
            format!(
                "{} in the cache snapshot {} after the download (found missing)",
                id.in_repo(&missing),
                dir.display()
            ),
        ));
    }
    if !is_commit(id.revision()) {
        write_ref(repo_dir, id.revision(), &commit).map_err(|e| hub_error(id, settings, None, HFError::Io(e)))?;
    }
    Ok(dir)
}

/// The error for a required file the repository's listing lacks: a pickle-only model says so.
fn missing_in_repo(
    id: &HubId,
    settings: &HubSettings,
    commit: &str,
    layout: Layout,
    wanted: &Wanted,
    listed: &[(String, u64)],
) -> Error {
    let names: Vec<String> = wanted.names.iter().map(|n| id.in_repo(&join_repo_path(wanted.folder, n))).collect();
    let folder = id.in_repo(wanted.folder);
    let prefix = if folder.is_empty() { String::new() } else { format!("{folder}/") };
    let pickles: Vec<&str> = listed
        .iter()
        .map(|(p, _)| p.as_str())
        .filter(|p| p.strip_prefix(&prefix).is_some_and(|rest| !rest.contains('/')))
        .filter(|p| [".bin", ".ckpt", ".pt", ".pth"].iter().any(|ext| p.ends_with(ext)))
        .collect();
    let why = if pickles.is_empty() {
        format!("it has no such file: is it {}?", layout.describe())
    } else {
        format!(
            "it has only {} (PyTorch pickles, which are never downloaded or read): choose a revision with safetensors \
             (e.g. the Hub's safetensors conversion, `@refs/pr/N`), or download it and convert it once (docs/weights.md)",
            pickles.join(", ")
        )
    };
    Error::invalid(
        format!("Hub id {id}"),
        format!("{} in {} (commit {commit}) on {}: {why}", names.join(" or "), id.at(), settings.endpoint),
    )
}

/// Downloads `files` one after the other into the cache (hf-hub: `blobs/<etag>.incomplete`,
/// renamed to `blobs/<etag>` when whole, then linked from `snapshots/<commit>/<path>`),
/// reporting [`Stage::Download`] progress over all of them in bytes on this thread.
#[allow(clippy::too_many_arguments)]
fn fetch_all(
    id: &HubId,
    settings: &HubSettings,
    repo: &HFRepositorySync<RepoTypeModel>,
    commit: &str,
    files: &[Fetch],
    expected_root: &Path,
    total: u64,
    progress: &mut dyn FnMut(Progress),
) -> Result<()> {
    let bytes = |n: u64| usize::try_from(n).unwrap_or(usize::MAX);
    progress(Progress::new(Stage::Download, 0, bytes(total), None));
    // At most about a thousand events for the whole download (each file's end always reported).
    let step = (total / 1000).max(64 * 1024);
    let mut finished = 0u64;
    for file in files {
        let (tx, rx) = mpsc::channel();
        let result = std::thread::scope(|scope| {
            let worker = scope.spawn(move || {
                repo.download_file()
                    .filename(file.path.clone())
                    .revision(commit.to_owned())
                    .progress(Forward(tx))
                    .send()
            });
            let mut reported = finished;
            loop {
                match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(done) => {
                        let now = finished + done.min(file.size);
                        if now >= reported + step {
                            reported = now;
                            progress(Progress::new(Stage::Download, bytes(now), bytes(total), None));
                        }
                    }
                    // hf-hub may keep a clone of the handler (and so the sender) after the
                    // download ends: the worker's end is what stops the loop.
                    Err(RecvTimeoutError::Timeout) if !worker.is_finished() => {}
                    Err(_) => break,
                }
            }
            worker.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic))
        });
        let path = result.map_err(|e| hub_error(id, settings, Some(&file.path), e))?;
        // The link must be where the revision's snapshot is: hf-hub places it by the
        // X-Repo-Commit header of the file's answer, which a misbehaving server could change.
        let expected = file.path.split('/').fold(expected_root.to_path_buf(), |p, part| p.join(part));
        if path != expected || !expected.is_file() {
            return Err(Error::invalid(
                format!("Hub id {id}"),
                format!(
                    "{} of {} (commit {commit}) at {} (the server put it at {})",
                    file.path,
                    id.at(),
                    expected.display(),
                    path.display()
                ),
            ));
        }
        finished += file.size;
        progress(Progress::new(Stage::Download, bytes(finished), bytes(total), None));
    }
    Ok(())
}

/// Records `commit` as the revision's in `refs/<revision>` (written under a temporary name,
/// then renamed), as hf-hub and `huggingface_hub` do.
fn write_ref(repo_dir: &Path, revision: &str, commit: &str) -> std::io::Result<()> {
    let path = revision.split('/').fold(repo_dir.join("refs"), |p, part| p.join(part));
    if std::fs::read_to_string(&path).is_ok_and(|s| s.trim() == commit) {
        return Ok(());
    }
    let parent = path.parent().unwrap_or(repo_dir);
    std::fs::create_dir_all(parent)?;
    let tmp = parent.join(format!(
        ".{}.{}.tmp",
        path.file_name().and_then(|n| n.to_str()).unwrap_or("ref"),
        std::process::id()
    ));
    std::fs::write(&tmp, commit)?;
    std::fs::rename(&tmp, &path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_parse_and_print_back() {
        for spec in [
            "a/b",
            "a/b@v1.0",
            "a/b@refs/pr/3",
            "a/b:sub/folder",
            "Org-1/Name_2.x@0123456789abcdef0123456789abcdef01234567:x",
        ] {
            assert_eq!(spec.parse::<HubId>().unwrap().to_string(), spec);
        }
        let id: HubId = "a/b:c/d".parse().unwrap();
        assert_eq!((id.revision(), id.in_repo("unet/config.json")), ("main", "c/d/unet/config.json".to_owned()));
    }

    #[test]
    fn ill_formed_ids_are_refused() {
        for spec in [
            "",
            " ",
            "a",
            "a/b/c",
            "/b",
            "a/",
            "a/../b",
            "..",
            "a/b@",
            "a/b:",
            "a/b@x/../y",
            "a/b:..",
            "a/b:x//y",
            "a/b@main:../x",
            "a b/c",
            "a/b c",
            "-a/b",
            "a/b.",
            "a/b--c",
            "a/b@ma in",
            "a/b:x\\y",
            "a/b@:x",
        ] {
            let e = spec.parse::<HubId>().unwrap_err().to_string();
            assert!(e.contains("owner/name[@revision][:sub/folder]"), "{spec:?}: {e}");
        }
    }

    #[test]
    fn paths_that_do_not_exist_are_not_taken_for_ids() {
        for spec in ["/no/such/dir", "./x/y", "../x/y", "~/x", "C:\\x\\y"] {
            let e = WeightsSpec::parse(spec).unwrap_err().to_string();
            assert!(e.contains("no such directory") || e.contains("character"), "{spec:?}: {e}");
        }
        let here = env!("CARGO_MANIFEST_DIR");
        assert_eq!(WeightsSpec::parse(here).unwrap(), WeightsSpec::Local(PathBuf::from(here)));
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/Cargo.toml");
        assert!(WeightsSpec::parse(file).unwrap_err().to_string().contains("this is a file"));
    }
}
