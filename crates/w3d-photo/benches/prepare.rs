//! `prepare/1024`: a 1024² synthetic product photo (a textured object with a soft shadow on
//! white, no alpha) → background removal + framing at 512²; `remove_background/1024` alone.
#![allow(missing_docs)] // criterion_group! generates an undocumented function

use criterion::{Criterion, criterion_group, criterion_main};
use w3d_core::Image;
use w3d_photo::eval::{Backdrop, composite};
use w3d_photo::{PrepareOptions, SegmentOptions, prepare, remove_background};

/// A 300×400 RGBA "vase": a superellipse body with a neck, shaded and striped.
fn object() -> Image {
    let (w, h) = (300u32, 400u32);
    let mut img = Image::filled(w, h, 4, 0.0).unwrap();
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f32 / w as f32 * 2.0 - 1.0, y as f32 / h as f32 * 2.0 - 1.0);
            let half_width = if v < -0.4 { 0.35 } else { 0.95 * (1.0 - ((v - 0.3) / 0.75).powi(4)).max(0.0).sqrt() };
            let inside = u.abs() < half_width && v > -0.98 && v < 0.98;
            if inside {
                let shade = 0.55 + 0.45 * (1.0 - (u / half_width.max(1e-3)).powi(2)).sqrt();
                let stripe = if (v * 12.0).sin() > 0.6 { 0.6 } else { 1.0 };
                img.pixel_mut(x, y).copy_from_slice(&[0.75 * shade * stripe, 0.35 * shade, 0.2 * shade * stripe, 1.0]);
            }
        }
    }
    img
}

fn bench(c: &mut Criterion) {
    let photo = composite(&object(), Backdrop::ShadowOnWhite, 1024, 0.6, 1).unwrap().rgb;
    let mut group = c.benchmark_group("photo");
    group.sample_size(10);
    group.bench_function("prepare/1024", |b| b.iter(|| prepare(&photo, &PrepareOptions::default()).unwrap()));
    group.bench_function("remove_background/1024", |b| {
        b.iter(|| remove_background(&photo, &SegmentOptions::default()).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
