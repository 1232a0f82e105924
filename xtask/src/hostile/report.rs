//! The campaign's report: counts per subcommand and class, and every case that is not `ok`
//! with its command line and the first line of its error (`report.md`, `report.json`).

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde_json::{Value, json};

use super::case::{COMMANDS, Class, Outcome};

/// What the report says about the run besides the outcomes.
pub(crate) struct Summary<'a> {
    /// The binary that ran.
    pub binary: String,
    /// `--quick`.
    pub quick: bool,
    /// `--filter`.
    pub filter: Option<&'a str>,
    /// Cases at once.
    pub jobs: usize,
    /// Wall time of the whole run (seeds included), seconds.
    pub seconds: f64,
    /// Bind-mount cases left out (the machine allows no mounts).
    pub mounts_left_out: usize,
    /// Shared inputs some case changed (should be none).
    pub inputs_changed: Vec<String>,
}

/// Shortens absolute paths under `root` (the workspace) in an argument.
fn short(arg: &str, root: &str) -> String {
    arg.replace(root, "")
}

/// A command line as a shell would take it (single quotes where needed).
pub(crate) fn shell(args: &[String], root: &str) -> String {
    let quote = |a: &str| {
        let a = short(a, root);
        if !a.is_empty() && a.chars().all(|c| c.is_ascii_alphanumeric() || "-_./=:,@%+".contains(c)) {
            a
        } else {
            format!("'{}'", a.replace('\'', "'\\''"))
        }
    };
    std::iter::once("wonder3d".to_string()).chain(args.iter().map(|a| quote(a))).collect::<Vec<_>>().join(" ")
}

/// Counts per subcommand and class.
pub(crate) fn counts(outcomes: &[Outcome]) -> BTreeMap<&'static str, BTreeMap<Class, usize>> {
    let mut by: BTreeMap<&'static str, BTreeMap<Class, usize>> = BTreeMap::new();
    for o in outcomes {
        *by.entry(o.command).or_default().entry(o.class).or_default() += 1;
    }
    by
}

/// The markdown report. `root` is the workspace path with a trailing slash (stripped from
/// paths).
pub(crate) fn markdown(summary: &Summary, outcomes: &[Outcome], root: &str) -> String {
    let mut md = String::new();
    let by = counts(outcomes);
    let total = |c: Class| outcomes.iter().filter(|o| o.class == c).count();
    let _ = writeln!(md, "# Hostile-input campaign (`cargo xtask hostile`)\n");
    let _ = writeln!(
        md,
        "{} cases{}{} against `{}`, {} at once, {:.0} s wall time (seeds included){}.\n",
        outcomes.len(),
        if summary.quick { " (the `--quick` subset)" } else { "" },
        summary.filter.map(|f| format!(" (filter `{f}`)")).unwrap_or_default(),
        short(&summary.binary, root),
        summary.jobs,
        summary.seconds,
        if summary.mounts_left_out > 0 {
            format!("; {} bind-mount cases left out (no mounts on this machine)", summary.mounts_left_out)
        } else {
            String::new()
        },
    );
    let _ = write!(md, "| subcommand | cases |");
    for c in Class::ALL {
        let _ = write!(md, " {} |", c.name());
    }
    let _ = write!(md, "\n|---|---:|");
    for _ in Class::ALL {
        let _ = write!(md, "---:|");
    }
    md.push('\n');
    for command in COMMANDS {
        let Some(row) = by.get(command) else { continue };
        let _ = write!(md, "| {command} | {} |", row.values().sum::<usize>());
        for c in Class::ALL {
            let _ = write!(md, " {} |", row.get(&c).copied().unwrap_or(0));
        }
        md.push('\n');
    }
    let _ = write!(md, "| **all** | **{}** |", outcomes.len());
    for c in Class::ALL {
        let _ = write!(md, " **{}** |", total(c));
    }
    md.push_str("\n\n");
    if !summary.inputs_changed.is_empty() {
        let _ = writeln!(md, "**Shared inputs changed by some case:** {}\n", summary.inputs_changed.join(", "));
    }
    let bad: Vec<&Outcome> = outcomes.iter().filter(|o| o.class != Class::Ok).collect();
    if bad.is_empty() {
        md.push_str("Every case ended as expected.\n");
        return md;
    }
    let _ = writeln!(md, "## Cases that did not end as expected ({})\n", bad.len());
    for class in Class::ALL {
        let of: Vec<&&Outcome> = bad.iter().filter(|o| o.class == class).collect();
        if of.is_empty() {
            continue;
        }
        let _ = writeln!(md, "### {} ({})\n", class.name(), of.len());
        for o in of {
            let status = match (o.code, o.signal) {
                (Some(c), _) => format!("exit code {c}"),
                (None, Some(s)) => format!("signal {s}"),
                _ => "killed".to_string(),
            };
            let _ = writeln!(md, "- `{}` ({status}, {:.2} s): {}", o.name, o.seconds, o.reason);
            let _ = writeln!(md, "  - `{}`", shell(&o.args, root).replace('`', "\\`"));
            if !o.first_line.is_empty() {
                let _ = writeln!(md, "  - stderr: `{}`", short(&o.first_line, root).replace('`', "'"));
            }
        }
        md.push('\n');
    }
    md
}

/// The JSON report.
pub(crate) fn json(summary: &Summary, outcomes: &[Outcome], root: &str) -> Value {
    let by = counts(outcomes);
    let mut counts = serde_json::Map::new();
    for c in Class::ALL {
        counts.insert(c.name().into(), outcomes.iter().filter(|o| o.class == c).count().into());
    }
    let by_command: serde_json::Map<String, Value> = by
        .iter()
        .map(|(cmd, row)| {
            let row: serde_json::Map<String, Value> =
                row.iter().map(|(c, n)| (c.name().to_string(), (*n).into())).collect();
            (cmd.to_string(), Value::Object(row))
        })
        .collect();
    json!({
        "binary": summary.binary,
        "quick": summary.quick,
        "filter": summary.filter,
        "jobs": summary.jobs,
        "seconds": summary.seconds,
        "mounts_left_out": summary.mounts_left_out,
        "inputs_changed": summary.inputs_changed,
        "cases": outcomes.len(),
        "counts": counts,
        "by_command": by_command,
        "outcomes": outcomes.iter().map(|o| json!({
            "index": o.index,
            "name": o.name,
            "command": o.command,
            "argv": shell(&o.args, root),
            "class": o.class.name(),
            "reason": o.reason,
            "code": o.code,
            "signal": o.signal,
            "seconds": (o.seconds * 1000.0).round() / 1000.0,
            "peak_mib": o.peak_kib >> 10,
            "first_line": short(&o.first_line, root),
        })).collect::<Vec<_>>(),
    })
}
