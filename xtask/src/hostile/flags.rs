//! Every numeric flag of every subcommand with values outside its range: negative, zero,
//! absurd (10¹², 2³²), non-finite, malformed and empty. Each is refused by the parser with the
//! flag named; the rest of the command line is valid and cheap, so a value that slips
//! through shows up as a success on bad input, a timeout or an abort.

use super::case::Case;
use super::ctx::{Ctx, with_flag};

/// What a flag accepts (the ranges of the CLI's help and parsers).
#[derive(Clone, Copy, Debug)]
enum Kind {
    /// A whole number in `lo..=hi`.
    Whole(i128, i128),
    /// A finite number in the range; `open_lo` / `open_hi` exclude the bound.
    Real { lo: f64, hi: f64, open_lo: bool, open_hi: bool },
    /// A seed: 0 to 2⁶⁴ − 1.
    Seed,
    /// `batch --shard I/N`.
    Shard,
    /// `refine --simplify`: 0 to 0.1 or `off`.
    Simplify,
    /// `train --min-snr-gamma`: (0, 1000] or `none`.
    Gamma,
    /// `--guidance-interval LO,HI`: two noise levels, 0 ≤ LO ≤ HI ≤ 1.
    Interval,
    /// `--products`: `f32` or `bf16`.
    Products,
}

/// A closed real range.
const fn real(lo: f64, hi: f64) -> Kind {
    Kind::Real { lo, hi, open_lo: false, open_hi: false }
}

/// The accelerations of `generate`, `run`, `batch`, `demo` and `refine`.
const ACCELERATION: [(&str, Kind); 5] = [
    ("--guidance-interval", Kind::Interval),
    ("--cache-interval", Kind::Whole(1, 50)),
    ("--cache-depth", Kind::Whole(0, 63)),
    ("--products", Kind::Products),
    ("--token-merge", real(0.0, 0.9)),
];

/// The sampling flags of `generate`, `run`, `batch` and `demo`.
const SAMPLING: [(&str, Kind); 11] = [
    ("--steps", Kind::Whole(1, 1000)),
    ("--guidance", real(0.0, 100.0)),
    ("--eta", real(0.0, 1.0)),
    ("--seed", Kind::Seed),
    ("--draws", Kind::Whole(1, 64)),
    ("--min-confidence", real(0.0, 1.0)),
    ACCELERATION[0],
    ACCELERATION[1],
    ACCELERATION[2],
    ACCELERATION[3],
    ACCELERATION[4],
];

/// Every subcommand's numeric flags.
fn flags() -> Vec<(&'static str, Vec<(&'static str, Kind)>)> {
    let texture = ("--texture-size", Kind::Whole(8, 8192));
    let starts = ("--starts", Kind::Whole(1, 64));
    let refine = [("--refine", Kind::Whole(0, 10)), ("--refine-size", Kind::Whole(1, 4096))];
    vec![
        ("render", vec![("--size", Kind::Whole(1, 4096))]),
        ("eval", vec![("--samples", Kind::Whole(1, 10_000_000)), ("--seed", Kind::Seed)]),
        ("reconstruct", [&[starts, texture][..], &refine[..]].concat()),
        (
            "texture",
            vec![
                ("--size", Kind::Whole(8, 8192)),
                ("--padding", Kind::Whole(0, 1024)),
                ("--dilation", Kind::Whole(0, 1024)),
                ("--exponent", real(0.0, 64.0)),
            ],
        ),
        (
            "refine",
            [
                &[
                    ("--iterations", Kind::Whole(0, 10)),
                    ("--size", Kind::Whole(1, 4096)),
                    texture,
                    ("--simplify", Kind::Simplify),
                ][..],
                &ACCELERATION[..],
            ]
            .concat(),
        ),
        ("demo", [&[("--size", Kind::Whole(1, 4096)), texture, starts][..], &SAMPLING[..]].concat()),
        ("prepare", vec![("--size", Kind::Whole(16, 8192)), ("--min-confidence", real(0.0, 1.0))]),
        ("generate", SAMPLING.to_vec()),
        ("run", [&[starts, texture][..], &refine[..], &SAMPLING[..]].concat()),
        (
            "batch",
            [
                &[
                    ("--shard", Kind::Shard),
                    ("--jobs", Kind::Whole(1, 256)),
                    ("--timeout", Kind::Real { lo: 0.0, hi: 1e7, open_lo: true, open_hi: false }),
                    texture,
                    starts,
                ][..],
                &SAMPLING[..],
            ]
            .concat(),
        ),
        (
            "dataset",
            vec![("--samples", Kind::Whole(1, 10_000)), ("--size", Kind::Whole(16, 2048)), ("--seed", Kind::Seed)],
        ),
        (
            "train",
            vec![
                ("--stage", Kind::Whole(1, 3)),
                ("--steps", Kind::Whole(1, 10_000_000)),
                ("--lr", Kind::Real { lo: 0.0, hi: 1.0, open_lo: true, open_hi: false }),
                ("--warmup", Kind::Whole(0, 10_000_000)),
                ("--objects-per-batch", Kind::Whole(1, 1024)),
                ("--accumulate", Kind::Whole(1, 1024)),
                ("--checkpoint-every", Kind::Whole(1, 10_000_000)),
                ("--seed", Kind::Seed),
                ("--ema-decay", Kind::Real { lo: 0.0, hi: 1.0, open_lo: false, open_hi: true }),
                ("--min-snr-gamma", Kind::Gamma),
            ],
        ),
    ]
}

