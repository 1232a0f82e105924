//! bf16 products ([`Products::Bf16`], issue #60) through the public API: `Linear` and
//! `Conv2d` against f64 sums of their bf16-rounded factors (f32 and f16 weights), the tiny
//! multi-view UNet within a measured bound of its f32 output, the work counts, and with f32
//! products (the default) the very bits of the plain forward. The kernel's own cases (odd
//! shapes, NaN, rounding) are unit tests of `kernels/bf16.rs`. The bf16 cases return early on
//! a CPU without AVX-512 BF16, where the layers never take that path.
//!
//! `cargo test --release -p w3d-diffusion --test bf16 -- --ignored --nocapture --test-threads 1`
//! times the products at the real-size UNet's shapes against the f32 paths, and one forward of
//! the real-size multi-view UNet with either products.

mod common;

use burn::module::Param;
use burn::tensor::FloatDType;
use common::{fixture, tensor, values};
use w3d_diffusion::compute::{self, PassSettings, Products, Work};
use w3d_diffusion::nn::{Conv2d, ConvAlgorithm, Linear};
use w3d_diffusion::{SafetensorsFile, Tensor, UNet, WeightStorage, gaussian_noise};

fn bf16() -> PassSettings {
    PassSettings::default().with_products(Products::Bf16)
}

/// Whether this CPU runs bf16 products; prints why a test stops early where it does not.
fn bf16_supported(test: &str) -> bool {
    let ok = Products::Bf16.supported();
    if !ok {
        eprintln!("{test}: skipped, this CPU has no AVX-512 BF16 (the layers keep f32 products)");
    }
    ok
}

/// `x` rounded to bf16 (to nearest, ties to even), as f64.
fn rounded(x: f32) -> f64 {
    half::bf16::from_f32(x).to_f64()
}

/// Runs `f` with `settings` inside a work count.
fn counted<R>(settings: PassSettings, f: impl FnOnce() -> R) -> (R, Work) {
    compute::count_work(|| compute::with_settings(settings, f))
}

fn linear_layer(d_in: usize, d_out: usize, seed: u64, half_weights: bool) -> Linear {
    let device = w3d_diffusion::default_device();
    let mut weight = gaussian_noise([d_in, d_out], seed, &device) * (1.0 / (d_in as f32).sqrt());
    if half_weights {
        weight = weight.cast(FloatDType::F16);
    }
    let bias = gaussian_noise([d_out], seed + 1, &device);
    Linear { weight: Param::from_tensor(weight), bias: Some(Param::from_tensor(bias)) }
}

fn conv_layer(c_in: usize, c_out: usize, kernel: usize, stride: usize, padding: usize, seed: u64) -> Conv2d {
    let device = w3d_diffusion::default_device();
    let fan_in = (c_in * kernel * kernel) as f32;
    let weight = gaussian_noise([c_out, c_in, kernel, kernel], seed, &device) * (1.0 / fan_in.sqrt());
    Conv2d {
        weight: Param::from_tensor(weight.cast(FloatDType::F16)),
        bias: Some(Param::from_tensor(gaussian_noise([c_out], seed + 1, &device))),
        stride,
        padding,
    }
}

/// A weight's values as f32 (f16 ones widened).
fn weight_values<const D: usize>(w: &Param<Tensor<D>>) -> Vec<f32> {
    values(w.val().cast(FloatDType::F32))
}

/// Largest `|got − want| / Σ|products|` over the outputs.
fn worst_relative(got: &[f32], want: &[f64], scale: &[f64]) -> f64 {
    got.iter().zip(want).zip(scale).map(|((&g, &w), &s)| (g as f64 - w).abs() / s.max(1e-30)).fold(0.0, f64::max)
}

