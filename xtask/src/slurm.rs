//! `cargo xtask slurm-check`: the Slurm job array of `docs/scale.md` run for real, on a
//! one-node Slurm cluster started on loopback for the check.
//!
//! 1. Slurm (`slurm-wlm`, with `munge`) is installed with `apt-get` when missing (needs root).
//! 2. `munged` (a fresh key) and `slurmctld` + `slurmd` (a `slurm.conf` written here, unusual
//!    ports, the node's CPUs and memory from `slurmd -C`) start in `target/slurm-check/`, all
//!    three in the foreground as children of this process; `/etc/slurm` and `/etc/munge` are
//!    neither read nor written.
//! 3. Six view folders are rendered with `wonder3d render` (64², quick to extract); one of them
//!    gets a truncated normal map. The manifest lists the six, in both of its syntaxes.
//! 4. The script is taken from the ```` ```bash ```` block under "### Slurm job array" of
//!    `docs/scale.md` when the check runs, and only the lines that must differ on this machine
//!    are changed ([`local_changes`]: each documented text must appear exactly once, so a
//!    changed document fails the check instead of being silently skipped).
//! 5. Three submissions of that same script: the first must extract every good item exactly
//!    once over the three shards and report the broken one with its file named; the second
//!    (nothing fixed) must skip the five good items without touching their files and fail
//!    the broken one again; after the broken folder is rendered again, the third must
//!    extract only that item.
//! 6. The daemons are stopped on every way out (a `Drop` guard: our jobs cancelled,
//!    `scontrol shutdown`, `munged` sent SIGTERM, each waited for by process id).
//!
//! `--script-only` prints the local script and its differences from the documented one
//! without Slurm (the test `xtask/tests/slurm.rs` runs it, so a document that no longer
//! matches fails `cargo test` too).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use serde_json::Value;

use crate::workspace::{target_dir, workspace_root};

/// The array's size: 3 shards of the 6 items, 2 items each.
const TASKS: usize = 3;

/// Ports of the check's `slurmctld` and `slurmd` (not Slurm's 6817 / 6818, so that a real
/// Slurm on the machine is left alone).
const PORTS: (u16, u16) = (26817, 26818);

/// The folder name of the broken item (its `normal_left.png` is truncated to 100 bytes).
const BROKEN: &str = "boot";

/// The file of the broken item that is damaged, and that its error must name.
const BROKEN_FILE: &str = "normal_left.png";

/// What starts each log in an error message.
const LOG_MARK: &str = "--- log ";

/// How long the cluster may take to come up.
const START_TIMEOUT: Duration = Duration::from_secs(60);

/// How long one submission may take to leave the queue.
const JOB_TIMEOUT: Duration = Duration::from_secs(600);

/// The six items: `(view folder name, mesh, manifest line)`. The meshes of
/// `../shared/data/meshes` fall back to the repository's own when that folder is missing.
const ITEMS: [(&str, &str, Syntax); 6] = [
    ("spot", "assets/spot.obj", Syntax::Json),
    ("bob", "assets/bob_tri.obj", Syntax::Json),
    ("torus", "../shared/data/meshes/torus.obj", Syntax::Path),
    ("suzanne", "../shared/data/meshes/suzanne.obj", Syntax::Json),
    (BROKEN, "../shared/data/meshes/boot.obj", Syntax::Json),
    ("wingnut", "../shared/data/meshes/wingnut.obj", Syntax::Json),
];

/// How an item is written in the manifest.
#[derive(Clone, Copy)]
enum Syntax {
    /// A bare path: the batch's own preset and texture size (the script sets neither, so the
    /// default preset and 1024² textures).
    Path,
    /// A JSON object with a quick preset and a small texture (`{"input": …, "preset": "fast",
    /// "texture_size": 256}`).
    Json,
}

