//! One hostile case: what it runs, what it expects, the files it needs; how it is run and
//! how its run is classified.

use std::collections::BTreeMap;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The subcommands in the CLI's order.
pub(crate) const COMMANDS: [&str; 13] = [
    "info",
    "render",
    "eval",
    "reconstruct",
    "texture",
    "refine",
    "demo",
    "prepare",
    "generate",
    "run",
    "batch",
    "dataset",
    "train",
];

/// The placeholder for the case's own folder in arguments, tokens and setup paths.
pub(crate) const CASE_DIR: &str = "{case}";

/// Environment variables `wonder3d batch` reads its shard from: removed for every case so
/// that a campaign run inside a Slurm or Kubernetes job runs whole manifests.
const SHARD_VARIABLES: [&str; 4] =
    ["SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "JOB_COMPLETION_INDEX", "W3D_SHARD_COUNT"];

/// The address space each run may use (`ulimit -v`, KiB): 4 GiB, so that a command reading
/// `/dev/zero` or trusting a huge header fails on allocation instead of taking the machine's
/// memory (several times what any valid case here needs).
pub(crate) const MEMORY_LIMIT_KIB: u64 = 4 << 20;

/// Resident memory above which a run counts as allocating without bound (KiB): 2 GiB.
const MEMORY_FINDING_KIB: u64 = 2 << 20;

/// Messages that mean the command line was misread rather than the culprit named (clap's
/// "unexpected argument '-1'" with its `-- -1` tip): an error containing one names nothing.
const MISREADINGS: [&str; 2] = ["tip: to pass", "unexpected argument '-"];

/// What a case expects of the command.
#[derive(Clone, Debug)]
pub(crate) enum Expect {
    /// Exit code 0 (a hostile-looking input that is valid).
    Success,
    /// A non-zero exit whose error message contains at least one of the tokens (the
    /// offending path or file name, the flag, the damaged field, key or tensor).
    Error(Vec<String>),
    /// Either exit code 0 or an error naming one of the tokens (inputs where refusing and
    /// accepting are both defensible).
    Either(Vec<String>),
}

/// A file or folder a case creates in its own folder before it runs (paths relative to it).
#[derive(Clone, Debug)]
pub(crate) enum Setup {
    /// A file with these bytes.
    Write(String, Vec<u8>),
    /// A copy of a file or (recursively) a folder.
    Copy(PathBuf, String),
    /// An empty folder.
    Dir(String),
    /// A named pipe (nothing ever writes to it).
    Fifo(String),
    /// A symbolic link to the target.
    Symlink(PathBuf, String),
}

/// One row of the campaign's table.
#[derive(Clone, Debug)]
pub(crate) struct Case {
    /// Unique name, `command/what`.
    pub name: String,
    /// The subcommand it drives (the report groups by it).
    pub command: &'static str,
    /// Arguments after the binary; `{case}` stands for the case's folder.
    pub args: Vec<String>,
    /// What the run must do.
    pub expect: Expect,
    /// Files made in the case's folder first.
    pub setup: Vec<Setup>,
    /// Wall-clock limit.
    pub timeout: Duration,
    /// Part of the `--quick` subset.
    pub quick: bool,
    /// Paths removed from the error message before the tokens are looked for: a damaged
    /// folder's own path, so that a token such as `size` does not match the folder's name
    /// (`ds-size-string`) when the message only names the folder.
    pub mask: Vec<String>,
    /// Phrases that make an error wrong even when it names a token (advice naming another
    /// flag than the culprit).
    pub forbid: Vec<String>,
    /// Files present in the case's folder before the run must be unchanged after it (false
    /// for cases that replace an earlier output on purpose).
    pub preserve: bool,
}

/// Default wall-clock limit of a case.
pub(crate) const DEFAULT_TIMEOUT: Duration = Duration::from_secs(20);

impl Case {
    /// A case of `command` named `command/what` running `args` (the subcommand first), expecting
    /// an error that names one of `tokens`.
    pub(crate) fn new(command: &'static str, what: &str, args: Vec<String>, tokens: &[&str]) -> Case {
        Case {
            name: format!("{command}/{what}"),
            command,
            args,
            expect: Expect::Error(tokens.iter().map(|t| t.to_string()).collect()),
            setup: Vec::new(),
            timeout: DEFAULT_TIMEOUT,
            quick: false,
            forbid: Vec::new(),
            mask: Vec::new(),
            preserve: true,
        }
    }

    /// The case expects exit code 0.
    pub(crate) fn succeeds(mut self) -> Case {
        self.expect = Expect::Success;
        self
    }

    /// The case accepts exit code 0 as well as an error naming one of its tokens.
    pub(crate) fn either(mut self) -> Case {
        if let Expect::Error(tokens) = self.expect {
            self.expect = Expect::Either(tokens);
        }
        self
    }

    /// Adds a file or folder to make before the run.
    pub(crate) fn with(mut self, setup: Setup) -> Case {
        self.setup.push(setup);
        self
    }

    /// Sets the wall-clock limit.
    pub(crate) fn timeout(mut self, seconds: u64) -> Case {
        self.timeout = Duration::from_secs(seconds);
        self
    }

    /// Puts the case into the `--quick` subset when `yes`.
    pub(crate) fn quick_if(mut self, yes: bool) -> Case {
        self.quick |= yes;
        self
    }

    /// An error containing one of `phrases` counts as naming nothing (it points elsewhere).
    pub(crate) fn forbid(mut self, phrases: &[&str]) -> Case {
        self.forbid.extend(phrases.iter().map(|p| p.to_string()));
        self
    }

    /// Tokens are not looked for in `path` (see [`Case::mask`]).
    pub(crate) fn masking(mut self, path: &str) -> Case {
        self.mask.push(path.to_string());
        self
    }

    /// The case may change the files of its folder (it replaces an earlier output on purpose).
    pub(crate) fn replaces(mut self) -> Case {
        self.preserve = false;
        self
    }
}

/// How a run ended, worst first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Class {
    /// A Rust panic ("panicked at" on stderr, or exit code 101).
    Panic,
    /// Killed by a signal (abort on allocation, segmentation fault, …).
    Signal,
    /// Still running at the case's limit (killed).
    Timeout,
    /// Hit the memory limit or held more than 2 GiB resident (an allocation without bound,
    /// whatever the exit).
    Memory,
    /// Exit code 0 where the case expects an error.
    SuccessOnBadInput,
    /// An error that names none of the case's tokens (or misreads the command line).
    ErrorNamingNothing,
    /// A file present before the run was changed or removed by it.
    InputChanged,
    /// An error where the case expects success.
    ErrorOnGoodInput,
    /// What the case expects.
    Ok,
}

