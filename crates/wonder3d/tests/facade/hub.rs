//! Weights by Hugging Face Hub id, for real over HTTP against a Hub on loopback
//! (`hub_server.rs`): the first use downloads into the cache, the second makes no request,
//! offline mode reads the cache, 404s and cut-off downloads get clear errors and leave nothing
//! a loader would take, pickles are never fetched, hostile ids are refused before any request.
//! Every test has its own server and cache and passes them explicitly
//! (`weights::resolve_with`), so none depends on the process's environment.

use std::path::{Path, PathBuf};

use wonder3d::weights::{HubSettings, Layout, resolve_with};
use wonder3d::{Generator, SampleOptions, Stage};

use crate::generate::disc;
use crate::hub_server::{HubServer, Repo};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../w3d-diffusion/tests/fixtures").join(name)
}

/// The tiny multi-view model as a repository, with what a real one has beside the loader's
/// files: PyTorch pickles, another model's folder, a README.
fn tiny_repo() -> Repo {
    Repo::from_dir(&fixture("wonder3d_tiny"), "")
        .with_file("unet/diffusion_pytorch_model.bin", b"a pickle that must never be downloaded")
        .with_file("image_encoder/pytorch_model.bin", b"another pickle")
        .with_file("mv_controlnet/config.json", b"{}")
        .with_file("mv_controlnet/diffusion_pytorch_model.safetensors", b"not the multi-view model")
        .with_file("README.md", b"# tiny")
}

/// A server serving `tiny_repo()` as `owner/tiny`, and settings with an empty cache.
fn setup() -> (HubServer, tempfile::TempDir, HubSettings, String) {
    let server = HubServer::start();
    let commit = server.add("owner/tiny", tiny_repo());
    let cache = tempfile::tempdir().unwrap();
    let settings = HubSettings::new(server.endpoint.clone(), cache.path().join("hub"));
    (server, cache, settings, commit)
}

/// The files of `dir` (relative, `/`-separated), following links.
fn files_under(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().to_string_lossy().replace('\\', "/"));
            }
        }
    }
    out.sort();
    out
}

/// The loader's files of the tiny model, as the snapshot must hold them.
const TINY_FILES: [&str; 9] = [
    "feature_extractor/preprocessor_config.json",
    "image_encoder/config.json",
    "image_encoder/model.safetensors",
    "model_index.json",
    "scheduler/scheduler_config.json",
    "unet/config.json",
    "unet/diffusion_pytorch_model.safetensors",
    "vae/config.json",
    "vae/diffusion_pytorch_model.safetensors",
];

#[test]
fn first_use_downloads_into_the_cache_and_generates_what_the_folder_generates() {
    let (server, _cache, settings, commit) = setup();
    let mut events = Vec::new();
    let dir = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |p| {
        assert_eq!(p.stage, Stage::Download);
        events.push((p.done, p.total));
    })
    .unwrap();
    // The standard cache layout: the snapshot of the commit, `refs/main` naming it.
    let repo_dir = settings.cache_dir.join("models--owner--tiny");
    assert_eq!(dir, repo_dir.join("snapshots").join(&commit));
    assert_eq!(std::fs::read_to_string(repo_dir.join("refs/main")).unwrap(), commit);
    assert_eq!(files_under(&dir), TINY_FILES, "exactly the loader's files");
    for file in TINY_FILES {
        assert!(std::fs::symlink_metadata(dir.join(file)).unwrap().file_type().is_symlink(), "{file} links a blob");
        assert_eq!(std::fs::read(dir.join(file)).unwrap(), std::fs::read(fixture("wonder3d_tiny").join(file)).unwrap());
    }
    // Progress in bytes over the files fetched, ending at the total.
    let total: usize = TINY_FILES.iter().map(|f| std::fs::metadata(dir.join(f)).unwrap().len() as usize).sum();
    assert_eq!(events.first(), Some(&(0, total)));
    assert_eq!(events.last(), Some(&(total, total)));
    assert!(events.windows(2).all(|w| w[0].0 <= w[1].0), "{events:?}");
    // The revision's commit (nothing else of the model card), the listing at that commit,
    // then HEAD + GET per file.
    let log = server.take_log();
    assert_eq!(log.len(), 2 + 2 * TINY_FILES.len(), "{log:#?}");
    assert_eq!(log[0], "GET /api/models/owner/tiny/revision/main?expand=sha");
    assert_eq!(log[1], format!("GET /api/models/owner/tiny/tree/{commit}?recursive=true"));
    assert!(log[2..].iter().all(|l| l.contains(&format!("/owner/tiny/resolve/{commit}/"))), "{log:#?}");
    // What the folder loads generates what the fixture generates.
    let options = SampleOptions { steps: 2, seed: 1, ..SampleOptions::default() };
    let image = disc(40);
    let from_hub = Generator::load(&dir).unwrap().with_options(options).generate(&image, &mut |_| {}).unwrap();
    let from_folder =
        Generator::load(fixture("wonder3d_tiny")).unwrap().with_options(options).generate(&image, &mut |_| {}).unwrap();
    assert_eq!(from_hub.views, from_folder.views);
}

