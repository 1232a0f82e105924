//! `wonder3d prepare IMAGE --out rgba.png [--no-crop] [--mask-out mask.png] [--size N]
//! [--min-confidence C] [--json]`: a photo or RGBA image → the RGBA image the model takes
//! (background removed when there is no alpha, cropped, the object's longest side 75 % of
//! the frame, centred), with the confidence of the mask and its reasons.

use std::path::{Path, PathBuf};

use wonder3d::outputs::{check_distinct, check_png_output, for_flag};
use wonder3d::photo::FrameOptions;
use wonder3d::{Error, PrepareOptions, Prepared, Result, prepare_image};

/// Arguments of `wonder3d prepare`.
#[derive(clap::Args)]
pub struct PrepareArgs {
    /// Input image: a photo (JPEG, PNG or WebP; the background is removed automatically) or
    /// an RGBA PNG / WebP whose alpha masks the object.
    pub image: PathBuf,
    /// Output RGBA PNG (straight alpha; white under transparent pixels).
    #[arg(long)]
    pub out: PathBuf,
    /// Keep the input's frame and size: only add the alpha channel (no crop, no resize).
    #[arg(long)]
    pub no_crop: bool,
    /// Also write the object mask as a grey PNG at the input's resolution.
    #[arg(long)]
    pub mask_out: Option<PathBuf>,
    /// Side of the square output in pixels (the object's longest side is 75 % of it).
    #[arg(long, default_value_t = 512, allow_hyphen_values = true, value_parser = crate::args::prepared_size)]
    pub size: u32,
    /// Refuse automatic masks less confident than this, in [0, 1] (0 accepts every mask).
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true, value_parser = crate::args::confidence)]
    pub min_confidence: f32,
    /// Print the result as one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// One line on what the preparation did: where the mask came from and how far to trust it.
pub fn describe(image: &Path, prepared: &Prepared) -> String {
    format!(
        "{}: mask from {}, confidence {:.2} (doubts: {})",
        image.display(),
        prepared.source.name(),
        prepared.confidence.score,
        prepared.confidence.summary()
    )
}

/// Runs `wonder3d prepare`.
pub fn run(args: &PrepareArgs) -> Result<()> {
    for_flag("--out", check_png_output(&args.out))?;
    if let Some(mask) = &args.mask_out {
        for_flag("--mask-out", check_png_output(mask))?;
    }
    let mut outputs = vec![("--out", args.out.as_path())];
    outputs.extend(args.mask_out.as_deref().map(|mask| ("--mask-out", mask)));
    check_distinct(&outputs, &[("IMAGE", args.image.as_path())])?;
    let options = PrepareOptions::default()
        .with_crop(!args.no_crop)
        .with_min_confidence(args.min_confidence)
        .with_frame(FrameOptions::default().with_size(args.size));
    let prepared = prepare_image(&args.image, &options)?;
    prepared.rgba.write_png(&args.out)?;
    if let Some(mask) = &args.mask_out {
        prepared.mask.write_png(mask)?;
    }
    if args.json {
        let c = &prepared.confidence;
        let m = &c.measures;
        let json = serde_json::json!({
            "image": args.image.display().to_string(),
            "out": args.out.display().to_string(),
            "width": prepared.rgba.width(),
            "height": prepared.rgba.height(),
            "source": prepared.source.name(),
            "confidence": c.score,
            "reasons": c.issues.iter().map(|i| serde_json::json!({
                "reason": i.reason.name(), "value": i.value, "factor": i.factor, "description": i.to_string(),
            })).collect::<Vec<_>>(),
            "measures": {
                "border_noise": m.border_noise, "object_fraction": m.object_fraction,
                "border_contact": m.border_contact, "ambiguous_fraction": m.ambiguous_fraction,
                "main_share": m.main_share, "shadow_fraction": m.shadow_fraction,
            },
            "crop": prepared.framing.map(|f| serde_json::json!({
                "x": f.crop.x, "y": f.crop.y, "width": f.crop.width, "height": f.crop.height, "scale": f.scale,
            })),
        });
        println!("{}", serde_json::to_string_pretty(&json).map_err(|e| Error::invalid("json", e.to_string()))?);
    } else {
        println!(
            "{} -> {} ({}×{} RGBA)",
            describe(&args.image, &prepared),
            args.out.display(),
            prepared.rgba.width(),
            prepared.rgba.height()
        );
    }
    Ok(())
}