/// `cargo xtask slurm-check [--script-only]`.
pub(crate) fn run(script_only: bool) -> Result<(), String> {
    let dir = std::path::absolute(target_dir().join("slurm-check")).map_err(|e| format!("target folder: {e}"))?;
    if dir.to_string_lossy().contains(char::is_whitespace) {
        return Err(format!("{}: slurm.conf and the script cannot hold a path with spaces", dir.display()));
    }
    let local = Local::new(&dir, 1024);
    let (script, changes) = local_script(&documented_script()?, &local)?;
    if script_only {
        print_changes(&changes);
        print!("{script}");
        return Ok(());
    }
    let start = Instant::now();
    let root = workspace_root();
    if !local.wonder3d.is_file() {
        return Err(format!(
            "{} is missing: build it first (`cargo build --release --workspace`)",
            local.wonder3d.display()
        ));
    }
    if !is_root() {
        return Err("slurm-check runs Slurm's daemons as root (and may apt-get install Slurm): run it as root".into());
    }

    // 1. Slurm and munge.
    let tools = Tools::find_or_install()?;
    let installed = start.elapsed();

    // 2. A one-node cluster on loopback.
    stop_stale(&dir, &tools);
    if dir.exists() {
        std::fs::remove_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    for sub in ["log", "state", "spool", "views", "logs", "results"] {
        mkdir(&dir.join(sub))?;
    }
    let node = tools.node_line()?;
    let mem_mb = (field(&node, "RealMemory").and_then(|m| m.parse::<u64>().ok()).unwrap_or(4096) / 4).clamp(256, 1024);
    let local = Local::new(&dir, mem_mb);
    let (script, changes) = local_script(&documented_script()?, &local)?;
    let t = Instant::now();
    let mut cluster = Cluster::start(&dir, tools, &node)?;
    let cluster_up = t.elapsed();
    println!("slurm-check: {} up in {:.1} s: {}", cluster.version()?, cluster_up.as_secs_f64(), cluster.sinfo()?);

    // 3. Six view folders, one broken, and the manifest.
    let t = Instant::now();
    let items = prepare_items(&root, &local)?;
    println!(
        "slurm-check: rendered {} view folders (64²) in {:.1} s; {BROKEN}/{BROKEN_FILE} truncated",
        items.len(),
        t.elapsed().as_secs_f64()
    );
    let job = dir.join("job.sh");
    write(&job, &script)?;
    print_changes(&changes);

    // 4–5. Three submissions of the same script.
    let seconds = submissions(&mut cluster, &local, &items, &job).map_err(|e| cluster.with_logs(&e))?;

    // 6. Stop the cluster (the guard would too) and sum up.
    let version = cluster.version()?;
    drop(cluster);
    println!(
        "slurm-check: passed in {:.1} s ({version}, munge {}, one node: {node})",
        start.elapsed().as_secs_f64(),
        munge_version()
    );
    println!(
        "slurm-check: Slurm found or installed {:.1} s, cluster up {:.1} s, the three array jobs {:.1} s, {:.1} s, {:.1} s",
        installed.as_secs_f64(),
        cluster_up.as_secs_f64(),
        seconds[0],
        seconds[1],
        seconds[2]
    );
    Ok(())
}

/// The three submissions of the script `job` and their checks (steps 4 and 5 of the module's
/// list); returns each array job's wall time.
fn submissions(cluster: &mut Cluster, local: &Local, items: &[Item], job: &Path) -> Result<[f64; 3], String> {
    let first = cluster.submit(job, items, "first run")?;
    let reports = Reports::read(&local.results)?;
    let good: Vec<&Item> = items.iter().filter(|i| !i.broken).collect();
    let broken = items.iter().find(|i| i.broken).expect("one item is broken");
    check_first(&reports, items, &first)?;
    let files = output_files(&local.results, &good)?;
    println!(
        "slurm-check: first run: {} items ok exactly once, {} failed naming {BROKEN_FILE}, over {} shard reports ✓",
        good.len(),
        broken.id,
        reports.files.len()
    );

    let second = cluster.submit(job, items, "resubmitted, nothing fixed")?;
    let reports = Reports::read(&local.results)?;
    check_resume(&reports, items, &second, 2)?;
    if output_files(&local.results, &good)? != files {
        return Err("resubmission: an item that was done has other files, sizes or times: it ran again".into());
    }
    println!(
        "slurm-check: resubmitted: the {} done items skipped (their {} files untouched), {} failed again ✓",
        good.len(),
        files.len(),
        broken.id
    );

    render(&local.wonder3d, &broken.mesh, &broken.folder)?;
    let third = cluster.submit(job, items, "resubmitted after the broken folder was rendered again")?;
    let reports = Reports::read(&local.results)?;
    check_fixed(&reports, items, &third)?;
    if output_files(&local.results, &good)? != files {
        return Err("third run: an item that was done has other files, sizes or times: it ran again".into());
    }
    println!("slurm-check: after the fix: only {} extracted, the other {} skipped ✓", broken.id, good.len());

    Ok([first.seconds, second.seconds, third.seconds])
}

/// The paths and sizes of the local run that replace the documented ones.
struct Local {
    /// The check's folder (`target/slurm-check`).
    dir: PathBuf,
    /// The built `wonder3d` binary.
    wonder3d: PathBuf,
    /// The manifest (`items.txt` in the check's folder).
    manifest: PathBuf,
    /// The batch's `--out`.
    results: PathBuf,
    /// A model folder for `--weights`: the tiny test model (batch loads the model it is given
    /// even when every item is a view folder; this one loads in a moment).
    weights: PathBuf,
    /// Memory per task in MiB.
    mem_mb: u64,
}

impl Local {
    /// The local paths for the check's folder `dir`, with `mem_mb` MiB per task.
    fn new(dir: &Path, mem_mb: u64) -> Self {
        Local {
            dir: dir.to_path_buf(),
            wonder3d: std::path::absolute(target_dir().join("release").join("wonder3d")).unwrap_or_default(),
            manifest: dir.join("items.txt"),
            results: dir.join("results"),
            weights: workspace_root().join("crates/w3d-diffusion/tests/fixtures/wonder3d_tiny"),
            mem_mb,
        }
    }
}

/// One change of the documented script: the documented text (which must appear exactly once),
/// what replaces it here, and why.
struct Change {
    documented: &'static str,
    local: String,
    why: &'static str,
}

/// Every difference between the documented script and the one submitted here. The script's
/// logic (`srun wonder3d batch … --resume …`, the array, `--requeue`, the time limit, the
/// sampling flags, `--jobs 2`, `--timeout`) is the document's.
fn local_changes(local: &Local) -> Vec<Change> {
    let path = |p: &Path| p.display().to_string();
    vec![
        Change {
            documented: "--array=0-15",
            local: format!("--array=0-{}", TASKS - 1),
            why: "3 shards of 6 items instead of 16 shards",
        },
        Change {
            documented: "--cpus-per-task=8",
            local: "--cpus-per-task=1".into(),
            why: "one core each, so the node runs several tasks at once",
        },
        Change { documented: "--mem=16G", local: format!("--mem={}M", local.mem_mb), why: "fits the one node" },
        Change {
            documented: "--output=logs/",
            local: format!("--output={}/", path(&local.dir.join("logs"))),
            why: "an absolute logs folder, made before submitting (Slurm does not create it)",
        },
        Change {
            documented: "srun wonder3d ",
            local: format!("srun {} ", path(&local.wonder3d)),
            why: "the binary just built, not one on PATH",
        },
        Change {
            documented: "/shared/catalogue/items.txt",
            local: path(&local.manifest),
            why: "the check's manifest of six view folders",
        },
        Change { documented: "/shared/results", local: path(&local.results), why: "the check's output folder" },
        Change {
            documented: "/shared/models/wonder3d_plus",
            local: path(&local.weights),
            why: "a model folder that exists: batch checks --weights names one even when every item is a view folder (it loads it only for image items)",
        },
    ]
}

/// The ```` ```bash ```` block under "### Slurm job array" of `docs/scale.md`.
fn documented_script() -> Result<String, String> {
    let doc_path = workspace_root().join("docs/scale.md");
    let doc = std::fs::read_to_string(&doc_path).map_err(|e| format!("{}: {e}", doc_path.display()))?;
    let mut lines = doc.lines().skip_while(|l| l.trim() != "### Slurm job array").skip(1);
    let missing = || format!("{}: no ```bash block under \"### Slurm job array\"", doc_path.display());
    lines.by_ref().find(|l| l.trim() == "```bash").ok_or_else(missing)?;
    let mut script = String::new();
    for line in lines {
        if line.trim() == "```" {
            return Ok(script);
        }
        script.push_str(line);
        script.push('\n');
    }
    Err(missing())
}

/// The documented script with [`local_changes`] applied, and those changes.
fn local_script(documented: &str, local: &Local) -> Result<(String, Vec<Change>), String> {
    let changes = local_changes(local);
    let mut script = documented.to_string();
    for change in &changes {
        let n = script.matches(change.documented).count();
        if n != 1 {
            return Err(format!(
                "docs/scale.md's Slurm script has `{}` {n} times (expected once): the document changed, so update \
                 xtask/src/slurm.rs's list of local changes with it",
                change.documented
            ));
        }
        script = script.replacen(change.documented, &change.local, 1);
    }
    for needed in ["#!/bin/bash", "srun ", " batch ", "--resume", "#SBATCH --requeue"] {
        if !script.contains(needed) {
            return Err(format!("docs/scale.md's Slurm script has no `{needed}`"));
        }
    }
    Ok((script, changes))
}

/// Prints the list of [`local_changes`].
fn print_changes(changes: &[Change]) {
    println!("slurm-check: the script of docs/scale.md, \"Slurm job array\", with these changes only:");
    for c in changes {
        println!("  `{}` → `{}`: {}", c.documented.trim(), c.local.trim(), c.why);
    }
}

/// Whether this process runs as root.
fn is_root() -> bool {
    Command::new("id").arg("-u").output().is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// `name` on `PATH` or in the sbin folders (where Debian puts the daemons).
fn which(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin", "/usr/bin", "/sbin", "/bin"].map(PathBuf::from))
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// The Slurm and munge programs the check runs.
struct Tools {
    /// Name → absolute path.
    paths: BTreeMap<&'static str, PathBuf>,
}

/// The programs the check needs; `slurm-wlm` brings all of them (munge as a dependency).
const PROGRAMS: [&str; 8] = ["slurmctld", "slurmd", "sbatch", "squeue", "sinfo", "scontrol", "scancel", "munged"];

impl Tools {
    /// Every program of [`PROGRAMS`], installing `slurm-wlm` with apt-get when one is missing
    /// (and `apt-get update` first only if that install fails).
    fn find_or_install() -> Result<Self, String> {
        let find = || PROGRAMS.iter().map(|&p| which(p).map(|path| (p, path))).collect::<Option<BTreeMap<_, _>>>();
        if let Some(paths) = find() {
            return Ok(Tools { paths });
        }
        let missing: Vec<&str> = PROGRAMS.iter().copied().filter(|p| which(p).is_none()).collect();
        let apt = |args: &[&str]| {
            println!("slurm-check: {} missing: apt-get {}", missing.join(", "), args.join(" "));
            let t = Instant::now();
            let ok = Command::new("apt-get")
                // Wait for another apt-get (or dpkg) to finish instead of failing at once.
                .args(["-o", "DPkg::Lock::Timeout=300"])
                .args(args)
                .env("DEBIAN_FRONTEND", "noninteractive")
                .stdout(Stdio::null())
                .status()
                .is_ok_and(|s| s.success());
            println!(
                "slurm-check: apt-get {} {} in {:.1} s",
                args[0],
                if ok { "done" } else { "failed" },
                t.elapsed().as_secs_f64()
            );
            ok
        };
        let install = ["install", "-y", "slurm-wlm"];
        if !(apt(&install) || (apt(&["update"]) && apt(&install))) {
            return Err("`apt-get install -y slurm-wlm` failed: install Slurm (slurmctld, slurmd, the client \
                        commands) and munge, then rerun"
                .into());
        }
        let paths = find().ok_or("slurm-wlm installed, but some of its programs are still missing")?;
        Ok(Tools { paths })
    }

    /// The absolute path of program `name` (one of [`PROGRAMS`]).
    fn get(&self, name: &str) -> &Path {
        &self.paths[name]
    }

    /// This machine's node line from `slurmd -C` (`NodeName=… CPUs=… RealMemory=…`).
    fn node_line(&self) -> Result<String, String> {
        let out = Command::new(self.get("slurmd")).arg("-C").output().map_err(|e| format!("slurmd -C: {e}"))?;
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .find(|l| l.starts_with("NodeName="))
            .map(|l| l.trim().to_string())
            .ok_or_else(|| format!("slurmd -C printed no NodeName line: {}", String::from_utf8_lossy(&out.stderr)))
    }
}

/// The value of `key=` in a line of `key=value` words.
fn field<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    line.split_whitespace().find_map(|w| w.strip_prefix(key)?.strip_prefix('='))
}

/// The check's `slurm.conf`: one node (this machine, as `slurmd -C` sees it) reached over
/// loopback, every file in `dir`, root as the Slurm user, munge on the check's own socket, no
/// accounting, no cgroups (so it also runs in a container).
fn slurm_conf(dir: &Path, node: &str, munge_socket: &Path) -> String {
    let name = field(node, "NodeName").unwrap_or("localhost");
    let d = dir.display();
    format!(
        "# Written by `cargo xtask slurm-check` (xtask/src/slurm.rs).\n\
         ClusterName=w3dcheck\n\
         SlurmctldHost={name}(127.0.0.1)\n\
         SlurmctldPort={ctld}\n\
         SlurmdPort={slurmd}\n\
         SlurmUser=root\n\
         SlurmdUser=root\n\
         AuthType=auth/munge\n\
         AuthInfo=socket={socket}\n\
         StateSaveLocation={d}/state\n\
         SlurmdSpoolDir={d}/spool\n\
         SlurmctldPidFile={d}/slurmctld.pid\n\
         SlurmdPidFile={d}/slurmd.pid\n\
         SlurmctldLogFile={d}/log/slurmctld.log\n\
         SlurmdLogFile={d}/log/slurmd.log\n\
         ProctrackType=proctrack/linuxproc\n\
         TaskPlugin=task/none\n\
         SelectType=select/cons_tres\n\
         SelectTypeParameters=CR_Core_Memory\n\
         SchedulerType=sched/builtin\n\
         MpiDefault=none\n\
         JobAcctGatherType=jobacct_gather/none\n\
         AccountingStorageType=accounting_storage/none\n\
         MailProg=/bin/true\n\
         ReturnToService=2\n\
         MinJobAge=3600\n\
         {node} NodeAddr=127.0.0.1 State=UNKNOWN\n\
         PartitionName=debug Nodes={name} Default=YES MaxTime=INFINITE State=UP\n",
        ctld = PORTS.0,
        slurmd = PORTS.1,
        socket = munge_socket.display(),
    )
}

/// The daemons of an earlier check that was killed before its guard ran, shut down the way
/// the guard does it: that cluster's jobs cancelled, `scontrol shutdown`, then SIGTERM to each
/// pid file's process whose command line names the check's folder (so it is one a check
/// started), each waited for.
fn stop_stale(dir: &Path, tools: &Tools) {
    let alive = |pid_file: &str| -> Option<String> {
        let pid = std::fs::read_to_string(dir.join(pid_file)).ok()?.trim().to_string();
        let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).ok()?;
        (!pid.is_empty() && String::from_utf8_lossy(&cmdline).contains(&*dir.to_string_lossy())).then_some(pid)
    };
    // A process that ended (a zombie included) has an empty command line.
    let wait = |pid: &str| {
        let t = Instant::now();
        while std::fs::read(format!("/proc/{pid}/cmdline")).is_ok_and(|c| !c.is_empty())
            && t.elapsed() < Duration::from_secs(30)
        {
            std::thread::sleep(Duration::from_millis(200));
        }
    };
    let conf = dir.join("slurm.conf");
    if let Some(pid) = alive("slurmctld.pid") {
        println!("slurm-check: an earlier check's slurmctld ({pid}) still runs: cancelling its jobs, shutting it down");
        let slurm = |name: &str, args: &[&str]| {
            Command::new(tools.get(name)).args(args).env("SLURM_CONF", &conf).stderr(Stdio::null()).output()
        };
        let _ = slurm("scancel", &["--user=root"]);
        let t = Instant::now();
        while slurm("squeue", &["-h"]).is_ok_and(|o| !o.stdout.is_empty()) && t.elapsed() < Duration::from_secs(30) {
            std::thread::sleep(Duration::from_millis(500));
        }
        let _ = slurm("scontrol", &["shutdown"]);
        wait(&pid);
    }
    for pid_file in ["slurmctld.pid", "slurmd.pid", "munge/munged.pid"] {
        if let Some(pid) = alive(pid_file) {
            println!("slurm-check: stopping {pid_file} {pid} left by an earlier check");
            let _ = Command::new("kill").arg(&pid).status();
            wait(&pid);
        }
    }
}

/// `create_dir_all`, its error naming the folder.
fn mkdir(dir: &Path) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))
}

