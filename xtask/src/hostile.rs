//! `cargo xtask hostile`: the hostile-input campaign against every `wonder3d` subcommand
//! (issue #63, item 4; the policy is `docs/robustness.md`).
//!
//! The cases are a table built by generators: every numeric flag with values outside its range
//! (`flags`), damaged files of every format the CLI reads (`files`: meshes and images),
//! damaged folders (`folders`: view sets, `cameras.json`, model directories, training sets,
//! batch manifests), every path argument given a missing path, the wrong kind of file,
//! `/dev/zero` or a FIFO, aliased and unwritable outputs, and hostile-looking inputs that are
//! valid (`paths`). Each case runs the binary in its own folder with a time limit and is
//! classified (`case::Class`): panic, signal, timeout, success on bad input, an error that
//! names none of the case's tokens (the offending path, flag or field), a changed input, an
//! error on a valid input, or ok. The run writes `report.md` and `report.json` into the work
//! folder and fails when any case is not ok.
//!
//! Inputs are made fresh in `target/hostile/inputs` (the work folder is emptied first): small
//! seeds (a cube in every mesh format, 32² oracle views, the tiny checkpoint, a one-sample
//! training set, RGBA and photo images) and their damaged copies. Where the machine allows
//! bind mounts (root), a read-only mount and writable mount points are made for the output
//! cases and removed at the end.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use crate::workspace::{target_dir, workspace_root};

// Cases, their runs and classes; the inputs they start from.
mod case;
mod inputs;

// What the generators share.
mod ctx;

// The generators.
mod files;
mod flags;
mod folders;
mod paths;

// The report.
mod report;

use case::{Case, Class, Outcome, Place};
use ctx::{Ctx, MOUNT_POINTS, Mounts, s};
use inputs::Seeds;

/// `cargo xtask hostile` options.
#[derive(clap::Args, Debug)]
pub(crate) struct Options {
    /// Only the quick subset (76 cases covering every subcommand, about 6 s on 2 cores; CI
    /// runs it).
    #[arg(long)]
    quick: bool,
    /// Only the cases whose name (`subcommand/what`) contains this.
    #[arg(long)]
    filter: Option<String>,
    /// Cases run at once.
    #[arg(long, default_value_t = 2)]
    jobs: usize,
    /// Print the table (names and command lines) and the counts without running anything.
    #[arg(long)]
    list: bool,
    /// The `wonder3d` binary (default: the one beside this xtask binary, refused when older
    /// than the sources; build it with `cargo build --release -p wonder3d-cli -p xtask`).
    #[arg(long)]
    bin: Option<PathBuf>,
    /// Work folder, emptied first (default: `target/hostile`).
    #[arg(long)]
    dir: Option<PathBuf>,
}

/// A marker file in the work folder: a folder without it is never emptied (unless empty).
const MARKER: &str = ".hostile-work-folder";

/// Builds the whole table over `ctx`.
fn table(ctx: &Ctx) -> Vec<Case> {
    let mut t = Vec::new();
    paths::valid_cases(ctx, &mut t);
    flags::cases(ctx, &mut t);
    files::mesh_cases(ctx, &mut t);
    files::image_cases(ctx, &mut t);
    folders::view_cases(ctx, &mut t);
    folders::camera_cases(ctx, &mut t);
    folders::weight_cases(ctx, &mut t);
    folders::dataset_cases(ctx, &mut t);
    folders::manifest_cases(ctx, &mut t);
    paths::path_cases(ctx, &mut t);
    paths::unwritable_cases(ctx, &mut t);
    paths::alias_cases(ctx, &mut t);
    t
}

