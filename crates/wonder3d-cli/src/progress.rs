//! Progress bars for the long-running commands, driven by the facade's staged
//! [`wonder3d::Progress`] events.

use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use wonder3d::{Error, Progress, Result};

/// A bar showing the current stage as prefix, its units as position and the loss as
/// message (hidden when `quiet`).
pub fn bar(quiet: bool) -> Result<ProgressBar> {
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
    bar.set_style(style()?);
    bar.enable_steady_tick(Duration::from_millis(200));
    Ok(bar)
}

/// The style of [`bar`]: stage, units, message, elapsed time.
pub fn style() -> Result<ProgressStyle> {
    Ok(ProgressStyle::with_template("{prefix:>10} [{bar:40}] {pos}/{len} {msg} ({elapsed})")
        .map_err(|e| Error::invalid("progress template", e.to_string()))?
        .progress_chars("=> "))
}

/// The style of a download: bytes, rate and time left.
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub fn bytes_style() -> Result<ProgressStyle> {
    Ok(ProgressStyle::with_template("{prefix:>10} [{bar:40}] {bytes}/{total_bytes} {bytes_per_sec} ETA {eta} {msg}")
        .map_err(|e| Error::invalid("progress template", e.to_string()))?
        .progress_chars("=> "))
}

/// A bar for a download alone (hidden when `quiet`): drawn only once there is something to
/// download ([`crate::weights::resolve`] styles it), so a local folder shows nothing.
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub fn download_bar(quiet: bool) -> ProgressBar {
    if quiet { ProgressBar::hidden() } else { ProgressBar::new(0) }
}

/// A progress callback that drives `bar`.
pub fn follow(bar: &ProgressBar) -> impl FnMut(Progress) + '_ {
    move |p: Progress| {
        bar.set_prefix(p.stage.name());
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
        match p.loss {
            Some(loss) => bar.set_message(format!("loss {loss:.5}")),
            None => bar.set_message(""),
        }
    }
}

/// The line to print when one view disagrees with the others (its agreement score below
/// 0.85 × the median of the others'; `wonder3d::recon::disagreeing_view`), else `None`:
/// which view, how far, and that the mesh follows the others.
pub fn disagreement_note(report: &wonder3d::recon::ReconReport) -> Option<String> {
    wonder3d::recon::disagreeing_view(&report.views, DISAGREEMENT_RATIO).map(|v| {
        format!(
            "note: the {} view disagrees with the others (silhouette IoU {:.2}, normals {:.1}° off the mesh); \
             the mesh follows the other views",
            v.view, v.mask_iou, v.normal_error_deg
        )
    })
}

/// A view scoring below this fraction of the other views' median agreement is named.
const DISAGREEMENT_RATIO: f32 = 0.85;

/// ` (fit k of n kept)` when the reconstruction tried several fits (`--starts`), why it
/// stopped after one when it skipped the others, else nothing.
pub fn starts_note(report: &wonder3d::recon::ReconReport) -> String {
    match (report.start_losses.len(), report.starts_skipped) {
        (n, skipped @ 1..) => format!(
            " (1 fit of {}: the views disagree beyond what any closed surface explains, so the other {skipped} \
             were skipped)",
            n + skipped
        ),
        (0 | 1, _) => String::new(),
        (n, _) => format!(" (fit {} of {n} kept, the best fit to the views)", report.start_kept + 1),
    }
}