/// `fs::write`, its error naming the file.
fn write(path: &Path, text: &str) -> Result<(), String> {
    std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

/// The last `n` lines of a file, or a note that it cannot be read.
fn tail(path: &Path, n: usize) -> String {
    match std::fs::read_to_string(path) {
        Ok(text) => {
            let lines: Vec<&str> = text.lines().collect();
            lines[lines.len().saturating_sub(n)..].join("\n")
        }
        Err(e) => format!("({e})"),
    }
}

/// munge's version, from `munged -V`.
fn munge_version() -> String {
    Command::new(which("munged").unwrap_or_else(|| "munged".into()))
        .arg("-V")
        .output()
        .map(|o| {
            let text = String::from_utf8_lossy(&o.stdout);
            let word = text.split_whitespace().next().unwrap_or("?");
            word.trim_start_matches("munge-").to_string()
        })
        .unwrap_or_else(|_| "?".into())
}

/// The running cluster: `munged`, `slurmctld` and `slurmd` as children of this process.
/// Dropping it stops them.
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    tools: Tools,
    /// `(name, process)`: munged first, then slurmctld and slurmd.
    daemons: Vec<(&'static str, Child)>,
    /// The job ids this check submitted.
    jobs: Vec<String>,
}

/// One array task's end, from `scontrol show job`.
struct Task {
    index: usize,
    state: String,
    exit: String,
    start: String,
    end: String,
}

/// One submission: its job id, its tasks and its wall time (submission to the array's end).
struct Submission {
    id: String,
    tasks: Vec<Task>,
    seconds: f64,
}

impl Cluster {
    /// Starts munged with a fresh key, then slurmctld and slurmd on `slurm.conf`, and waits
    /// until the node is idle.
    fn start(dir: &Path, tools: Tools, node: &str) -> Result<Self, String> {
        let munge = dir.join("munge");
        mkdir(&munge)?;
        // munged wants the socket's folder searchable by everyone and the key readable by its
        // owner alone.
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&munge, std::fs::Permissions::from_mode(0o755))
            .map_err(|e| format!("{}: {e}", munge.display()))?;
        let key = munge.join("munge.key");
        // A fresh 1024-bit key, as `mungekey` makes (munge takes any key of 32 bytes or more).
        let mut bytes = [0u8; 128];
        {
            use std::io::{Read, Write};
            use std::os::unix::fs::OpenOptionsExt;
            std::fs::File::open("/dev/urandom")
                .and_then(|mut f| f.read_exact(&mut bytes))
                .map_err(|e| format!("/dev/urandom: {e}"))?;
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .open(&key)
                .and_then(|mut f| f.write_all(&bytes))
                .map_err(|e| format!("{}: {e}", key.display()))?;
        }
        let socket = munge.join("munge.socket");
        let conf = dir.join("slurm.conf");
        write(&conf, &slurm_conf(dir, node, &socket))?;
        let mut cluster =
            Cluster { dir: dir.to_path_buf(), conf: conf.clone(), tools, daemons: Vec::new(), jobs: Vec::new() };

        // Each daemon's standard output and error, into one file.
        let log = |name: &str| -> Result<(Stdio, Stdio), String> {
            let path = dir.join("log").join(format!("{name}.stderr"));
            let file = std::fs::File::create(&path).map_err(|e| format!("{}: {e}", path.display()))?;
            let copy = file.try_clone().map_err(|e| format!("{}: {e}", path.display()))?;
            Ok((Stdio::from(file), Stdio::from(copy)))
        };
        let (out, err) = log("munged")?;
        let munged = Command::new(cluster.tools.get("munged"))
            .arg("--foreground")
            .arg(format!("--key-file={}", key.display()))
            .arg(format!("--socket={}", socket.display()))
            .arg(format!("--pid-file={}", munge.join("munged.pid").display()))
            .arg(format!("--log-file={}", dir.join("log/munged.log").display()))
            .arg(format!("--seed-file={}", munge.join("munged.seed").display()))
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err)
            .spawn()
            .map_err(|e| format!("cannot start munged: {e}"))?;
        cluster.daemons.push(("munged", munged));
        cluster.wait_for("munged's socket", |_| Ok(socket.exists()))?;
        for name in ["slurmctld", "slurmd"] {
            let (out, err) = log(name)?;
            let child = Command::new(cluster.tools.get(name))
                .arg("-D")
                .arg("-f")
                .arg(&conf)
                .env("SLURM_CONF", &conf)
                .current_dir(dir)
                .stdin(Stdio::null())
                .stdout(out)
                .stderr(err)
                .spawn()
                .map_err(|e| format!("cannot start {name}: {e}"))?;
            cluster.daemons.push((name, child));
        }
        cluster.wait_for("the node to be idle", |c: &Cluster| {
            let out = c.slurm("sinfo").args(["-h", "-N", "-o", "%T"]).output().map_err(|e| format!("sinfo: {e}"))?;
            Ok(String::from_utf8_lossy(&out.stdout).trim() == "idle")
        })?;
        Ok(cluster)
    }

    /// Polls `ready` every 0.2 s until it holds; fails when a daemon exits or after
    /// [`START_TIMEOUT`], with the daemons' logs.
    fn wait_for(&mut self, what: &str, mut ready: impl FnMut(&Cluster) -> Result<bool, String>) -> Result<(), String> {
        let t = Instant::now();
        loop {
            let exited = self.daemons.iter_mut().find_map(|(name, child)| Some((*name, child.try_wait().ok()??)));
            if let Some((name, status)) = exited {
                return Err(self.with_logs(&format!("{name} exited ({status}) while waiting for {what}")));
            }
            if ready(self)? {
                return Ok(());
            }
            if t.elapsed() > START_TIMEOUT {
                return Err(self.with_logs(&format!("gave up waiting {} s for {what}", START_TIMEOUT.as_secs())));
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// A Slurm client command (`sinfo`, `sbatch` …) on the check's `slurm.conf`.
    fn slurm(&self, name: &str) -> Command {
        let mut cmd = Command::new(self.tools.get(name));
        cmd.env("SLURM_CONF", &self.conf).current_dir(&self.dir);
        cmd
    }

    /// Runs a Slurm client command and returns its standard output.
    fn output(&self, name: &str, args: &[&str]) -> Result<String, String> {
        let out = self.slurm(name).args(args).output().map_err(|e| format!("{name}: {e}"))?;
        if !out.status.success() {
            return Err(self.with_logs(&format!(
                "{name} {} failed ({}): {}",
                args.join(" "),
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            )));
        }
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// `slurm 22.05.8`, from `sinfo -V`.
    fn version(&self) -> Result<String, String> {
        Ok(self.output("sinfo", &["-V"])?.trim().to_string())
    }

    /// The partition and node, from `sinfo`.
    fn sinfo(&self) -> Result<String, String> {
        Ok(self.output("sinfo", &["-h", "-o", "partition %P, %D node %N (%c CPUs, %m MB), %T"])?.trim().to_string())
    }

    /// `message`, then the tail of every log of the cluster and of the array's tasks.
    /// A message that has them already is returned as it is.
    fn with_logs(&self, message: &str) -> String {
        let mut text = message.to_string();
        if text.contains(LOG_MARK) {
            return text;
        }
        let mut logs: Vec<PathBuf> = ["log", "logs"]
            .iter()
            .filter_map(|sub| std::fs::read_dir(self.dir.join(sub)).ok())
            .flat_map(|entries| entries.flatten().map(|e| e.path()))
            .collect();
        logs.sort();
        // The daemons write their log file and, in the foreground, the same lines to stderr:
        // the stderr file only when the log file says nothing.
        let says_something = |p: &Path| std::fs::metadata(p).is_ok_and(|m| m.len() > 0);
        logs.retain(|p| !(p.extension().is_some_and(|x| x == "stderr") && says_something(&p.with_extension("log"))));
        for log in logs {
            text.push_str(&format!("\n{LOG_MARK}{} (last 30 lines)\n{}", log.display(), tail(&log, 30)));
        }
        text
    }

    /// Submits `script` with `sbatch --parsable`, waits for the whole array to leave the
    /// queue and returns its tasks' ends (printed as a table).
    fn submit(&mut self, script: &Path, items: &[Item], what: &str) -> Result<Submission, String> {
        let t = Instant::now();
        let out = self.output("sbatch", &["--parsable", &script.display().to_string()])?;
        let id = out.trim().split(';').next().unwrap_or("").to_string();
        if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
            return Err(format!("sbatch --parsable printed {out:?}, not a job id"));
        }
        self.jobs.push(id.clone());
        println!("slurm-check: submitted array job {id} ({what})");
        loop {
            let queued = self.output("squeue", &["-h", "-j", &id, "-o", "%i %T"])?;
            if queued.trim().is_empty() {
                break;
            }
            if t.elapsed() > JOB_TIMEOUT {
                return Err(self.with_logs(&format!(
                    "array job {id} still queued or running after {} s:\n{queued}",
                    JOB_TIMEOUT.as_secs()
                )));
            }
            std::thread::sleep(Duration::from_millis(500));
        }
        let seconds = t.elapsed().as_secs_f64();
        let mut tasks = parse_tasks(&self.output("scontrol", &["show", "job", &id])?);
        tasks.sort_by_key(|t| t.index);
        if tasks.iter().map(|t| t.index).collect::<Vec<_>>() != (0..TASKS).collect::<Vec<_>>() {
            return Err(self.with_logs(&format!("array job {id}: expected tasks 0..{TASKS}, scontrol shows others")));
        }
        println!("  task  shard  items                       state      exit  start → end");
        for task in &tasks {
            let ids: Vec<&str> =
                items.iter().filter(|i| i.index % TASKS == task.index).map(|i| i.id.as_str()).collect();
            println!(
                "  {:<4}  {}/{}    {:<26}  {:<9}  {:<4}  {} → {}",
                task.index,
                task.index,
                TASKS,
                ids.join(", "),
                task.state,
                task.exit,
                task.start,
                task.end
            );
        }
        println!("  array job {id} done in {seconds:.1} s");
        Ok(Submission { id, tasks, seconds })
    }
}

impl Drop for Cluster {
    /// Cancels this check's jobs that are still queued, shuts Slurm down, stops munged, and
    /// waits for each daemon (killing it after 20 s).
    fn drop(&mut self) {
        let slurm_up = self.daemons.iter().any(|(n, _)| *n == "slurmctld");
        if slurm_up && !self.jobs.is_empty() {
            let queued = |c: &Cluster| {
                c.slurm("squeue")
                    .args(["-h", "-j", &c.jobs.join(",")])
                    .stderr(Stdio::null())
                    .output()
                    .is_ok_and(|o| !String::from_utf8_lossy(&o.stdout).trim().is_empty())
            };
            if queued(self) {
                eprintln!("slurm-check: cancelling jobs {}", self.jobs.join(","));
                let _ = self.slurm("scancel").args(&self.jobs).stderr(Stdio::null()).status();
                let t = Instant::now();
                while queued(self) && t.elapsed() < Duration::from_secs(30) {
                    std::thread::sleep(Duration::from_millis(500));
                }
            }
        }
        if slurm_up {
            let _ = self.slurm("scontrol").arg("shutdown").stdout(Stdio::null()).stderr(Stdio::null()).status();
        }
        // Slurm's daemons first (they stop on `scontrol shutdown`), munged last.
        for (name, mut child) in self.daemons.drain(..).rev() {
            if name == "munged" {
                let _ = Command::new("kill").arg(child.id().to_string()).status();
            }
            let t = Instant::now();
            while matches!(child.try_wait(), Ok(None)) && t.elapsed() < Duration::from_secs(20) {
                std::thread::sleep(Duration::from_millis(100));
            }
            if matches!(child.try_wait(), Ok(None)) {
                eprintln!("slurm-check: {name} ({}) did not stop: killing it", child.id());
                let _ = child.kill();
                let _ = child.wait();
            }
        }
        println!("slurm-check: cluster stopped (scontrol shutdown, munged terminated)");
    }
}

/// The array tasks in `scontrol show job` output (one record per task, words `key=value`).
fn parse_tasks(text: &str) -> Vec<Task> {
    text.split("\n\n")
        .filter_map(|record| {
            let words: Vec<&str> = record.split_whitespace().collect();
            let get = |key: &str| words.iter().find_map(|w| w.strip_prefix(key)?.strip_prefix('=')).unwrap_or("?");
            Some(Task {
                index: get("ArrayTaskId").parse().ok()?,
                state: get("JobState").to_string(),
                exit: get("ExitCode").to_string(),
                start: get("StartTime").rsplit('T').next().unwrap_or("?").to_string(),
                end: get("EndTime").rsplit('T').next().unwrap_or("?").to_string(),
            })
        })
        .collect()
}

/// One manifest item.
struct Item {
    /// Its place in the manifest (0-based): it belongs to shard `index mod 3`.
    index: usize,
    /// Its id (the view folder's manifest path, `views/spot` → `views_spot`).
    id: String,
    /// The mesh its views are rendered from.
    mesh: PathBuf,
    /// Its view folder.
    folder: PathBuf,
    /// Whether its views are damaged.
    broken: bool,
}

/// Renders `mesh`'s 6 views at 64² into `folder`.
fn render(wonder3d: &Path, mesh: &Path, folder: &Path) -> Result<(), String> {
    let out = Command::new(wonder3d)
        .arg("render")
        .arg(mesh)
        .args(["--size", "64", "--out"])
        .arg(folder)
        .output()
        .map_err(|e| format!("{}: {e}", wonder3d.display()))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!("wonder3d render {}: {}", mesh.display(), String::from_utf8_lossy(&out.stderr)))
    }
}

