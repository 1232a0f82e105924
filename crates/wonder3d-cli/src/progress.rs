//! Progress bars shared by the long-running commands.

use indicatif::{ProgressBar, ProgressStyle};
use w3d_core::{Error, Result};
use w3d_recon::{Progress, Stage};

/// A bar for one pipeline stage named `prefix` (hidden when `quiet`).
pub fn stage_bar(quiet: bool, prefix: &str) -> Result<ProgressBar> {
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
    bar.set_style(
        ProgressStyle::with_template("{prefix:>12} [{bar:40}] {pos}/{len} {msg} ({elapsed})")
            .map_err(|e| Error::invalid("progress template", e.to_string()))?
            .progress_chars("=> "),
    );
    bar.set_prefix(prefix.to_string());
    Ok(bar)
}

/// A `w3d_recon::reconstruct` progress callback that drives `bar`: the stage as prefix,
/// steps as position, the loss as message.
pub fn recon_progress(bar: &ProgressBar) -> impl FnMut(Progress) + '_ {
    move |p: Progress| {
        bar.set_prefix(match p.stage {
            Stage::Init => "init",
            Stage::Coarse => "coarse",
            Stage::Untangle => "untangle",
            Stage::Polish => "polish",
        });
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
        if let Some(loss) = p.loss {
            bar.set_message(format!("loss {loss:.5}"));
        }
    }
}
