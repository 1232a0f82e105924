//! `wonder3d prepare`: a photo without alpha gets its background removed and is framed; an
//! RGBA image keeps its alpha; `--no-crop` keeps the frame; a cluttered photo is refused
//! with the reasons; bad output paths fail before any work.

use crate::common::{s, wonder3d};

use wonder3d::Image;

/// A 200×150 RGB photo: a shaded teal ellipse on a light backdrop graded top to bottom.
/// Returns the photo and its true mask.
fn photo() -> (Image, Vec<bool>) {
    let (w, h) = (200u32, 150u32);
    let mut img = Image::filled(w, h, 3, 0.0).unwrap();
    let mut truth = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let (u, v) = ((x as f32 - 110.0) / 50.0, (y as f32 - 70.0) / 40.0);
            let inside = u * u + v * v < 1.0;
            let bg = 0.93 - 0.2 * y as f32 / h as f32;
            let p = if inside { [0.1, 0.45 + 0.3 * u, 0.5 - 0.2 * v] } else { [bg, bg, bg * 0.98] };
            img.pixel_mut(x, y).copy_from_slice(&p);
            truth.push(inside);
        }
    }
    (img, truth)
}

#[test]
fn photo_is_segmented_and_framed() {
    let dir = tempfile::tempdir().unwrap();
    let (img, truth) = photo();
    let input = dir.path().join("photo.png");
    img.write_png(&input).unwrap();
    let out = dir.path().join("rgba.png");
    let mask = dir.path().join("mask.png");
    let run = wonder3d(&["prepare", s(&input), "--out", s(&out), "--mask-out", s(&mask)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("mask from segmented") && stdout.contains("confidence"), "{stdout}");
    let rgba = Image::read_png(&out).unwrap();
    assert_eq!((rgba.width(), rgba.height(), rgba.channels()), (512, 512, 4));
    // The 100-pixel-wide ellipse now spans 384 pixels, centred: opaque at the centre, clear
    // at the sides.
    assert_eq!(rgba.pixel(256, 256)[3], 1.0);
    assert_eq!(rgba.pixel(40, 256)[3], 0.0);
    assert!(rgba.pixel(70, 256)[3] > 0.5);
    let mask = Image::read_png(&mask).unwrap();
    assert_eq!((mask.width(), mask.height(), mask.channels()), (200, 150, 1));
    let inter = mask.data().iter().zip(&truth).filter(|&(&m, &t)| m >= 0.5 && t).count();
    let union = mask.data().iter().zip(&truth).filter(|&(&m, &t)| m >= 0.5 || t).count();
    assert!(inter as f32 / union as f32 > 0.97, "IoU {}", inter as f32 / union as f32);
}

#[test]
fn no_crop_keeps_the_frame_and_rgba_keeps_its_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let (img, _) = photo();
    let input = dir.path().join("photo.png");
    img.write_png(&input).unwrap();
    let out = dir.path().join("same_frame.png");
    let run = wonder3d(&["prepare", s(&input), "--out", s(&out), "--no-crop", "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(json["source"], "segmented");
    assert_eq!((json["width"].as_u64(), json["height"].as_u64()), (Some(200), Some(150)));
    assert!(json["crop"].is_null());
    let rgba = Image::read_png(&out).unwrap();
    assert_eq!((rgba.width(), rgba.height(), rgba.channels()), (200, 150, 4));
    assert_eq!(rgba.pixel(110, 70)[3], 1.0);
    assert_eq!(rgba.pixel(5, 5)[3], 0.0);

    // That RGBA output goes back in: its alpha is used as it is, confidence 1.
    let again = dir.path().join("framed.png");
    let run = wonder3d(&["prepare", s(&out), "--out", s(&again), "--size", "256", "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(json["source"], "alpha");
    assert_eq!(json["confidence"].as_f64(), Some(1.0));
    assert_eq!(json["width"].as_u64(), Some(256));
}

#[test]
fn cluttered_photo_is_refused_with_reasons() {
    let dir = tempfile::tempdir().unwrap();
    let data: Vec<f32> =
        (0..120 * 90 * 3u32).map(|i| ((i.wrapping_mul(2_654_435_761) >> 9) % 256) as f32 / 255.0).collect();
    let input = dir.path().join("clutter.png");
    Image::new(120, 90, 3, data).unwrap().write_png(&input).unwrap();
    let out = dir.path().join("out.png");
    let run = wonder3d(&["prepare", s(&input), "--out", s(&out)]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("clutter.png") && err.contains("RGBA") && err.contains("cluttered"), "{err}");
    assert!(!out.exists(), "nothing written on refusal");
    // Accepting every mask, it goes through.
    let run = wonder3d(&["prepare", s(&input), "--out", s(&out), "--min-confidence", "0", "--no-crop"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
}

#[test]
fn bad_paths_and_values_fail_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let (img, _) = photo();
    let input = dir.path().join("photo.png");
    img.write_png(&input).unwrap();
    let missing = dir.path().join("no/such/folder/out.png");
    for (args, expect) in [
        (vec!["--out", s(&missing)], "create it first"),
        (vec!["--out", "out.jpg"], ".png"),
        (vec!["--out", "out.png", "--min-confidence", "2"], "--min-confidence"),
        (vec!["--out", "out.png", "--mask-out", "mask.tif"], ".png"),
    ] {
        let mut all = vec!["prepare", s(&input)];
        all.extend(args);
        let run = wonder3d(&all);
        assert!(!run.status.success());
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains(expect), "{all:?}: {err}");
    }
    // Two outputs on one file, or an output on the input, are refused before any work (the
    // mask used to overwrite the RGBA output and the command reported success).
    let same = dir.path().join("same.png");
    let input_bytes = std::fs::read(&input).unwrap();
    let run = wonder3d(&["prepare", s(&input), "--out", s(&same), "--mask-out", s(&same)]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("--mask-out") && err.contains("--out output"), "{err}");
    let run = wonder3d(&["prepare", s(&input), "--out", s(&input)]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("--out") && err.contains("IMAGE input"), "{err}");
    assert!(!same.exists());
    assert!(std::fs::read(&input).unwrap() == input_bytes, "the input is untouched");
    // Negative numbers get the option's range, not clap's "unexpected argument".
    for (option, value, range) in
        [("--size", "-1", "from 16 to 8192 pixels"), ("--min-confidence", "-0.5", "a confidence from 0 to 1")]
    {
        let run = wonder3d(&["prepare", s(&input), "--out", s(&same), option, value]);
        assert_eq!(run.status.code(), Some(2), "{option} {value}");
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains(option) && err.contains(range) && !err.contains("tip"), "{option} {value}: {err}");
    }
    let run = wonder3d(&["prepare", s(&dir.path().join("nope.jpg")), "--out", s(&dir.path().join("o.png"))]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("nope.jpg"));
}