#[test]
fn linear_sums_the_rounded_products_and_counts_them() {
    if !bf16_supported("linear") {
        return;
    }
    let device = w3d_diffusion::default_device();
    for (half_weights, [batch, tokens, d_in, d_out]) in
        [(true, [2, 17, 33, 65]), (false, [1, 3, 320, 40]), (true, [3, 50, 513, 7])]
    {
        let layer = linear_layer(d_in, d_out, 7, half_weights);
        let x = gaussian_noise([batch, tokens, d_in], 3, &device);
        let (y, work) = counted(bf16(), || layer.forward(x.clone()));
        assert_eq!(y.dims(), [batch, tokens, d_out]);
        assert_eq!(work.bf16_multiply_adds, (batch * tokens * d_in * d_out) as u64);
        let (xs, w, b) = (values(x.clone()), weight_values(&layer.weight), values(layer.bias.as_ref().unwrap().val()));
        let rows = batch * tokens;
        let (mut want, mut scale) = (vec![0.0f64; rows * d_out], vec![0.0f64; rows * d_out]);
        for r in 0..rows {
            for j in 0..d_out {
                for k in 0..d_in {
                    let p = rounded(xs[r * d_in + k]) * rounded(w[k * d_out + j]);
                    want[r * d_out + j] += p;
                    scale[r * d_out + j] += p.abs();
                }
                want[r * d_out + j] += b[j] as f64;
            }
        }
        let err = worst_relative(&values(y), &want, &scale);
        assert!(err <= 1e-5, "{d_in}→{d_out}: error {err:.2e} of the products' magnitudes");

        // f32 products, asked for or by default: the plain forward, bit for bit, nothing counted.
        let plain = values(layer.forward(x.clone()));
        let (y, work) = counted(PassSettings::default(), || layer.forward(x.clone()));
        assert_eq!(values(y), plain);
        assert_eq!(work.bf16_multiply_adds, 0);
    }
}

#[test]
fn conv2d_sums_the_rounded_products_and_counts_them() {
    if !bf16_supported("conv2d") {
        return;
    }
    let device = w3d_diffusion::default_device();
    // (batch, c_in, side, c_out, kernel, stride, padding)
    for (n, c_in, side, c_out, k, s, p) in [(2, 9, 7, 17, 3, 1, 1), (3, 5, 8, 6, 3, 2, 1), (1, 33, 6, 15, 1, 1, 0)] {
        let conv = conv_layer(c_in, c_out, k, s, p, 11);
        let x = gaussian_noise([n, c_in, side, side], 5, &device);
        for algorithm in [ConvAlgorithm::Auto, ConvAlgorithm::Im2col] {
            let (y, work) = counted(bf16(), || conv.forward_with(x.clone(), algorithm));
            let [_, _, ho, wo] = y.dims();
            assert_eq!(y.dims(), [n, c_out, (side + 2 * p - k) / s + 1, (side + 2 * p - k) / s + 1]);
            assert_eq!(work.bf16_multiply_adds, (n * c_out * ho * wo * c_in * k * k) as u64);
            let (xs, w, b) =
                (values(x.clone()), weight_values(&conv.weight), values(conv.bias.as_ref().unwrap().val()));
            let got = values(y);
            let (mut want, mut scale) = (vec![0.0f64; got.len()], vec![0.0f64; got.len()]);
            for (i, (want, scale)) in want.iter_mut().zip(&mut scale).enumerate() {
                let (img, o, oy, ox) = (i / (c_out * ho * wo), i / (ho * wo) % c_out, i / wo % ho, i % wo);
                *want = b[o] as f64;
                for c in 0..c_in {
                    for ky in 0..k {
                        for kx in 0..k {
                            let (iy, ix) = ((oy * s + ky) as isize - p as isize, (ox * s + kx) as isize - p as isize);
                            if iy < 0 || ix < 0 || iy >= side as isize || ix >= side as isize {
                                continue;
                            }
                            let xv = xs[((img * c_in + c) * side + iy as usize) * side + ix as usize];
                            let prod = rounded(xv) * rounded(w[((o * c_in + c) * k + ky) * k + kx]);
                            *want += prod;
                            *scale += prod.abs();
                        }
                    }
                }
            }
            let err = worst_relative(&got, &want, &scale);
            assert!(err <= 1e-5, "{algorithm:?} {c_in}→{c_out} k{k} s{s}: error {err:.2e}");
        }
        // The backend's own convolution stays f32 whatever the pass asks for.
        let (direct, work) = counted(bf16(), || conv.forward_with(x.clone(), ConvAlgorithm::Direct));
        assert_eq!(values(direct), values(conv.forward_with(x.clone(), ConvAlgorithm::Direct)));
        assert_eq!(work.bf16_multiply_adds, 0);
        let plain = values(conv.forward(x.clone()));
        let (y, work) = counted(PassSettings::default(), || conv.forward(x.clone()));
        assert_eq!((values(y), work.bf16_multiply_adds), (plain, 0));
    }
}