#[test]
fn second_use_makes_no_request() {
    let (server, _cache, settings, _) = setup();
    let first = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap();
    assert!(server.take_log().len() > 2);
    let mut events = 0;
    let second = resolve_with("owner/tiny@main", Layout::MultiView, &settings, &mut |_| events += 1).unwrap();
    assert_eq!((second, server.requests(), events), (first.clone(), 0, 0));
    // By commit, too.
    let commit = first.file_name().unwrap().to_str().unwrap().to_owned();
    assert_eq!(
        resolve_with(&format!("owner/tiny@{commit}"), Layout::MultiView, &settings, &mut |_| {}).unwrap(),
        first
    );
    assert_eq!(server.requests(), 0);
    // A local folder is taken as it is, whatever its spelling.
    let local = fixture("wonder3d_tiny");
    assert_eq!(resolve_with(local.to_str().unwrap(), Layout::MultiView, &settings, &mut |_| {}).unwrap(), local);
    assert_eq!(server.requests(), 0);
}

#[test]
fn offline_mode_reads_the_cache_and_names_what_it_lacks() {
    let (server, cache, settings, _) = setup();
    let offline = settings.clone().with_offline(true);
    // Empty cache: no request, the repository, revision and first file named.
    let e = resolve_with("owner/tiny", Layout::MultiView, &offline, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("owner/tiny@main") && e.contains("unet/config.json") && e.contains("HF_HUB_OFFLINE"), "{e}");
    assert!(e.contains(&cache.path().join("hub").display().to_string()), "names the cache: {e}");
    assert_eq!(server.requests(), 0);
    // Once cached, offline resolves to the same folder, which loads.
    let online = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap();
    server.take_log();
    let dir = resolve_with("owner/tiny", Layout::MultiView, &offline, &mut |_| {}).unwrap();
    assert_eq!((&dir, server.requests()), (&online, 0));
    Generator::load(&dir).unwrap();
    // A snapshot missing a file offline names that file.
    std::fs::remove_file(dir.join("vae/diffusion_pytorch_model.safetensors")).unwrap();
    let e = resolve_with("owner/tiny", Layout::MultiView, &offline, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("vae/diffusion_pytorch_model.safetensors") && e.contains("owner/tiny@main"), "{e}");
    assert_eq!(server.requests(), 0);
    // Online again, only that file is asked for (after the revision and the listing); its
    // blob is still in the cache, so a HEAD finds it and it is linked again, not downloaded.
    resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap();
    let log = server.take_log();
    assert_eq!(log.len(), 3, "{log:#?}");
    assert!(log[2].starts_with("HEAD") && log[2].ends_with("/vae/diffusion_pytorch_model.safetensors"), "{log:#?}");
    Generator::load(&dir).unwrap();
}

#[test]
fn not_found_names_the_repository_and_the_file() {
    let (server, _cache, settings, commit) = setup();
    let e = resolve_with("owner/nothing", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("owner/nothing@main") && e.contains("404") && e.contains(&server.endpoint), "{e}");
    let e = resolve_with("owner/tiny@v9", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("owner/tiny@v9") && e.contains("404"), "{e}");
    // A folder the repository does not have (the listing answers 404).
    let e = resolve_with("owner/tiny:no/such", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("no/such of owner/tiny@main") && e.contains("404"), "{e}");
    // Listed, but the file itself is not found.
    server.mark_missing("owner/tiny", "vae/diffusion_pytorch_model.safetensors");
    let e = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(
        e.contains("vae/diffusion_pytorch_model.safetensors") && e.contains("owner/tiny@main") && e.contains("404"),
        "{e}"
    );
    let snapshot = settings.cache_dir.join("models--owner--tiny/snapshots").join(&commit);
    assert!(!snapshot.join("vae/diffusion_pytorch_model.safetensors").exists());
    assert!(!settings.cache_dir.join("models--owner--tiny/refs/main").exists(), "no ref to an incomplete snapshot");
    // A repository without the layout's files names the one it lacks.
    server.add(
        "owner/other",
        Repo::from_dir(&fixture("wonder3d_tiny"), "").without_file("scheduler/scheduler_config.json"),
    );
    let e = resolve_with("owner/other", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("scheduler/scheduler_config.json") && e.contains("owner/other@main"), "{e}");
}

#[test]
fn an_unreachable_hub_says_what_to_do() {
    // A closed loopback port: connections are refused (after hf-hub's retries, a few seconds).
    let cache = tempfile::tempdir().unwrap();
    let closed = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap();
    let settings = HubSettings::new(format!("http://{closed}"), cache.path());
    let e = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("owner/tiny@main") && e.contains(&closed.to_string()) && e.contains("HF_HUB_OFFLINE"), "{e}");
}