/// Renders the six view folders, truncates the broken one's normal map and writes the manifest.
fn prepare_items(root: &Path, local: &Local) -> Result<Vec<Item>, String> {
    let mut items = Vec::new();
    let mut manifest = String::from("# cargo xtask slurm-check: six view folders, one with a truncated normal map\n");
    for (index, (name, mesh, syntax)) in ITEMS.iter().enumerate() {
        let mut mesh = root.join(mesh);
        if !mesh.is_file() {
            mesh = root.join(["assets/spot.obj", "assets/bob_tri.obj"][index % 2]);
        }
        let folder = local.dir.join("views").join(name);
        render(&local.wonder3d, &mesh, &folder)?;
        let input = format!("views/{name}");
        manifest.push_str(&match syntax {
            Syntax::Path => format!("{input}\n"),
            Syntax::Json => format!("{{\"input\": \"{input}\", \"preset\": \"fast\", \"texture_size\": 256}}\n"),
        });
        items.push(Item { index, id: format!("views_{name}"), mesh, folder, broken: *name == BROKEN });
    }
    let damaged = local.dir.join("views").join(BROKEN).join(BROKEN_FILE);
    std::fs::OpenOptions::new()
        .write(true)
        .open(&damaged)
        .and_then(|f| f.set_len(100))
        .map_err(|e| format!("{}: {e}", damaged.display()))?;
    write(&local.manifest, &manifest)?;
    Ok(items)
}