/// The tiny multi-view UNet (f16 weights on disk, held as f32 and as stored) with bf16
/// products against f32 products: measured 9.8e-3 max-abs and 1.8e-3 mean-abs difference of
/// its output (whose largest magnitude is 1.30), the same for both storages; the bounds are
/// about twice those.
#[test]
fn tiny_unet_with_bf16_products_stays_near_f32() {
    let device = w3d_diffusion::default_device();
    let mut io = SafetensorsFile::open(fixture("multiview/unet_io.safetensors")).unwrap();
    let timesteps = values(tensor::<1>(&mut io, "timesteps", &device));
    let (sample, context, labels) = (
        tensor::<4>(&mut io, "sample", &device),
        tensor::<3>(&mut io, "context", &device),
        tensor::<2>(&mut io, "class_labels_ortho", &device),
    );
    for storage in [WeightStorage::F32, WeightStorage::AsStored] {
        let unet = UNet::from_dir_with(fixture("wonder3d_tiny/unet"), &device, storage).unwrap();
        let forward =
            || values(unet.forward(sample.clone(), &timesteps, context.clone(), Some(labels.clone())).unwrap());
        let plain = forward();
        let (f32_products, work) = counted(PassSettings::default(), forward);
        assert_eq!(f32_products, plain, "{storage:?}: f32 products are the plain forward's bits");
        assert_eq!(work.bf16_multiply_adds, 0);
        if !bf16_supported("tiny UNet") {
            return;
        }
        let (bf16_products, work) = counted(bf16(), forward);
        assert!(work.bf16_multiply_adds > 0 && work.unet_passes == 1, "{work:?}");
        let scale = plain.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let diff = common::max_abs_vec(&bf16_products, &plain);
        let mean = bf16_products.iter().zip(&plain).map(|(a, b)| (a - b).abs()).sum::<f32>() / plain.len() as f32;
        eprintln!(
            "tiny UNet, {storage:?} weights: bf16 vs f32 products, max-abs {diff:.2e}, mean-abs {mean:.2e} \
             (output max {scale:.2}; {} bf16 multiply-adds)",
            work.bf16_multiply_adds
        );
        assert!(diff > 0.0 && diff <= 2e-2 && mean <= 4e-3, "{storage:?}: bf16 products moved the output by {diff}");
    }
}

// ---------------------------------------------------------------------------------------------
// Timing (ignored: `-- --ignored --nocapture`).