impl Class {
    /// Every class, in report order.
    pub(crate) const ALL: [Class; 9] = [
        Class::Panic,
        Class::Signal,
        Class::Timeout,
        Class::Memory,
        Class::SuccessOnBadInput,
        Class::ErrorNamingNothing,
        Class::InputChanged,
        Class::ErrorOnGoodInput,
        Class::Ok,
    ];

    /// The class's name in reports.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Class::Panic => "panic",
            Class::Signal => "signal",
            Class::Timeout => "timeout",
            Class::Memory => "memory",
            Class::SuccessOnBadInput => "success-on-bad-input",
            Class::ErrorNamingNothing => "error-naming-nothing",
            Class::InputChanged => "input-changed",
            Class::ErrorOnGoodInput => "error-on-good-input",
            Class::Ok => "ok",
        }
    }
}

/// The result of running one case.
#[derive(Clone, Debug)]
pub(crate) struct Outcome {
    /// The case's position in the whole table (its folder is `cases/NNNN`).
    pub index: usize,
    /// The case's name.
    pub name: String,
    /// Its subcommand.
    pub command: &'static str,
    /// The arguments as run (placeholders replaced).
    pub args: Vec<String>,
    /// The class.
    pub class: Class,
    /// Why the class was given (for non-ok classes).
    pub reason: String,
    /// Exit code, if the process exited.
    pub code: Option<i32>,
    /// Signal number, if a signal ended it.
    pub signal: Option<i32>,
    /// Wall time of the run in seconds.
    pub seconds: f64,
    /// Peak resident memory seen while it ran (KiB, sampled every 10 ms).
    pub peak_kib: u64,
    /// The first error line of stderr (or its first line).
    pub first_line: String,
}

