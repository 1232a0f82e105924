//! The background-removal evaluation: every RGBA image marked "alpha matte" in
//! `DATA_DIR/SOURCES.md` is composited over each backdrop of `w3d_photo::eval::Backdrop`
//! at two scales (object 80 % and 35 % of a 512² frame), segmented by
//! `w3d_photo::remove_background`, and scored against its true alpha (IoU at 0.5, boundary
//! F-score within 2 pixels). The RGB images of the folder (no alpha) are prepared as a user's
//! photos would be, and their masks and framed results written for inspection.
//!
//! ```text
//! cargo run --release -p w3d-photo --example composites -- ../shared/data/images target/composites
//! ```
//!
//! A third argument limits the run to some backdrops (`white,shadow`). Writes
//! `OUT_DIR/composites.json` (every case), `OUT_DIR/composites.md` (the summary
//! tables of `docs/input.md`) and, per RGB photo, `OUT_DIR/rgb/NAME_sheet.png` (photo | mask |
//! prepared). The composites themselves are not written: the images may not be
//! redistributed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use w3d_core::Image;
use w3d_photo::eval::{Backdrop, boundary_f_score, composite, mask_iou};
use w3d_photo::{PrepareOptions, SegmentOptions, prepare, remove_background};

/// The rows of SOURCES.md whose note contains `note`: file names.
fn listed(data: &Path, note: &str) -> Result<Vec<String>, String> {
    let text = std::fs::read_to_string(data.join("SOURCES.md")).map_err(|e| format!("{}: {e}", data.display()))?;
    Ok(text
        .lines()
        .filter_map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let file = *cells.get(1)?;
            let last = cells.iter().rev().find(|c| !c.is_empty())?;
            (last.contains(note) && file.contains('.')).then(|| file.to_string())
        })
        .collect())
}

/// A row of labelled cells (input | mask | prepared) scaled to `cell` pixels high.
fn sheet(images: &[&Image], cell: u32) -> w3d_core::Result<Image> {
    let mut cells = Vec::new();
    for img in images {
        let c = img.channels() as usize;
        // RGBA is shown over a light checkerboard, masks as grey.
        let mut rgb = image::Rgb32FImage::new(img.width(), img.height());
        for (x, y, px) in rgb.enumerate_pixels_mut() {
            let p = img.pixel(x, y);
            px.0 = match c {
                1 => [p[0]; 3],
                3 => [p[0], p[1], p[2]],
                _ => {
                    let check = if ((x / 16) + (y / 16)).is_multiple_of(2) { 0.92 } else { 0.78 };
                    [0, 1, 2].map(|k| p[k] * p[3] + check * (1.0 - p[3]))
                }
            };
        }
        let w = (img.width() as f32 * cell as f32 / img.height() as f32).round().max(1.0) as u32;
        cells.push(image::imageops::resize(&rgb, w, cell, image::imageops::FilterType::Triangle));
    }
    let gap = 4;
    let total: u32 = cells.iter().map(|c| c.width() + gap).sum::<u32>() + gap;
    let mut out = Image::filled(total, cell + 2 * gap, 3, 1.0)?;
    let mut x0 = gap;
    for c in &cells {
        for (x, y, px) in c.enumerate_pixels() {
            out.pixel_mut(x0 + x, gap + y).copy_from_slice(&px.0);
        }
        x0 += c.width() + gap;
    }
    Ok(out)
}