/// Medians in milliseconds of `runs` timed calls of each of `methods`, after one untimed call
/// of each: the calls interleaved (round-robin), so that a change of the machine's load during
/// the measurement weighs on every method alike.
fn medians_ms(runs: usize, methods: &mut [&mut dyn FnMut()]) -> Vec<f64> {
    methods.iter_mut().for_each(|f| f());
    let mut times = vec![Vec::with_capacity(runs); methods.len()];
    for _ in 0..runs {
        for (f, times) in methods.iter_mut().zip(&mut times) {
            let start = std::time::Instant::now();
            f();
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    times
        .into_iter()
        .map(|mut t| {
            t.sort_by(f64::total_cmp);
            t[runs / 2]
        })
        .collect()
}

/// Waits for `t`'s values and frees them without copying them (a copy of a 100 MiB output
/// would cost its page faults, which the `gemm` crate's timings do not pay).
fn finish<const D: usize>(t: Tensor<D>) {
    drop(t.into_data());
}

/// `C = A·B` with the `gemm` crate in f32 on rayon's pool (all threads): `a` `[m, k]`, `b`
/// `[k, n]`, row-major.
fn gemm_f32(a: &[f32], b: &[f32], m: usize, k: usize, n: usize) -> Vec<f32> {
    assert_eq!((a.len(), b.len()), (m * k, k * n));
    let mut c = vec![0.0f32; m * n];
    // SAFETY: the three row-major matrices lie in their slices (lengths asserted above), `c`
    // is written without being read (`read_dst` false) and aliases neither input.
    #[allow(unsafe_code)]
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            n as isize,
            false,
            a.as_ptr(),
            1,
            k as isize,
            b.as_ptr(),
            1,
            n as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::Rayon(0),
        );
    }
    c
}

#[test]
#[ignore = "timing: run with --ignored --nocapture"]
fn time_bf16_products_at_the_real_unet_shapes() {
    if !bf16_supported("timing") {
        return;
    }
    let runs: usize = std::env::var("W3D_BF16_RUNS").ok().and_then(|v| v.parse().ok()).unwrap_or(5);
    let device = w3d_diffusion::default_device();
    let load = || std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim().to_string();
    println!("load average before: {}", load());
    println!("threads: {}, median of {runs} interleaved runs", rayon::current_num_threads());
    println!(
        "| product (m × k × n) | GMAC | f32 flex matmul (ms) | f32 gemm crate (ms) | Linear f32, f16 weight (ms) | bf16 Linear, f16 weight (ms) | bf16 GMAC/s | speed-up vs best f32 |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for [rows, d_in, d_out] in [
        [12288, 320, 320],
        [12288, 320, 2560],
        [12288, 1280, 320],
        [3072, 640, 640],
        [3072, 640, 5120],
        [3072, 2560, 640],
        [768, 1280, 1280],
    ] {
        let x = gaussian_noise([rows, d_in], 1, &device);
        let layer = linear_layer(d_in, d_out, 2, true);
        let w32 = layer.weight.val().cast(FloatDType::F32);
        let (xs, ws) = (values(x.clone()), values(w32.clone()));
        let [flex, gemm, linear, bf] = medians_ms(
            runs,
            &mut [
                &mut || finish(x.clone().matmul(w32.clone())),
                &mut || drop(gemm_f32(&xs, &ws, rows, d_in, d_out)),
                &mut || finish(layer.forward(x.clone())),
                &mut || finish(compute::with_settings(bf16(), || layer.forward(x.clone()))),
            ],
        )[..] else {
            unreachable!()
        };
        let gmac = (rows * d_in * d_out) as f64 / 1e9;
        println!(
            "| {rows} × {d_in} × {d_out} | {gmac:.2} | {flex:.1} | {gemm:.1} | {linear:.1} | {bf:.1} | {:.0} | {:.2} |",
            gmac / bf * 1e3,
            flex.min(gemm) / bf
        );
    }
    println!();
    println!(
        "| convolution (GEMM m × k × n) | GMAC | f32 Auto (ms) | f32 im2col (ms) | f32 GEMM alone, gemm crate (ms) | bf16 conv (ms) | bf16 GMAC/s | speed-up vs best f32 conv |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (c, side) in [(320, 32), (640, 16), (1280, 8)] {
        let (batch, k) = (12, 3);
        let conv = conv_layer(c, c, k, 1, 1, 3);
        let x = gaussian_noise([batch, c, side, side], 4, &device);
        let (m, kk, n) = (c, c * k * k, batch * side * side);
        let a = values(gaussian_noise([m, kk], 5, &device));
        let b = values(gaussian_noise([kk, n], 6, &device));
        let [auto, im2col, gemm, bf] = medians_ms(
            runs,
            &mut [
                &mut || finish(conv.forward(x.clone())),
                &mut || finish(conv.forward_with(x.clone(), ConvAlgorithm::Im2col)),
                &mut || drop(gemm_f32(&a, &b, m, kk, n)),
                &mut || finish(compute::with_settings(bf16(), || conv.forward(x.clone()))),
            ],
        )[..] else {
            unreachable!()
        };
        let gmac = (m * kk * n) as f64 / 1e9;
        println!(
            "| {c}→{c} 3×3 @{side}², batch {batch} ([{m}, {kk}]·[{kk}, {n}]) | {gmac:.2} | {auto:.1} | {im2col:.1} | {gemm:.1} | {bf:.1} | {:.0} | {:.2} |",
            gmac / bf * 1e3,
            auto.min(im2col) / bf
        );
    }
    println!("load average after: {}", load());
}

