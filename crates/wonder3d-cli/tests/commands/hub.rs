//! `--weights owner/name`: `wonder3d generate` with the tiny model served by a Hugging Face Hub
//! on loopback (the facade's `hub_server.rs`), found through `HF_ENDPOINT` and cached under
//! `HF_HOME`; offline (`HF_HUB_OFFLINE=1`) the second run reads the cache alone.
#![cfg(feature = "diffusion")]

use std::path::Path;
use std::process::{Command, Output};

use crate::common::{s, tiny_weights, write_input};
use crate::hub_server::{HubServer, Repo};

/// `wonder3d generate IMAGE --weights WEIGHTS --out OUT` with the Hub settings of `env`.
fn generate(image: &Path, weights: &str, out: &Path, env: &[(&str, &str)]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_wonder3d"));
    command.args(["generate", s(image), "--weights", weights, "--out", s(out), "--steps", "2", "--seed", "3"]);
    for var in ["HF_ENDPOINT", "HF_HOME", "HF_HUB_CACHE", "HUGGINGFACE_HUB_CACHE", "HF_HUB_OFFLINE", "HF_TOKEN"] {
        command.env_remove(var);
    }
    command.envs(env.iter().copied()).output().unwrap()
}

#[test]
fn generate_takes_weights_by_hub_id() {
    let server = HubServer::start();
    let tiny = tiny_weights();
    let commit = server.add("owner/tiny", Repo::from_dir(Path::new(&tiny), "").with_file("unet/x.bin", b"pickle"));
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("disc.png");
    write_input(&input);
    let home = dir.path().join("hf");
    let env = [("HF_ENDPOINT", server.endpoint.as_str()), ("HF_HOME", s(&home))];
    let run = generate(&input, "owner/tiny", &dir.path().join("hub_views"), &env);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let snapshot = home.join("hub/models--owner--tiny/snapshots").join(&commit);
    assert!(snapshot.join("unet/diffusion_pytorch_model.safetensors").is_file(), "cached under HF_HOME/hub");
    let log = server.take_log();
    assert!(log.iter().any(|l| l.starts_with("GET /owner/tiny/resolve/")), "{log:#?}");
    assert!(!log.iter().any(|l| l.ends_with(".bin")), "{log:#?}");
    // The same views as from the folder itself.
    let local = generate(&input, &tiny, &dir.path().join("local_views"), &[]);
    assert!(local.status.success(), "{}", String::from_utf8_lossy(&local.stderr));
    for file in ["normal_front.png", "colour_back.png", "mask_left.png"] {
        let read = |views: &str| std::fs::read(dir.path().join(views).join(file)).unwrap();
        assert_eq!(read("hub_views"), read("local_views"), "{file}");
    }
    // Offline, from the cache: no request.
    let offline = [env[0], env[1], ("HF_HUB_OFFLINE", "1")];
    let run = generate(&input, "owner/tiny@main", &dir.path().join("offline_views"), &offline);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert_eq!(server.requests(), 0);
    // A repository the Hub does not have: the flag, the id and the 404 named.
    let run = generate(&input, "owner/missing", &dir.path().join("missing_views"), &env);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("--weights") && stderr.contains("owner/missing@main") && stderr.contains("404"),
        "{stderr}"
    );
    // A hostile id: refused before any request.
    server.take_log();
    let run = generate(&input, "owner/tiny@../../x", &dir.path().join("hostile_views"), &env);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && stderr.contains("--weights") && stderr.contains("\"..\" part"), "{stderr}");
    assert_eq!(server.requests(), 0);
}