/// A backdrop and a scale name.
type Group = (Backdrop, &'static str);
/// IoU, boundary F, refused, seconds of one case.
type Score = (f32, f32, bool, f32);

fn mean(v: &[f32]) -> f32 {
    if v.is_empty() { f32::NAN } else { v.iter().sum::<f32>() / v.len() as f32 }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (data, out, only) = match &args[..] {
        [data, out] => (data, out, None),
        [data, out, only] => (data, out, Some(only.split(',').map(str::to_string).collect::<Vec<_>>())),
        _ => {
            eprintln!("usage: composites DATA_DIR OUT_DIR [BACKDROP,...]");
            std::process::exit(2);
        }
    };
    let (data, out) = (PathBuf::from(data), PathBuf::from(out));
    std::fs::create_dir_all(out.join("rgb"))?;
    let options = SegmentOptions::default();
    let scales = [("large", 0.8f32), ("small", 0.35f32)];
    let size = 512;

    let mut cases = Vec::new();
    let mut groups: Vec<(Group, Vec<Score>)> = Vec::new();
    for (k, name) in listed(&data, "alpha matte")?.iter().enumerate() {
        let object = Image::read(data.join(name))?;
        if object.channels() != 4 {
            eprintln!("{name}: {} channels, skipped", object.channels());
            continue;
        }
        for backdrop in Backdrop::ALL {
            if only.as_ref().is_some_and(|o| !o.iter().any(|b| b == backdrop.name())) {
                continue;
            }
            for &(scale_name, fill) in &scales {
                let c = composite(&object, backdrop, size, fill, k as u64 * 31 + 7)?;
                let t = Instant::now();
                let seg = remove_background(&c.rgb, &options)?;
                let seconds = t.elapsed().as_secs_f32();
                let iou = mask_iou(&seg.alpha, &c.alpha, 0.5)?;
                let bf = boundary_f_score(&seg.alpha, &c.alpha, 0.5, 2)?;
                let refused = seg.confidence.score < PrepareOptions::default().min_confidence;
                eprintln!(
                    "{name:>36} {:>8} {scale_name:>5}: IoU {iou:.4}  BF {bf:.3}  confidence {:.2}  shadow {:.2}{}",
                    backdrop.name(),
                    seg.confidence.score,
                    seg.confidence.measures.shadow_fraction,
                    if refused { format!("  REFUSED: {}", seg.confidence.summary()) } else { String::new() }
                );
                cases.push(serde_json::json!({
                    "image": name, "backdrop": backdrop.name(), "scale": scale_name,
                    "iou": iou, "boundary_f": bf, "confidence": seg.confidence.score,
                    "reasons": seg.confidence.issues.iter().map(|i| i.reason.name()).collect::<Vec<_>>(),
                    "refused": refused, "seconds": seconds,
                    "shadow_fraction": seg.confidence.measures.shadow_fraction,
                }));
                let key = (backdrop, scale_name);
                match groups.iter_mut().find(|(k, _)| *k == key) {
                    Some((_, v)) => v.push((iou, bf, refused, seconds)),
                    None => groups.push((key, vec![(iou, bf, refused, seconds)])),
                }
            }
        }
    }

    let mut md = String::from(
        "| backdrop | scale | images | mean IoU | min IoU | mean boundary F (2 px) | refused (confidence < 0.5) |\n|---|---|---|---|---|---|---|\n",
    );
    let mut summary = Vec::new();
    for ((backdrop, scale), v) in &groups {
        let ious: Vec<f32> = v.iter().map(|r| r.0).collect();
        let bfs: Vec<f32> = v.iter().map(|r| r.1).collect();
        let refused = v.iter().filter(|r| r.2).count();
        let min = ious.iter().copied().fold(f32::INFINITY, f32::min);
        md.push_str(&format!(
            "| {} | {scale} | {} | {:.4} | {min:.4} | {:.3} | {refused} |\n",
            backdrop.name(),
            v.len(),
            mean(&ious),
            mean(&bfs)
        ));
        summary.push(serde_json::json!({
            "backdrop": backdrop.name(), "scale": scale, "images": v.len(), "mean_iou": mean(&ious),
            "min_iou": min, "mean_boundary_f": mean(&bfs), "refused": refused,
        }));
    }
    let pick = |names: &[&str]| -> Vec<f32> {
        groups.iter().filter(|((b, _), _)| names.contains(&b.name())).flat_map(|(_, v)| v.iter().map(|r| r.0)).collect()
    };
    let plain = mean(&pick(&["white", "grey", "black", "gradient"]));
    let shadow = mean(&pick(&["shadow"]));
    let wood = mean(&pick(&["wood"]));
    let seconds: Vec<f32> = groups.iter().flat_map(|(_, v)| v.iter().map(|r| r.3)).collect();
    md.push_str(&format!(
        "\nMean IoU: plain + gradient {plain:.4}, soft shadow {shadow:.4}, wood {wood:.4}; {:.3} s per 512² composite on average.\n",
        mean(&seconds)
    ));

    // The RGB photos: prepared as a user's would be.
    let mut photos = Vec::new();
    md.push_str("\n| photo | size | result | confidence | reasons | object fraction | border noise (/255) |\n|---|---|---|---|---|---|---|\n");
    for name in listed(&data, "RGB, no alpha")? {
        let photo = Image::read(data.join(&name))?;
        let t = Instant::now();
        let seg = remove_background(&photo, &options)?;
        let prepared = prepare(&photo, &PrepareOptions::default());
        let seconds = t.elapsed().as_secs_f32();
        let m = seg.confidence.measures;
        let result = match &prepared {
            Ok(_) => "prepared".to_string(),
            Err(e) => format!("refused ({e})"),
        };
        eprintln!(
            "{name}: {result}; confidence {:.2}: {}; shadow {:.2}",
            seg.confidence.score,
            seg.confidence.summary(),
            m.shadow_fraction
        );
        let masked = photo_with_alpha(&photo, &seg.alpha)?;
        let framed = prepare(&photo, &PrepareOptions::default().with_min_confidence(0.0))?;
        sheet(&[&photo, &seg.alpha, &masked, &framed.rgba], 256)?
            .write_png(out.join("rgb").join(format!("{}_sheet.png", name.split('.').next().unwrap_or("photo"))))?;
        md.push_str(&format!(
            "| {name} | {}×{} | {} | {:.2} | {} | {:.3} | {:.1} |\n",
            photo.width(),
            photo.height(),
            if prepared.is_ok() { "prepared" } else { "refused" },
            seg.confidence.score,
            seg.confidence.issues.iter().map(|i| i.reason.name()).collect::<Vec<_>>().join(", "),
            m.object_fraction,
            m.border_noise
        ));
        photos.push(serde_json::json!({
            "photo": name, "prepared": prepared.is_ok(), "confidence": seg.confidence.score,
            "summary": seg.confidence.summary(), "object_fraction": m.object_fraction,
            "border_noise": m.border_noise, "border_contact": m.border_contact, "shadow_fraction": m.shadow_fraction,
            "ambiguous_fraction": m.ambiguous_fraction, "main_share": m.main_share, "seconds": seconds,
        }));
    }
    let json = serde_json::json!({
        "size": size, "summary": summary, "mean_iou_plain_and_gradient": plain, "mean_iou_shadow": shadow,
        "mean_iou_wood": wood, "cases": cases, "photos": photos,
    });
    std::fs::write(out.join("composites.json"), serde_json::to_string_pretty(&json)?)?;
    std::fs::write(out.join("composites.md"), &md)?;
    println!("{md}");
    Ok(())
}

/// The photo (1 or 3 channels) with `alpha` as its alpha channel.
fn photo_with_alpha(photo: &Image, alpha: &Image) -> w3d_core::Result<Image> {
    let c = photo.channels() as usize;
    let data = photo
        .data()
        .chunks_exact(c)
        .zip(alpha.data())
        .flat_map(|(p, &a)| if c < 3 { [p[0], p[0], p[0], a] } else { [p[0], p[1], p[2], a] })
        .collect();
    Image::new(photo.width(), photo.height(), 4, data)
}