/// One forward of the real-size multi-view UNet (`configs/wonder3d/unet_mv`, random f16
/// weights as generation holds them) over the 12 images of a step's guidance branch (6 views ×
/// 2 domains, 32×32 latents), with f32 and with bf16 products: the faster of two rounds each.
#[test]
#[ignore = "slow: real-size multi-view UNet (~0.9 G parameters); run with --ignored --nocapture"]
fn time_real_size_multiview_unet_forward() {
    if !bf16_supported("real-size UNet") {
        return;
    }
    let device = w3d_diffusion::default_device();
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/wonder3d/unet_mv/config.json");
    let config = w3d_diffusion::UNetConfig::from_file(path).unwrap();
    let unet = UNet::random_with(&config, 1, &device, WeightStorage::F16).unwrap();
    let mut labels =
        w3d_diffusion::switcher_labels(w3d_diffusion::Domain::Normal, w3d_diffusion::CameraType::Orthographic, 14)
            .unwrap();
    labels.extend(
        w3d_diffusion::switcher_labels(w3d_diffusion::Domain::Colour, w3d_diffusion::CameraType::Orthographic, 14)
            .unwrap(),
    );
    let labels = Tensor::<2>::from_data(w3d_diffusion::TensorData::new(labels, [12, 14]), &device);
    let (sample, context) = (gaussian_noise([12, 8, 32, 32], 2, &device), gaussian_noise([12, 1, 768], 3, &device));
    let forward = || values(unet.forward(sample.clone(), &[500.0], context.clone(), Some(labels.clone())).unwrap());
    let load = || std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim().to_string();
    println!("load average before: {}", load());
    // Two rounds, f32 then bf16 in each, the faster of each kept (the first call of a
    // process also pays the allocator's growth).
    let (mut f32_s, mut bf16_s) = (f64::MAX, f64::MAX);
    let (mut plain, mut bf, mut work) = (Vec::new(), Vec::new(), Work::default());
    for _ in 0..2 {
        let start = std::time::Instant::now();
        plain = forward();
        f32_s = f32_s.min(start.elapsed().as_secs_f64());
        let start = std::time::Instant::now();
        (bf, work) = counted(bf16(), forward);
        bf16_s = bf16_s.min(start.elapsed().as_secs_f64());
    }
    let scale = plain.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    println!(
        "real-size MV UNet forward, 12 × 8 × 32 × 32: f32 products {f32_s:.1} s, bf16 products {bf16_s:.1} s ({:.2}x; \
         {:.0} G bf16 multiply-adds); max-abs difference {:.2e} (output max {scale:.2})",
        f32_s / bf16_s,
        work.bf16_multiply_adds as f64 / 1e9,
        common::max_abs_vec(&bf, &plain)
    );
    println!("load average after: {}", load());
}