/// Values outside what `kind` accepts; the first is the one of the `--quick` subset (for every
/// other flag).
fn bad_values(kind: Kind) -> Vec<String> {
    let mut v: Vec<String> = match kind {
        Kind::Whole(lo, hi) => {
            let mut v = vec!["-1".to_string()];
            if lo > 0 {
                v.push("0".into());
            }
            v.push((hi + 1).to_string());
            if hi + 1 < 4_294_967_296 {
                v.push("4294967296".into());
            }
            v.extend(["1e12", "2.5", "nan"].map(String::from));
            v
        }
        Kind::Real { lo, hi, open_lo, open_hi } => {
            let mut v = vec!["-1".to_string(), "-0.5".into()];
            if open_lo {
                v.push(lo.to_string());
            }
            if open_hi {
                v.push(hi.to_string());
            }
            v.extend(["nan", "inf", "-inf", "1e12", "1e309"].map(String::from));
            v
        }
        Kind::Seed => ["-1", "18446744073709551616", "1e12", "nan"].map(String::from).to_vec(),
        Kind::Shard => {
            ["-1/2", "2/2", "0/0", "1/-2", "a/b", "1/2/3", "18446744073709551616/2", "1"].map(String::from).to_vec()
        }
        Kind::Simplify => ["-1", "0.2", "nan", "inf", "OFF"].map(String::from).to_vec(),
        Kind::Gamma => ["-1", "0", "1001", "nan", "inf", "None"].map(String::from).to_vec(),
        Kind::Interval => {
            ["0.5", "1.2,0.3", "0.7,0.1", "-1,0", "0,1.5", "nan,1", "0,inf", "1e309,1", "0.1,0.5,0.7", ",", "0.1,"]
                .map(String::from)
                .to_vec()
        }
        Kind::Products => ["fp8", "F32", "bf16 ", "AUTO"].map(String::from).to_vec(),
    };
    v.extend(["abc", ""].map(String::from));
    v
}

/// The cases: every (subcommand, numeric flag, bad value), expecting an error naming the flag.
pub(crate) fn cases(ctx: &Ctx, out: &mut Vec<Case>) {
    for (command, flags) in flags() {
        let base = ctx.base(command);
        for (f, (flag, kind)) in flags.into_iter().enumerate() {
            for (i, value) in bad_values(kind).into_iter().enumerate() {
                let args = with_flag(&base, flag, &value);
                let shown = if value.is_empty() { "(empty)".to_string() } else { value.clone() };
                let case = Case::new(command, &format!("{flag}={shown}"), args, &[flag]).quick_if(i == 0 && f % 2 == 0);
                // A value that slips through does the command's real work: give it room.
                out.push(if matches!(command, "run" | "demo" | "refine") { case.timeout(60) } else { case });
            }
        }
    }
}
