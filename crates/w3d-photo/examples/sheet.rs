//! A contact sheet of background removal on one object: the object (an RGBA image, or a
//! colour image plus a mask) is composited over white, a gradient, a soft shadow and wood,
//! and each row shows photo | mask found | prepared (framed RGBA over a checkerboard). The
//! pictures of `docs/input.md` come from it, with the bundled spot rendered by
//! `wonder3d render`:
//!
//! ```text
//! wonder3d render assets/spot.obj --size 512 --out target/spot_views
//! cargo run --release -p w3d-photo --example sheet -- target/spot_views/colour_front_right.png \
//!     target/spot_views/mask_front_right.png docs/images/input/spot_sheet.png
//! ```

use w3d_core::Image;
use w3d_photo::eval::{Backdrop, boundary_f_score, composite, mask_iou};
use w3d_photo::{PrepareOptions, prepare};

/// `img` as RGB for display: RGBA over a light checkerboard, masks as grey.
fn display(img: &Image, cell: u32) -> image::Rgb32FImage {
    let c = img.channels() as usize;
    let mut rgb = image::Rgb32FImage::new(img.width(), img.height());
    let check = img.width().max(img.height()) / 16 + 1;
    for (x, y, px) in rgb.enumerate_pixels_mut() {
        let p = img.pixel(x, y);
        px.0 = match c {
            1 => [p[0]; 3],
            3 => [p[0], p[1], p[2]],
            _ => {
                let bg = if ((x / check) + (y / check)).is_multiple_of(2) { 0.93 } else { 0.8 };
                [0, 1, 2].map(|k| p[k] * p[3] + bg * (1.0 - p[3]))
            }
        };
    }
    image::imageops::resize(&rgb, cell, cell, image::imageops::FilterType::Triangle)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [colour, mask, out] = &args[..] else {
        eprintln!("usage: sheet COLOUR.png MASK.png OUT.png");
        std::process::exit(2);
    };
    let colour = Image::read(colour)?;
    let mask = Image::read(mask)?;
    let object = if colour.channels() == 4 {
        colour
    } else {
        let grey: Vec<f32> = mask.data().chunks_exact(mask.channels() as usize).map(|p| p[0]).collect();
        colour.with_alpha(&Image::new(mask.width(), mask.height(), 1, grey)?)?
    };
    let (cell, gap) = (160u32, 4u32);
    let rows = [Backdrop::White, Backdrop::Gradient, Backdrop::ShadowOnWhite, Backdrop::Wood];
    let width = 3 * (cell + gap) + gap;
    let height = rows.len() as u32 * (cell + gap) + gap;
    let mut sheet = Image::filled(width, height, 3, 1.0)?;
    for (r, &backdrop) in rows.iter().enumerate() {
        let c = composite(&object, backdrop, 320, 0.6, r as u64 + 1)?;
        let prepared = match prepare(&c.rgb, &PrepareOptions::default().with_min_confidence(0.0)) {
            Ok(p) => p,
            // Nothing found: show the mask without framing.
            Err(_) => prepare(&c.rgb, &PrepareOptions::default().with_min_confidence(0.0).with_crop(false))?,
        };
        let iou = mask_iou(&prepared.mask, &c.alpha, 0.5)?;
        let bf = boundary_f_score(&prepared.mask, &c.alpha, 0.5, 2)?;
        println!(
            "{}: IoU {iou:.4}, boundary F {bf:.3}, confidence {:.2} ({})",
            backdrop.name(),
            prepared.confidence.score,
            prepared.confidence.summary()
        );
        for (k, img) in [&c.rgb, &prepared.mask, &prepared.rgba].into_iter().enumerate() {
            let cellimg = display(img, cell);
            let (x0, y0) = (gap + k as u32 * (cell + gap), gap + r as u32 * (cell + gap));
            for (x, y, px) in cellimg.enumerate_pixels() {
                sheet.pixel_mut(x0 + x, y0 + y).copy_from_slice(&px.0);
            }
        }
    }
    sheet.write_png(out)?;
    Ok(())
}