#[test]
fn a_cut_off_download_leaves_nothing_the_loader_takes_and_the_next_call_completes_it() {
    let (server, _cache, settings, commit) = setup();
    server.cut_next_download("owner/tiny", "unet/diffusion_pytorch_model.safetensors");
    let e = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("unet/diffusion_pytorch_model.safetensors") && e.contains("owner/tiny@main"), "{e}");
    let repo_dir = settings.cache_dir.join("models--owner--tiny");
    let snapshot = repo_dir.join("snapshots").join(&commit);
    assert!(!snapshot.join("unet/diffusion_pytorch_model.safetensors").exists(), "no link to a partial file");
    assert_eq!(
        Layout::MultiView.first_missing(&snapshot).as_deref(),
        Some("unet/diffusion_pytorch_model.safetensors or unet/diffusion_pytorch_model.fp16.safetensors")
    );
    assert!(Generator::load(&snapshot).is_err());
    assert!(!repo_dir.join("refs/main").exists(), "no ref to an incomplete snapshot");
    // The next call fetches what is missing and the folder loads.
    server.take_log();
    let dir = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap();
    assert_eq!(dir, snapshot);
    let weights = "unet/diffusion_pytorch_model.safetensors";
    assert_eq!(
        std::fs::read(dir.join(weights)).unwrap(),
        std::fs::read(fixture("wonder3d_tiny").join(weights)).unwrap()
    );
    assert!(server.take_log().iter().any(|l| l.starts_with("GET") && l.ends_with(weights)));
    Generator::load(&dir).unwrap();
}

#[test]
fn pickles_are_never_downloaded() {
    let (server, _cache, settings, _) = setup();
    let dir = resolve_with("owner/tiny", Layout::MultiView, &settings, &mut |_| {}).unwrap();
    let log = server.take_log();
    assert!(
        !log.iter().any(|l| l.ends_with(".bin") || l.contains("mv_controlnet") || l.ends_with("README.md")),
        "{log:#?}"
    );
    assert!(files_under(&dir).iter().all(|f| f.ends_with(".json") || f.ends_with(".safetensors")));
    // Only the blobs of the files fetched (plus nothing partial).
    let blobs = files_under(&settings.cache_dir.join("models--owner--tiny/blobs"));
    assert_eq!(blobs.len(), TINY_FILES.len(), "{blobs:?}");
    // A model whose weights exist only as a pickle is an error that says so.
    let pickled = Repo::from_dir(&fixture("wonder3d_tiny"), "")
        .without_file("unet/diffusion_pytorch_model.safetensors")
        .with_file("unet/diffusion_pytorch_model.bin", b"pickle");
    server.add("owner/pickled", pickled);
    let e = resolve_with("owner/pickled", Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
    assert!(
        e.contains("unet/diffusion_pytorch_model.bin") && e.contains("safetensors") && e.contains("owner/pickled@main"),
        "{e}"
    );
    assert!(!server.take_log().iter().any(|l| l.contains("/resolve/")), "nothing downloaded for it");
}

#[test]
fn a_folder_inside_a_repository_and_the_enhancer_layout() {
    let server = HubServer::start();
    let mut repo = Repo::from_dir(&fixture("wonder3d_tiny"), "models/mv");
    repo.add_dir(&fixture("enhancer"), "enhancer");
    let commit = server.add("org/bundle", repo.with_file("enhancer/unet/diffusion_pytorch_model.bin", b"pickle"));
    let cache = tempfile::tempdir().unwrap();
    let settings = HubSettings::new(server.endpoint.clone(), cache.path());
    let dir = resolve_with("org/bundle:models/mv", Layout::MultiView, &settings, &mut |_| {}).unwrap();
    assert_eq!(dir, cache.path().join("models--org--bundle/snapshots").join(&commit).join("models/mv"));
    assert_eq!(files_under(&dir), TINY_FILES);
    Generator::load(&dir).unwrap();
    let enhancer = resolve_with("org/bundle@main:enhancer", Layout::Enhancer, &settings, &mut |_| {}).unwrap();
    wonder3d::diffusion::pipelines::enhancer::check_enhancer_dir(&enhancer).unwrap();
    assert!(!enhancer.join("unet/diffusion_pytorch_model.bin").exists());
    assert!(!server.take_log().iter().any(|l| l.ends_with(".bin")));
}

#[test]
fn hostile_ids_are_refused_before_any_request() {
    let (server, cache, settings, _) = setup();
    for (spec, says) in [
        ("a/../b", "'..' is not allowed"),
        ("", "empty value"),
        ("owner/name@", "revision after '@' is empty"),
        ("owner/name:", "folder after ':' is empty"),
        ("owner/name:../../etc", "\"..\" part"),
        ("owner/name@../../../etc/passwd", "\"..\" part"),
        ("owner/name@main:sub//x", "empty part"),
        ("/definitely/not/here", "no such directory"),
        ("./not/here", "no such directory"),
        ("owner/name/extra", "owner/name"),
        ("owner", "owner/name"),
        ("own er/name", "character"),
        ("owner/na%2e%2e", "character"),
    ] {
        let e = resolve_with(spec, Layout::MultiView, &settings, &mut |_| {}).unwrap_err().to_string();
        assert!(e.contains(says), "{spec:?}: {e}");
        assert!(e.contains("owner/name[@revision][:sub/folder]"), "{spec:?} names the syntax: {e}");
    }
    assert_eq!(server.requests(), 0);
    assert!(!cache.path().join("hub").exists(), "nothing written");
}
