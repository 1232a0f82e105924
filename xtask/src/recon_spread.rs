//! `cargo xtask recon-spread --views DIR --objects spot,plane [--seeds 8] [--starts 1] [--repairs]`: how
//! far one reconstruction's Chamfer distance moves with the remesher's seed alone
//! (`docs/accuracy.md`, "Several starts"). For each object of the small model's set, the
//! views in `DIR/<object>` (as `cargo xtask eval-small` saves its generated ones; `--views
//! truth` renders the true views of the same sample instead) are reconstructed with the
//! default preset at seeds `0..seeds`, each with `--starts` fits (`--repairs`: the remesher's
//! repairs on from the first step), and every result is scored
//! against the posed object as `eval-small` scores it. Prints one line per seed (CD, final
//! view loss, crossings untangled, triangles) and the spread.

use std::path::Path;

use wonder3d::ViewSet;
use wonder3d::eval::{EvalOptions, evaluate};
use wonder3d::recon::{Preset, ReconOptions, reconstruct};

use crate::eval_small::{object_name, pick_objects, scored_sample};

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// Side of the true views rendered for `--views truth` (the small model's).
const TRUTH_SIZE: u32 = 64;

/// Runs `recon-spread` (see the module docs).
pub(crate) fn run(views_root: &Path, objects: &str, seeds: u64, starts: usize, repairs: bool) -> Result<(), String> {
    // (0 starts: `reconstruct` refuses them before any work.)
    if seeds == 0 {
        return Err("--seeds: at least 1".into());
    }
    let root = crate::workspace::workspace_root();
    let truth = views_root.as_os_str() == "truth";
    for mesh_path in pick_objects(Some(objects))? {
        let name = object_name(mesh_path);
        let views = if truth { None } else { Some(ViewSet::load(views_root.join(&name)).map_err(err)?) };
        let size = views.as_ref().map_or(TRUTH_SIZE, |v| v.views()[0].mask.width());
        let (dataset, posed) = scored_sample(&root.join(mesh_path), size)?;
        let views = match views {
            Some(views) => views,
            None => dataset.render_sample(0).map_err(err)?,
        };
        let mut cds = Vec::new();
        for seed in 0..seeds {
            let mut options = ReconOptions::preset(Preset::Default).with_seed(seed).with_starts(starts);
            options.coarse = options.coarse.with_remesh_repairs(repairs);
            let (mesh, report) = reconstruct(&views, &options, &mut |_| {}).map_err(err)?;
            let cd = evaluate(&mesh, &posed, &EvalOptions::default().with_normalize_pred(true)).map_err(err)?.chamfer;
            eprintln!(
                "{name} seed {seed}: CD {cd:.4}, final view loss {:.4} (fit {} of {starts}), {} crossings untangled, \
                 {} triangles, {:.1} s",
                report.polish.loss_after,
                report.start_kept + 1,
                report.untangle.before,
                mesh.triangle_count(),
                report.seconds
            );
            cds.push(cd);
        }
        let mean = cds.iter().sum::<f64>() / cds.len() as f64;
        let (min, max) = cds.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &c| (lo.min(c), hi.max(c)));
        eprintln!("{name}: CD mean {mean:.4}, min {min:.4}, max {max:.4} over {seeds} seeds");
    }
    Ok(())
}