/// Where a case runs: its folder, and the files its output goes to.
pub(crate) struct Place {
    /// The case's own folder (`cases/NNNN`), created empty.
    pub dir: PathBuf,
    /// stdout and stderr of the run (`logs/NNNN.out`, `logs/NNNN.err`).
    pub stdout: PathBuf,
    /// See `stdout`.
    pub stderr: PathBuf,
}

/// Replaces the case-folder placeholder in `s`.
pub(crate) fn resolve(s: &str, dir: &Path) -> String {
    s.replace(CASE_DIR, &dir.to_string_lossy())
}

/// Makes one setup entry in the case folder.
fn make(setup: &Setup, dir: &Path) -> Result<(), String> {
    let at = |rel: &str| dir.join(resolve(rel, dir));
    let err = |what: &str, p: &Path, e: std::io::Error| format!("setup: {what} {}: {e}", p.display());
    let parent = |p: &Path| -> Result<(), String> {
        match p.parent() {
            Some(parent) => std::fs::create_dir_all(parent).map_err(|e| err("create", parent, e)),
            None => Ok(()),
        }
    };
    match setup {
        Setup::Write(rel, bytes) => {
            let p = at(rel);
            parent(&p)?;
            std::fs::write(&p, bytes).map_err(|e| err("write", &p, e))
        }
        Setup::Copy(from, rel) => {
            let p = at(rel);
            parent(&p)?;
            copy_recursive(from, &p)
        }
        Setup::Dir(rel) => {
            let p = at(rel);
            std::fs::create_dir_all(&p).map_err(|e| err("create", &p, e))
        }
        Setup::Fifo(rel) => {
            let p = at(rel);
            parent(&p)?;
            let status = Command::new("mkfifo").arg(&p).status().map_err(|e| err("mkfifo", &p, e))?;
            if status.success() { Ok(()) } else { Err(format!("setup: mkfifo {} failed", p.display())) }
        }
        Setup::Symlink(target, rel) => {
            let p = at(rel);
            parent(&p)?;
            std::os::unix::fs::symlink(target, &p).map_err(|e| err("symlink", &p, e))
        }
    }
}

/// Copies a file, or a folder with everything in it (symbolic links copied as links).
pub(crate) fn copy_recursive(from: &Path, to: &Path) -> Result<(), String> {
    let meta = std::fs::symlink_metadata(from).map_err(|e| format!("copy {}: {e}", from.display()))?;
    if meta.is_dir() {
        std::fs::create_dir_all(to).map_err(|e| format!("create {}: {e}", to.display()))?;
        let entries = std::fs::read_dir(from).map_err(|e| format!("read {}: {e}", from.display()))?;
        for entry in entries {
            let entry = entry.map_err(|e| format!("read {}: {e}", from.display()))?;
            copy_recursive(&entry.path(), &to.join(entry.file_name()))?;
        }
        Ok(())
    } else if meta.file_type().is_symlink() {
        let target = std::fs::read_link(from).map_err(|e| format!("read link {}: {e}", from.display()))?;
        std::os::unix::fs::symlink(target, to).map_err(|e| format!("link {}: {e}", to.display()))
    } else {
        std::fs::copy(from, to).map(|_| ()).map_err(|e| format!("copy {} to {}: {e}", from.display(), to.display()))
    }
}

/// Size and FNV-1a hash of every regular file under `dir` (symbolic links and special files
/// are not followed or read).
pub(crate) fn fingerprint(dir: &Path) -> BTreeMap<PathBuf, (u64, String)> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for entry in entries.flatten() {
            let p = entry.path();
            let Ok(meta) = std::fs::symlink_metadata(&p) else { continue };
            if meta.is_dir() {
                stack.push(p);
            } else if meta.is_file() {
                let hash = std::fs::read(&p).map(|b| wonder3d::core::io::fnv1a64(&b)).unwrap_or_default();
                out.insert(p, (meta.len(), hash));
            }
        }
    }
    out
}

