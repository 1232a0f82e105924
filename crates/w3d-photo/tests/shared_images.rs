//! Background removal on real objects: RGBA examples of `../shared/data/images`
//! composited over plain, graded and shadowed backdrops must come back with the IoU of
//! `docs/input.md`; the RGB examples must be prepared or refused with a clear message,
//! never crash. Skipped, with a note, when the shared folder is missing.

use std::path::PathBuf;

use w3d_core::Image;
use w3d_photo::eval::{Backdrop, boundary_f_score, composite, mask_iou};
use w3d_photo::{PrepareOptions, SegmentOptions, prepare, remove_background};

fn shared_images() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/images");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("note: {} is missing; skipping the real-image checks", dir.display());
        None
    }
}

#[test]
fn composites_of_real_objects_are_segmented() {
    let Some(dir) = shared_images() else { return };
    let mut worst = (f32::INFINITY, String::new());
    let mut ious = Vec::new();
    for (k, name) in ["box.png", "teapot.png", "milk.png", "cat.png"].iter().enumerate() {
        let object = Image::read(dir.join(name)).unwrap();
        for backdrop in [Backdrop::White, Backdrop::Gradient, Backdrop::ShadowOnWhite] {
            let c = composite(&object, backdrop, 256, 0.7, k as u64).unwrap();
            let seg = remove_background(&c.rgb, &SegmentOptions::default()).unwrap();
            let iou = mask_iou(&seg.alpha, &c.alpha, 0.5).unwrap();
            let bf = boundary_f_score(&seg.alpha, &c.alpha, 0.5, 2).unwrap();
            eprintln!(
                "{name} on {}: IoU {iou:.4}, BF {bf:.3}, confidence {:.2}",
                backdrop.name(),
                seg.confidence.score
            );
            assert!(seg.confidence.score >= 0.5, "{name} on {}: {}", backdrop.name(), seg.confidence.summary());
            if iou < worst.0 {
                worst = (iou, format!("{name} on {}", backdrop.name()));
            }
            ious.push(iou);
        }
    }
    let mean = ious.iter().sum::<f32>() / ious.len() as f32;
    assert!(mean >= 0.97, "mean IoU {mean}");
    assert!(worst.0 >= 0.95, "worst: {} with IoU {}", worst.1, worst.0);
}

#[test]
fn rgb_examples_are_prepared_or_refused_clearly() {
    let Some(dir) = shared_images() else { return };
    for name in ["cute_tiger.jpg", "dragon2.png", "mushroom_teapot.jpg", "princess-large.png", "robot.jpg"] {
        let photo = Image::read(dir.join(name)).unwrap();
        assert_eq!(photo.channels(), 3, "{name} is an RGB photo");
        match prepare(&photo, &PrepareOptions::default()) {
            Ok(p) => {
                assert!(p.confidence.score >= 0.5);
                assert_eq!((p.rgba.width(), p.rgba.height()), (512, 512));
                let covered = p.mask.data().iter().filter(|&&a| a >= 0.5).count() as f32 / p.mask.data().len() as f32;
                assert!((0.02..0.9).contains(&covered), "{name}: object covers {covered}");
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.contains("RGBA") && msg.contains("confidence"), "{name}: {msg}");
            }
        }
    }
}