/// Runs the campaign.
pub(crate) fn run(options: &Options) -> Result<(), String> {
    let start = Instant::now();
    let root = workspace_root();
    let work = options.dir.clone().unwrap_or_else(|| target_dir().join("hostile"));
    let work = if work.is_absolute() { work } else { std::env::current_dir().map_err(|e| e.to_string())?.join(work) };
    let seeds = Seeds::at(&work.join("inputs"));
    let mount_paths = Mounts { readonly: work.join("mnt/readonly"), points: work.join("mnt/points") };
    if options.list {
        let ctx = Ctx::new(seeds, Some(mount_paths), false);
        let cases = select(table(&ctx), options)?;
        let root_s = format!("{}/", root.display());
        for (i, c) in &cases {
            println!("{i:4} {}{}  {}", c.name, if c.quick { " [quick]" } else { "" }, report::shell(&c.args, &root_s));
        }
        print_counts(&cases);
        return Ok(());
    }
    let bin = binary(options.bin.as_deref(), &root)?;
    prepare_work_folder(&work)?;
    // A copy runs every case: a rebuild during the campaign cannot mix two binaries.
    let built = bin;
    let bin = work.join("wonder3d");
    std::fs::copy(&built, &bin).map_err(|e| format!("copying {} to {}: {e}", built.display(), bin.display()))?;
    eprintln!("hostile: seeds in {}", seeds.dir.display());
    seeds.make(&bin, &root)?;
    let ctx = Ctx::new(seeds, Some(mount_paths.clone()), true);
    let all = table(&ctx);
    if let Some(e) = ctx.errors().first() {
        return Err(format!("making the damaged inputs: {e} ({} failures)", ctx.errors().len()));
    }
    let mut cases = select(all, options)?;
    // Bind mounts only when a selected case needs them; without them those cases are left out.
    let mnt = s(&work.join("mnt"));
    let uses_mounts = |c: &Case| c.args.iter().any(|a| a.contains(&mnt));
    let needed = cases.iter().any(|(_, c)| uses_mounts(c));
    let mounts = if needed { MountGuard::make(&mount_paths) } else { MountGuard::none() };
    let left_out = if mounts.made { 0 } else { cases.iter().filter(|(_, c)| uses_mounts(c)).count() };
    cases.retain(|(_, c)| mounts.made || !uses_mounts(c));
    if cases.is_empty() {
        return Err("no case left to run (the selected ones need bind mounts, which this machine refuses)".into());
    }
    let inputs_before = case::fingerprint(&ctx.seeds.dir);
    for d in ["cases", "logs"] {
        std::fs::create_dir_all(work.join(d)).map_err(|e| format!("{}: {e}", work.display()))?;
    }
    let note =
        if left_out > 0 { format!(" ({left_out} bind-mount cases left out: no mounts here)") } else { String::new() };
    eprintln!("hostile: {} cases, {} at once, binary {}{note}", cases.len(), options.jobs.max(1), built.display());
    let outcomes = run_all(&cases, &bin, &work, options.jobs.max(1));
    drop(mounts);
    let inputs_changed: Vec<String> = case::changed(&inputs_before, &case::fingerprint(&ctx.seeds.dir))
        .iter()
        .map(|p| p.strip_prefix(&work).unwrap_or(p).display().to_string())
        .collect();
    let summary = report::Summary {
        binary: format!(
            "{} (FNV-1a {})",
            built.display(),
            std::fs::read(&bin).map(|b| wonder3d::core::io::fnv1a64(&b)).unwrap_or_default()
        ),
        quick: options.quick,
        filter: options.filter.as_deref(),
        jobs: options.jobs.max(1),
        seconds: start.elapsed().as_secs_f64(),
        mounts_left_out: left_out,
        inputs_changed,
    };
    let root_s = format!("{}/", root.display());
    let md = report::markdown(&summary, &outcomes, &root_s);
    let json = report::json(&summary, &outcomes, &root_s);
    let (md_path, json_path) = (work.join("report.md"), work.join("report.json"));
    std::fs::write(&md_path, &md).map_err(|e| format!("{}: {e}", md_path.display()))?;
    let text = serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?;
    std::fs::write(&json_path, text).map_err(|e| format!("{}: {e}", json_path.display()))?;
    let table_end = md.find("\n\n## ").unwrap_or(md.len());
    println!("{}", &md[..table_end]);
    println!("report: {} and {}", md_path.display(), json_path.display());
    let failing = outcomes.iter().filter(|o| o.class != Class::Ok).count();
    if failing > 0 || !summary.inputs_changed.is_empty() {
        return Err(format!(
            "{failing} of {} cases did not end as expected{} (see {})",
            outcomes.len(),
            if summary.inputs_changed.is_empty() { "" } else { "; shared inputs changed" },
            md_path.display()
        ));
    }
    Ok(())
}

