//! `wonder3d eval PRED GT`: geometry metrics of a prediction against a ground truth.

use std::path::PathBuf;

use w3d_core::{Result, load_mesh};
use w3d_eval::{EvalOptions, evaluate};

/// Arguments of `wonder3d eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// Predicted mesh, in the canonical unit-cube frame (as `wonder3d reconstruct` writes it).
    pred: PathBuf,
    /// Ground-truth mesh (normalised into the unit cube before comparing).
    gt: PathBuf,
    /// Print one JSON object with stable keys instead of text.
    #[arg(long)]
    json: bool,
    /// Normalise the prediction into the unit cube too (for results of unknown scale).
    #[arg(long)]
    normalize_pred: bool,
    /// Surface samples per mesh.
    #[arg(long, default_value_t = EvalOptions::default().samples)]
    samples: usize,
    /// Sampling seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

/// Runs `wonder3d eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    let pred = load_mesh(&args.pred)?;
    let gt = load_mesh(&args.gt)?;
    let options = EvalOptions { samples: args.samples, seed: args.seed, normalize_pred: args.normalize_pred };
    let metrics = evaluate(&pred, &gt, &options)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&metrics).expect("plain data serialises"));
        return Ok(());
    }
    println!("{} vs {} ({} samples, seed {})", args.pred.display(), args.gt.display(), metrics.samples, metrics.seed);
    println!(
        "  chamfer             {:.6} (pred→gt {:.6}, gt→pred {:.6})",
        metrics.chamfer, metrics.chamfer_pred_to_gt, metrics.chamfer_gt_to_pred
    );
    println!(
        "  F-score @0.01       {:.4} (precision {:.4}, recall {:.4})",
        metrics.fscore_001, metrics.precision_001, metrics.recall_001
    );
    println!(
        "  F-score @0.02       {:.4} (precision {:.4}, recall {:.4})",
        metrics.fscore_002, metrics.precision_002, metrics.recall_002
    );
    println!("  volume IoU 64³      {:.4}", metrics.iou_64);
    println!("  volume IoU 128³     {:.4}", metrics.iou_128);
    println!("  normal consistency  {:.4}", metrics.normal_consistency);
    Ok(())
}