/// Every line of the batch's shard reports (`results/reports/*.jsonl`).
struct Reports {
    /// The report files' names.
    files: Vec<String>,
    /// Every line, in file order.
    lines: Vec<Value>,
}

impl Reports {
    /// Reads every `*.jsonl` of `results/reports`, in file-name order.
    fn read(results: &Path) -> Result<Self, String> {
        let dir = results.join("reports");
        let mut files: Vec<String> = std::fs::read_dir(&dir)
            .map_err(|e| format!("{}: {e}", dir.display()))?
            .flatten()
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|n| n.ends_with(".jsonl"))
            .collect();
        files.sort();
        let mut lines = Vec::new();
        for name in &files {
            let text = std::fs::read_to_string(dir.join(name)).map_err(|e| format!("{name}: {e}"))?;
            for line in text.lines().filter(|l| !l.trim().is_empty()) {
                lines.push(serde_json::from_str(line).map_err(|e| format!("{name}: {e}: {line}"))?);
            }
        }
        Ok(Reports { files, lines })
    }

    /// The report lines of item `id`, in order.
    fn of(&self, id: &str) -> Vec<&Value> {
        self.lines.iter().filter(|l| l["id"] == id).collect()
    }
}

/// The statuses of `item`'s report lines, after checking they name its shard.
fn statuses(reports: &Reports, item: &Item) -> Result<Vec<String>, String> {
    let shard = format!("{}/{TASKS}", item.index % TASKS);
    reports
        .of(&item.id)
        .into_iter()
        .map(|l| {
            if l["shard"] != shard.as_str() {
                return Err(format!("{}: reported by shard {}, expected {shard}", item.id, l["shard"]));
            }
            Ok(l["status"].as_str().unwrap_or("?").to_string())
        })
        .collect()
}

