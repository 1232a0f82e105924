//! Model folders for every flag that takes one (`--weights`, `--init`, `--enhancer`): an
//! existing local folder as it is, or a Hugging Face Hub id `owner/name[@revision][:sub/folder]`
//! found in or downloaded into the Hugging Face cache (`wonder3d::weights`: `HF_ENDPOINT`,
//! `HF_HOME`, `HF_HUB_OFFLINE`), with a byte progress bar on stderr.

use std::path::{Path, PathBuf};

use indicatif::ProgressBar;
use wonder3d::weights::{Layout, WeightsSpec};
use wonder3d::{Error, Result, Stage};

use crate::progress;

/// The spec of `value` as text (a local folder needs none: it is taken as it is).
fn spec<'a>(flag: &str, value: &'a Path) -> Result<&'a str> {
    value.to_str().ok_or_else(|| {
        Error::invalid(
            flag,
            format!(
                "an existing model folder or a Hub id owner/name[@revision][:sub/folder] (found {})",
                value.display()
            ),
        )
    })
}

/// Fails, naming `flag`, when `value` is neither an existing folder nor a well-formed Hub id
/// (no network access).
pub fn check(flag: &str, value: &Path) -> Result<()> {
    if value.is_dir() {
        return Ok(());
    }
    wonder3d::outputs::for_flag(flag, WeightsSpec::parse(spec(flag, value)?)).map(|_| ())
}

/// The local folder of `value`: itself when it is an existing folder, else the cached snapshot
/// of the Hub id it names, downloaded first where the cache lacks files. The download drives
/// `bar` (its bytes, the id as message), which gets the usual style and `load` prefix back
/// afterwards; errors name `flag`.
pub fn resolve(flag: &str, value: &Path, layout: Layout, bar: &ProgressBar) -> Result<PathBuf> {
    if value.is_dir() {
        return Ok(value.to_path_buf());
    }
    let spec = spec(flag, value)?;
    let mut downloading = false;
    let mut style_error = None;
    let dir = wonder3d::weights::resolve_layout(spec, layout, &mut |p| {
        if p.stage != Stage::Download {
            return;
        }
        if !downloading {
            downloading = true;
            match progress::bytes_style() {
                Ok(style) => bar.set_style(style),
                Err(e) => style_error = Some(e),
            }
            bar.set_prefix("download");
            bar.set_message(spec.to_owned());
        }
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
    });
    if downloading {
        bar.set_style(progress::style()?);
        bar.set_prefix("load");
        bar.set_message("");
        bar.set_length(1);
        bar.set_position(0);
    }
    if let Some(e) = style_error {
        return Err(e);
    }
    wonder3d::outputs::for_flag(flag, dir)
}
