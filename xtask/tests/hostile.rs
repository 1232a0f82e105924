//! `cargo xtask hostile`: the campaign's table covers every subcommand with at least 300 cases
//! and a quick subset of 60 to 100, and a filtered run against the built `wonder3d` writes its
//! report with the case classified.

use std::path::Path;
use std::process::Command;

/// Runs the xtask binary.
fn xtask(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().expect("the xtask binary runs")
}

/// The subcommands of `wonder3d` the campaign must drive.
const COMMANDS: [&str; 13] = [
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

/// `--list` prints every case and, per subcommand, `NAME COUNT (QUICK)`; it needs no binary.
#[test]
fn the_table_covers_every_subcommand() {
    let out = xtask(&["hostile", "--list"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let counts = text.split("cases per subcommand").nth(1).expect("the counts follow the cases");
    let count = |name: &str| -> (usize, usize) {
        let line =
            counts.lines().find(|l| l.split_whitespace().next() == Some(name)).unwrap_or_else(|| panic!("{name}"));
        let fields: Vec<&str> = line.split_whitespace().collect();
        (fields[1].parse().unwrap(), fields[2].trim_matches(|c| c == '(' || c == ')').parse().unwrap())
    };
    for command in COMMANDS {
        let (all, quick) = count(command);
        assert!(all >= 10 && quick >= 1, "{command}: {all} cases, {quick} quick");
    }
    let (all, quick) = count("all");
    assert!(all >= 300, "{all} cases");
    assert!((60..=100).contains(&quick), "{quick} quick cases");
    // Case names are unique and start with their subcommand.
    let names: Vec<&str> =
        text.lines().filter_map(|l| l.split_whitespace().nth(1)).filter(|n| n.contains('/')).collect();
    let unique: std::collections::BTreeSet<&&str> = names.iter().collect();
    assert_eq!(unique.len(), names.len());
    assert!(names.iter().all(|n| COMMANDS.iter().any(|c| n.starts_with(&format!("{c}/")))));
}

/// One valid case and one hostile case, run against the `wonder3d` built beside xtask (skipped
/// when it is not: `cargo test -p xtask` alone does not build it).
#[test]
fn a_filtered_run_classifies_and_reports() {
    let bin = Path::new(env!("CARGO_BIN_EXE_xtask")).with_file_name("wonder3d");
    if !bin.is_file() {
        eprintln!("skipped: no {} (build wonder3d-cli)", bin.display());
        return;
    }
    let dir = std::env::temp_dir().join(format!("xtask-hostile-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = |filter: &str| {
        xtask(&["hostile", "--filter", filter, "--bin", bin.to_str().unwrap(), "--dir", dir.to_str().unwrap()])
    };
    let out = run("info/");
    let err = String::from_utf8_lossy(&out.stderr);
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert!(report["cases"].as_u64().unwrap() >= 10, "{report}");
    let outcomes = report["outcomes"].as_array().unwrap();
    let valid = outcomes.iter().find(|o| o["name"] == "info/valid-base").expect("info/valid-base ran");
    assert_eq!(valid["class"], "ok", "{valid}");
    let empty = outcomes.iter().find(|o| o["name"] == "info/obj-empty-obj").expect("info/obj-empty-obj ran");
    assert_eq!(empty["class"], "ok", "{empty}");
    assert!(empty["first_line"].as_str().unwrap().contains("obj-empty.obj"), "{empty}");
    // The exit code says whether every case was ok; the markdown report has the table.
    let all_ok = outcomes.iter().all(|o| o["class"] == "ok");
    assert_eq!(out.status.success(), all_ok, "{err}");
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(md.contains("| info |"), "{md}");
    // A second run empties the work folder it made; a foreign folder is refused.
    let again = run("info/valid-base");
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["cases"], 1, "{report}");
    let foreign = dir.with_extension("foreign");
    std::fs::create_dir_all(&foreign).unwrap();
    std::fs::write(foreign.join("mine.txt"), "mine").unwrap();
    let refused = xtask(&[
        "hostile",
        "--filter",
        "info/valid-base",
        "--bin",
        bin.to_str().unwrap(),
        "--dir",
        foreign.to_str().unwrap(),
    ]);
    assert!(!refused.status.success() && String::from_utf8_lossy(&refused.stderr).contains("refusing to empty"));
    assert_eq!(std::fs::read_to_string(foreign.join("mine.txt")).unwrap(), "mine");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&foreign);
}

/// Every subcommand `wonder3d --help` lists is in the campaign: a new command (a server, a
/// Python entry point's CLI twin) fails this test until it joins (skipped when the binary was
/// not built beside xtask).
#[test]
fn every_cli_subcommand_is_in_the_campaign() {
    let bin = Path::new(env!("CARGO_BIN_EXE_xtask")).with_file_name("wonder3d");
    if !bin.is_file() {
        eprintln!("skipped: no {} (build wonder3d-cli)", bin.display());
        return;
    }
    let help = Command::new(&bin).arg("--help").output().expect("wonder3d runs");
    let text = String::from_utf8_lossy(&help.stdout);
    let listed: Vec<&str> = text
        .split("Commands:")
        .nth(1)
        .and_then(|rest| rest.split("Options:").next())
        .expect("a Commands: section")
        .lines()
        .filter_map(|line| line.split_whitespace().next())
        .filter(|name| *name != "help")
        .collect();
    assert!(listed.len() >= 13, "{listed:?}");
    for name in &listed {
        assert!(
            COMMANDS.contains(name),
            "`wonder3d {name}` is not in the hostile campaign (xtask/src/hostile/case.rs)"
        );
    }
}