/// The report files the three shards must have written.
fn expected_report_files() -> Vec<String> {
    (0..TASKS).map(|i| format!("shard-{i:04}-of-{TASKS:04}.jsonl")).collect()
}

/// Checks what every submission must show: one report file per shard, only the six items,
/// `runs` lines per item, and each task's exit code (1 for the shard with a failed item).
fn check_common(
    reports: &Reports,
    items: &[Item],
    sub: &Submission,
    runs: usize,
    broken_fails: bool,
) -> Result<(), String> {
    if reports.files != expected_report_files() {
        return Err(format!("reports {:?}, expected {:?}", reports.files, expected_report_files()));
    }
    if reports.lines.len() != runs * items.len() {
        return Err(format!("{} report lines after {runs} runs of {} items", reports.lines.len(), items.len()));
    }
    for line in &reports.lines {
        if !items.iter().any(|i| line["id"] == i.id.as_str()) {
            return Err(format!("a report line of an unknown item: {line}"));
        }
    }
    for task in &sub.tasks {
        let fails = broken_fails && items.iter().any(|i| i.broken && i.index % TASKS == task.index);
        let (state, exit) = if fails { ("FAILED", "1:0") } else { ("COMPLETED", "0:0") };
        if task.state != state || task.exit != exit {
            return Err(format!(
                "job {} task {}: {} with exit code {}, expected {state} with {exit} (batch exits 1 when an item fails)",
                sub.id, task.index, task.state, task.exit
            ));
        }
    }
    Ok(())
}