/// The table filtered by `--quick` and `--filter`, each case with its index in the whole table.
fn select(all: Vec<Case>, options: &Options) -> Result<Vec<(usize, Case)>, String> {
    let mut names = std::collections::BTreeSet::new();
    for c in &all {
        if !names.insert(c.name.clone()) {
            return Err(format!("two cases are named {}", c.name));
        }
    }
    let cases: Vec<(usize, Case)> = all
        .into_iter()
        .enumerate()
        .filter(|(_, c)| !options.quick || c.quick)
        .filter(|(_, c)| options.filter.as_deref().is_none_or(|f| c.name.contains(f)))
        .collect();
    if cases.is_empty() {
        return Err("no case matches".into());
    }
    Ok(cases)
}

/// Prints the number of cases per subcommand.
fn print_counts(cases: &[(usize, Case)]) {
    let mut by: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
    for (_, c) in cases {
        let e = by.entry(c.command).or_default();
        e.0 += 1;
        e.1 += usize::from(c.quick);
    }
    println!("cases per subcommand (quick in parentheses):");
    for command in case::COMMANDS {
        let (n, q) = by.get(command).copied().unwrap_or_default();
        println!("  {command:12} {n:4} ({q})");
    }
    let quick = cases.iter().filter(|(_, c)| c.quick).count();
    println!("  {:12} {:4} ({quick})", "all", cases.len());
}

/// The `wonder3d` binary: `--bin`, or the one beside this xtask binary (else in
/// `target/release`), which must be newer than every source file of the CLI's crates.
fn binary(bin: Option<&Path>, root: &Path) -> Result<PathBuf, String> {
    if let Some(b) = bin {
        return if b.is_file() { Ok(b.to_path_buf()) } else { Err(format!("--bin {}: no such file", b.display())) };
    }
    let beside = std::env::current_exe().ok().map(|e| e.with_file_name("wonder3d")).filter(|p| p.is_file());
    let bin = beside.unwrap_or_else(|| target_dir().join("release").join("wonder3d"));
    let built = std::fs::metadata(&bin).and_then(|m| m.modified()).map_err(|_| {
        format!("{} is missing: build it with `cargo build --release -p wonder3d-cli -p xtask`", bin.display())
    })?;
    let mut newest: Option<(std::time::SystemTime, PathBuf)> = None;
    let mut stack = vec![root.join("crates")];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            let name = e.file_name();
            if p.is_dir() && name != "tests" && name != "benches" && name != "target" {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs")
                && p.components().any(|c| c.as_os_str() == "src")
                && let Ok(t) = e.metadata().and_then(|m| m.modified())
                && newest.as_ref().is_none_or(|(n, _)| t > *n)
            {
                newest = Some((t, p));
            }
        }
    }
    match newest {
        Some((t, p)) if t > built => Err(format!(
            "{} is older than {}: rebuild it (`cargo build --release -p wonder3d-cli -p xtask`) or pass --bin",
            bin.display(),
            p.display()
        )),
        _ => Ok(bin),
    }
}

/// Empties the work folder (refusing one that is not empty and was not made by this task),
/// unmounting any mount left inside it by an interrupted run first.
fn prepare_work_folder(work: &Path) -> Result<(), String> {
    if work.exists() {
        let empty = std::fs::read_dir(work).map(|mut d| d.next().is_none()).unwrap_or(false);
        if !empty && !work.join(MARKER).exists() {
            return Err(format!("{} is not a hostile work folder (no {MARKER}): refusing to empty it", work.display()));
        }
        for m in mounts_under(work).into_iter().rev() {
            let _ = Command::new("umount").arg(&m).status();
        }
        if !mounts_under(work).is_empty() {
            return Err(format!("{} still holds mounts: unmount them first", work.display()));
        }
        std::fs::remove_dir_all(work).map_err(|e| format!("emptying {}: {e}", work.display()))?;
    }
    std::fs::create_dir_all(work).map_err(|e| format!("{}: {e}", work.display()))?;
    std::fs::write(work.join(MARKER), b"made by cargo xtask hostile; emptied by its next run\n")
        .map_err(|e| format!("{}: {e}", work.display()))
}