/// The files of `before` that are missing or different in `after`.
pub(crate) fn changed(
    before: &BTreeMap<PathBuf, (u64, String)>,
    after: &BTreeMap<PathBuf, (u64, String)>,
) -> Vec<PathBuf> {
    before.iter().filter(|(p, v)| after.get(*p) != Some(v)).map(|(p, _)| p.clone()).collect()
}

/// Runs `case` (number `index` of the table) with the binary `bin` in `place`.
pub(crate) fn run(case: &Case, index: usize, bin: &Path, place: &Place) -> Outcome {
    let dir = &place.dir;
    let args: Vec<String> = case.args.iter().map(|a| resolve(a, dir)).collect();
    let mut outcome = Outcome {
        index,
        name: case.name.clone(),
        command: case.command,
        args: args.clone(),
        class: Class::Ok,
        reason: String::new(),
        code: None,
        signal: None,
        seconds: 0.0,
        peak_kib: 0,
        first_line: String::new(),
    };
    let fail_setup = |mut o: Outcome, e: String| {
        o.class = Class::ErrorOnGoodInput;
        o.reason = format!("the campaign could not set the case up: {e}");
        o
    };
    if let Err(e) = std::fs::create_dir_all(dir).map_err(|e| e.to_string()) {
        return fail_setup(outcome, e);
    }
    for s in &case.setup {
        if let Err(e) = make(s, dir) {
            return fail_setup(outcome, e);
        }
    }
    let before = if case.preserve { fingerprint(dir) } else { BTreeMap::new() };
    let files = std::fs::File::create(&place.stdout).and_then(|o| Ok((o, std::fs::File::create(&place.stderr)?)));
    let (out, err) = match files {
        Ok(f) => f,
        Err(e) => return fail_setup(outcome, format!("log files: {e}")),
    };
    // The shell sets the limit and execs the binary (same process: exit status and signals
    // are the binary's own).
    let mut cmd = Command::new("sh");
    cmd.arg("-c").arg(format!("ulimit -v {MEMORY_LIMIT_KIB} && exec \"$0\" \"$@\"")).arg(bin);
    cmd.args(&args).current_dir(dir).stdin(Stdio::null()).stdout(out).stderr(err);
    for v in SHARD_VARIABLES {
        cmd.env_remove(v);
    }
    let start = Instant::now();
    let mut child = match cmd.spawn() {
        Ok(c) => c,
        Err(e) => return fail_setup(outcome, format!("cannot start {}: {e}", bin.display())),
    };
    let mut timed_out = false;
    let status_file = PathBuf::from(format!("/proc/{}/status", child.id()));
    let status = loop {
        outcome.peak_kib = outcome.peak_kib.max(resident_peak(&status_file));
        match child.try_wait() {
            Ok(Some(status)) => break Some(status),
            Ok(None) if start.elapsed() >= case.timeout => {
                timed_out = true;
                let _ = child.kill();
                break child.wait().ok();
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(_) => break None,
        }
    };
    outcome.seconds = start.elapsed().as_secs_f64();
    outcome.code = status.and_then(|s| s.code());
    outcome.signal = status.and_then(|s| s.signal());
    let stderr = String::from_utf8_lossy(&std::fs::read(&place.stderr).unwrap_or_default()).into_owned();
    let message = error_message(&stderr);
    outcome.first_line = first_error_line(&stderr);
    let changed = if case.preserve { changed(&before, &fingerprint(dir)) } else { Vec::new() };
    let run = Run { timed_out, code: outcome.code, signal: outcome.signal, peak_kib: outcome.peak_kib };
    let (class, reason) = classify(case, &run, &stderr, message, &changed, dir);
    outcome.class = class;
    outcome.reason = reason;
    outcome
}

/// The peak resident memory (`VmHWM`, KiB) in a `/proc/PID/status` file; 0 when unreadable.
fn resident_peak(status: &Path) -> u64 {
    std::fs::read_to_string(status)
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(0)
}

/// How a run ended.
pub(crate) struct Run {
    /// Killed at the case's limit.
    pub timed_out: bool,
    /// Exit code.
    pub code: Option<i32>,
    /// Ending signal.
    pub signal: Option<i32>,
    /// Peak resident memory seen (KiB).
    pub peak_kib: u64,
}

/// The part of stderr that holds the error: from the first line starting with `error` (the
/// CLI's and clap's prefix) or `failed:` (a batch item) to the end; all of it when there is
/// none (notes and warnings before the error, such as a model config's notice that names
/// the weights folder, do not count as naming anything).
pub(crate) fn error_message(stderr: &str) -> &str {
    let mut at = 0;
    for line in stderr.split_inclusive('\n') {
        let l = line.trim_start().to_ascii_lowercase();
        if l.starts_with("error") || l.starts_with("failed:") {
            return &stderr[at..];
        }
        at += line.len();
    }
    stderr
}

/// The first line of the error message (trimmed, at most 300 characters).
pub(crate) fn first_error_line(stderr: &str) -> String {
    let line = error_message(stderr).lines().map(str::trim).find(|l| !l.is_empty()).unwrap_or("");
    let mut s: String = line.chars().take(300).collect();
    if s.len() < line.len() {
        s.push('…');
    }
    s
}

/// The class of a run and why.
pub(crate) fn classify(
    case: &Case,
    run: &Run,
    stderr: &str,
    message: &str,
    changed: &[PathBuf],
    dir: &Path,
) -> (Class, String) {
    let (code, signal) = (run.code, run.signal);
    if run.timed_out {
        return (Class::Timeout, format!("still running after {} s", case.timeout.as_secs()));
    }
    if stderr.contains("panicked at") || code == Some(101) {
        return (Class::Panic, format!("exit code {code:?}; a panic message on stderr"));
    }
    if let Some(sig) = signal {
        return (Class::Signal, format!("killed by signal {sig}"));
    }
    let out_of_memory = ["out of memory", "memory allocation of", "capacity overflow", "Cannot allocate memory"]
        .iter()
        .any(|m| stderr.contains(m));
    if out_of_memory || run.peak_kib >= MEMORY_FINDING_KIB {
        return (
            Class::Memory,
            format!(
                "{} MiB resident at peak{} (limit {} MiB of address space)",
                run.peak_kib >> 10,
                if out_of_memory { ", allocation refused" } else { "" },
                MEMORY_LIMIT_KIB >> 10
            ),
        );
    }
    if !changed.is_empty() {
        let names: Vec<String> =
            changed.iter().map(|p| p.strip_prefix(dir).unwrap_or(p).display().to_string()).collect();
        return (Class::InputChanged, format!("changed or removed: {}", names.join(", ")));
    }
    let success = code == Some(0);
    let check = |tokens: &[String]| -> (Class, String) {
        let tokens: Vec<String> = tokens.iter().map(|t| resolve(t, dir)).collect();
        let message = case.mask.iter().fold(message.to_string(), |m, p| m.replace(&resolve(p, dir), "…"));
        if let Some(m) = MISREADINGS.iter().find(|m| message.contains(*m)) {
            return (Class::ErrorNamingNothing, format!("the command line was misread ({m:?})"));
        }
        if let Some(m) = case.forbid.iter().find(|m| message.contains(m.as_str())) {
            return (Class::ErrorNamingNothing, format!("it points at something else ({m:?})"));
        }
        if tokens.iter().any(|t| message.contains(t.as_str())) {
            (Class::Ok, String::new())
        } else {
            (Class::ErrorNamingNothing, format!("names none of {tokens:?}"))
        }
    };
    match &case.expect {
        Expect::Success if success => (Class::Ok, String::new()),
        Expect::Success => (Class::ErrorOnGoodInput, format!("exit code {code:?} on a valid input")),
        Expect::Error(_) if success => (Class::SuccessOnBadInput, "exit code 0".into()),
        Expect::Error(tokens) => check(tokens),
        Expect::Either(_) if success => (Class::Ok, String::new()),
        Expect::Either(tokens) => check(tokens),
    }
}