/// The broken item's error must name the damaged file.
fn check_broken_error(reports: &Reports, item: &Item) -> Result<(), String> {
    let last = *reports.of(&item.id).last().ok_or(format!("{}: not reported", item.id))?;
    let error = last["error"].as_str().unwrap_or("");
    let file = item.folder.join(BROKEN_FILE);
    if !error.contains(&*file.to_string_lossy()) {
        return Err(format!("{}: the error does not name {}: {error:?}", item.id, file.display()));
    }
    println!("  {} failed: {error}", item.id);
    Ok(())
}

/// First run: every good item ok once with its mesh and `done.json`, the broken one failed
/// (naming its file) with no folder.
fn check_first(reports: &Reports, items: &[Item], sub: &Submission) -> Result<(), String> {
    check_common(reports, items, sub, 1, true)?;
    let results = reports_root(reports, items)?;
    for item in items {
        let want = if item.broken { "failed" } else { "ok" };
        let got = statuses(reports, item)?;
        if got != [want] {
            return Err(format!("{}: statuses {got:?}, expected [{want:?}]", item.id));
        }
        let folder = results.join(&item.id);
        let complete = folder.join("mesh.glb").is_file() && folder.join("done.json").is_file();
        if item.broken == folder.exists() || (!item.broken && !complete) {
            return Err(format!("{}: output folder {} is not as expected", item.id, folder.display()));
        }
    }
    check_broken_error(reports, items.iter().find(|i| i.broken).expect("one broken item"))
}