/// Mount points under `dir` (from `/proc/self/mountinfo`), in mount order.
fn mounts_under(dir: &Path) -> Vec<PathBuf> {
    let Ok(info) = std::fs::read_to_string("/proc/self/mountinfo") else { return Vec::new() };
    info.lines()
        .filter_map(|l| l.split(' ').nth(4))
        .map(|m| PathBuf::from(m.replace("\\040", " ").replace("\\011", "\t").replace("\\134", "\\")))
        .filter(|m| m.starts_with(dir) && m != dir)
        .collect()
}

/// The campaign's bind mounts, removed when dropped.
struct MountGuard {
    /// Whether every mount was made (else none is left).
    made: bool,
    /// The mount points made, in order.
    points: Vec<PathBuf>,
}

impl MountGuard {
    /// No mounts.
    fn none() -> MountGuard {
        MountGuard { made: false, points: Vec::new() }
    }

    /// Makes the read-only mount and the writable mount points of `m` (each a bind mount of
    /// a folder in `mnt/src`); on any failure (not root, no mount permission) undoes what
    /// was made and reports `made: false`.
    fn make(m: &Mounts) -> MountGuard {
        let mut guard = MountGuard::none();
        let src = m.points.with_file_name("src");
        let mount = |args: &[&std::ffi::OsStr]| {
            Command::new("mount").args(args).stderr(std::process::Stdio::null()).status().is_ok_and(|s| s.success())
        };
        let mut pairs = vec![(src.join("readonly"), m.readonly.clone())];
        pairs.extend(MOUNT_POINTS.iter().map(|n| (src.join(n), m.points.join(n))));
        for (from, to) in &pairs {
            if std::fs::create_dir_all(from).and_then(|()| std::fs::create_dir_all(to)).is_err()
                || !mount(&["--bind".as_ref(), from.as_os_str(), to.as_os_str()])
            {
                return guard;
            }
            guard.points.push(to.clone());
        }
        let ro = ["-o".as_ref(), "remount,ro,bind".as_ref(), m.readonly.as_os_str()];
        guard.made = mount(&ro) && std::fs::write(m.readonly.join("probe"), b"").is_err();
        guard
    }
}

impl Drop for MountGuard {
    fn drop(&mut self) {
        for p in self.points.iter().rev() {
            let _ = Command::new("umount").arg(p).status();
        }
        self.points.clear();
    }
}

/// Runs the cases on `jobs` threads (the longest limits first), printing each case that is
/// not ok as it ends; outcomes in table order.
fn run_all(cases: &[(usize, Case)], bin: &Path, work: &Path, jobs: usize) -> Vec<Outcome> {
    let mut order: Vec<&(usize, Case)> = cases.iter().collect();
    order.sort_by_key(|(i, c)| (std::cmp::Reverse(c.timeout), *i));
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let results = Mutex::new(Vec::with_capacity(cases.len()));
    let n = order.len();
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::SeqCst);
                    let Some((index, case)) = order.get(k) else { break };
                    let place = Place {
                        dir: work.join("cases").join(format!("{index:04}")),
                        stdout: work.join("logs").join(format!("{index:04}.out")),
                        stderr: work.join("logs").join(format!("{index:04}.err")),
                    };
                    let outcome = case::run(case, *index, bin, &place);
                    let d = done.fetch_add(1, Ordering::SeqCst) + 1;
                    if outcome.class != Class::Ok {
                        eprintln!(
                            "[{d}/{n}] {} {} ({:.1} s): {}",
                            outcome.class.name(),
                            outcome.name,
                            outcome.seconds,
                            if outcome.first_line.is_empty() { &outcome.reason } else { &outcome.first_line }
                        );
                    } else if d.is_multiple_of(50) {
                        eprintln!("[{d}/{n}] …");
                    }
                    if let Ok(mut r) = results.lock() {
                        r.push(outcome);
                    }
                }
            });
        }
    });
    let mut outcomes = results.into_inner().unwrap_or_default();
    outcomes.sort_by_key(|o| o.index);
    outcomes
}
