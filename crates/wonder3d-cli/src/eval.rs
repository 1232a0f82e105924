//! `wonder3d eval PRED GT`: geometry metrics of a prediction against a ground truth,
//! optionally with SyncDreamer's visible-surface Chamfer (`--visible`) and an ICP + scale
//! alignment diagnostic (`--icp`: metrics again after aligning the prediction).

use std::path::PathBuf;

use serde_json::{Value, json};
use wonder3d::eval::{
    EvalOptions, IcpOptions, MeshMetrics, Similarity, VisibleOptions, align_icp_scale, evaluate,
    visible_surface_chamfer,
};
use wonder3d::{Mesh, Result};

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
    #[arg(long, default_value_t = EvalOptions::default().samples, allow_hyphen_values = true, value_parser = crate::args::eval_samples)]
    samples: usize,
    /// Sampling seed.
    #[arg(long, default_value_t = 0, allow_hyphen_values = true, value_parser = crate::args::seed)]
    seed: u64,
    /// Also compute SyncDreamer's visible-surface Chamfer (16 depth views at 256², voxel
    /// down-sampling at 0.01); JSON key `visible_chamfer`.
    #[arg(long)]
    visible: bool,
    /// Diagnostic: align the prediction to the ground truth with ICP (rotation, uniform
    /// scale, translation) and report the similarity (`icp_scale`, `icp_rotation_deg`,
    /// `icp_translation`) and every metric again after alignment (JSON key `aligned`).
    #[arg(long)]
    icp: bool,
}

/// The metrics of one prediction, with the visible Chamfer when asked for.
struct Report {
    metrics: MeshMetrics,
    visible_chamfer: Option<f64>,
}

impl Report {
    fn new(pred: &Mesh, gt: &Mesh, options: &EvalOptions, visible: bool) -> Result<Self> {
        let metrics = evaluate(pred, gt, options)?;
        let visible_chamfer =
            if visible { Some(visible_surface_chamfer(pred, gt, &VisibleOptions::default())?.chamfer) } else { None };
        Ok(Report { metrics, visible_chamfer })
    }

    fn to_json(&self) -> Value {
        let mut value = serde_json::to_value(self.metrics).expect("plain data serialises");
        if let (Some(v), Some(map)) = (self.visible_chamfer, value.as_object_mut()) {
            map.insert("visible_chamfer".into(), json!(v));
        }
        value
    }

    fn print(&self) {
        let m = &self.metrics;
        println!(
            "  chamfer             {:.6} (pred→gt {:.6}, gt→pred {:.6})",
            m.chamfer, m.chamfer_pred_to_gt, m.chamfer_gt_to_pred
        );
        if let Some(v) = self.visible_chamfer {
            println!("  visible chamfer     {v:.6}");
        }
        println!(
            "  F-score @0.01       {:.4} (precision {:.4}, recall {:.4})",
            m.fscore_001, m.precision_001, m.recall_001
        );
        println!(
            "  F-score @0.02       {:.4} (precision {:.4}, recall {:.4})",
            m.fscore_002, m.precision_002, m.recall_002
        );
        println!("  volume IoU 64³      {:.4}", m.iou_64);
        println!("  volume IoU 128³     {:.4}", m.iou_128);
        println!("  normal consistency  {:.4}", m.normal_consistency);
    }
}

/// Runs `wonder3d eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    let mut pred = wonder3d::load_mesh_with_surface(&args.pred, "PRED")?;
    let mut gt = wonder3d::load_mesh_with_surface(&args.gt, "GT")?;
    crate::args::orient_outward(&mut pred, &args.pred);
    crate::args::orient_outward(&mut gt, &args.gt);
    // The frames `evaluate` compares in, needed as well by the visible Chamfer and ICP.
    gt.normalize_unit_cube();
    if args.normalize_pred {
        pred.normalize_unit_cube();
    }
    let options = EvalOptions::default().with_samples(args.samples).with_seed(args.seed).with_normalize_pred(false);
    let both = format!("PRED {} against GT {}", args.pred.display(), args.gt.display());
    let report = wonder3d::outputs::for_flag(&both, Report::new(&pred, &gt, &options, args.visible))?;
    let icp: Option<(Similarity, Report)> = if args.icp {
        let similarity = align_icp_scale(&pred, &gt, &IcpOptions::default().with_seed(args.seed))?;
        let aligned = similarity.apply_to_mesh(&pred)?;
        Some((similarity, Report::new(&aligned, &gt, &options, args.visible)?))
    } else {
        None
    };
    if args.json {
        let mut value = report.to_json();
        if let (Some((s, after)), Some(map)) = (&icp, value.as_object_mut()) {
            map.insert("icp_scale".into(), json!(s.scale));
            map.insert("icp_rotation_deg".into(), json!(s.rotation_deg()));
            map.insert("icp_translation".into(), json!(s.translation.to_array()));
            map.insert("aligned".into(), after.to_json());
        }
        println!("{}", serde_json::to_string_pretty(&value).expect("plain data serialises"));
        return Ok(());
    }
    let m = &report.metrics;
    println!("{} vs {} ({} samples, seed {})", args.pred.display(), args.gt.display(), m.samples, m.seed);
    report.print();
    if let Some((s, after)) = &icp {
        let t = s.translation;
        println!(
            "after ICP alignment (scale {:.5}, rotation {:.3}°, translation [{:.5}, {:.5}, {:.5}]):",
            s.scale,
            s.rotation_deg(),
            t.x,
            t.y,
            t.z
        );
        after.print();
    }
    Ok(())
}