/// Resubmission with nothing fixed: each good item's new line is `skipped`, the broken one's
/// `failed` again, and no good item has a second `ok`.
fn check_resume(reports: &Reports, items: &[Item], sub: &Submission, runs: usize) -> Result<(), String> {
    check_common(reports, items, sub, runs, true)?;
    for item in items {
        let got = statuses(reports, item)?;
        let want: Vec<&str> = if item.broken { vec!["failed"; runs] } else { vec!["ok", "skipped"] };
        if got != want {
            return Err(format!("{}: statuses {got:?}, expected {want:?}", item.id));
        }
    }
    check_broken_error(reports, items.iter().find(|i| i.broken).expect("one broken item"))
}

/// After the fix: the formerly broken item ok, every other skipped, all six ok exactly once.
fn check_fixed(reports: &Reports, items: &[Item], sub: &Submission) -> Result<(), String> {
    check_common(reports, items, sub, 3, false)?;
    let results = reports_root(reports, items)?;
    for item in items {
        let got = statuses(reports, item)?;
        let want: Vec<&str> =
            if item.broken { vec!["failed", "failed", "ok"] } else { vec!["ok", "skipped", "skipped"] };
        if got != want {
            return Err(format!("{}: statuses {got:?}, expected {want:?}", item.id));
        }
        if !results.join(&item.id).join("done.json").is_file() {
            return Err(format!("{}: no done.json after the third run", item.id));
        }
    }
    Ok(())
}

/// The results folder, from a good item's `folder` in the reports.
fn reports_root(reports: &Reports, items: &[Item]) -> Result<PathBuf, String> {
    let good = items.iter().find(|i| !i.broken).expect("good items");
    let folder = reports.of(&good.id).first().and_then(|l| l["folder"].as_str()).map(PathBuf::from);
    folder.and_then(|f| f.parent().map(Path::to_path_buf)).ok_or(format!("{}: no folder in its report", good.id))
}

/// Every file of the good items' output folders with its size and modification time.
fn output_files(results: &Path, good: &[&Item]) -> Result<BTreeMap<PathBuf, (u64, SystemTime)>, String> {
    let mut files = BTreeMap::new();
    for item in good {
        let folder = results.join(&item.id);
        for entry in std::fs::read_dir(&folder).map_err(|e| format!("{}: {e}", folder.display()))?.flatten() {
            let meta = entry.metadata().map_err(|e| format!("{}: {e}", entry.path().display()))?;
            files.insert(entry.path(), (meta.len(), meta.modified().map_err(|e| e.to_string())?));
        }
    }
    Ok(files)
}
