//! `nn::multi_head_attention` on every test backend against a reference that materialises the
//! whole score matrix in f64; the CPU kernel it runs at inference and the fused differentiable
//! attention it runs under autodiff on flex against Burn's own attention, values and
//! gradients, at shapes that cross the kernels' query and key blocks.

use crate::common::{relative_max_diff, test_devices, values};
#[cfg(feature = "train")]
use burn::tensor::GradientCheckpointingStrategy;
use burn::tensor::module::attention;
use burn::tensor::ops::AttentionModuleOptions;
use w3d_diffusion::nn::multi_head_attention;
use w3d_diffusion::{Tensor, TensorData};

/// `[batch, tokens, heads · head_dim]` token-major values in about [−amp, amp] (xorshift, so
/// the test needs no random-number crate and gives the same values everywhere).
fn tokens(batch: usize, len: usize, width: usize, seed: u32, amp: f32) -> Vec<f32> {
    let mut x = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    (0..batch * len * width)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x as f32 / u32::MAX as f32 * 2.0 - 1.0) * amp
        })
        .collect()
}

/// `softmax(q·kᵀ/√d)·v` per sequence and head in f64 with the whole score matrix.
fn reference(q: &[f32], k: &[f32], v: &[f32], [batch, tq, tk, heads, d]: [usize; 5]) -> Vec<f32> {
    let w = heads * d;
    let mut out = vec![0.0f32; q.len()];
    let scale = 1.0 / (d as f64).sqrt();
    for b in 0..batch {
        for h in 0..heads {
            for i in 0..tq {
                let qi = &q[(b * tq + i) * w + h * d..][..d];
                let scores: Vec<f64> = (0..tk)
                    .map(|j| {
                        let kj = &k[(b * tk + j) * w + h * d..][..d];
                        qi.iter().zip(kj).map(|(x, y)| f64::from(*x) * f64::from(*y)).sum::<f64>() * scale
                    })
                    .collect();
                let m = scores.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let e: Vec<f64> = scores.iter().map(|s| (s - m).exp()).collect();
                let sum: f64 = e.iter().sum();
                for c in 0..d {
                    let acc: f64 = (0..tk).map(|j| e[j] * f64::from(v[(b * tk + j) * w + h * d + c])).sum();
                    out[(b * tq + i) * w + h * d + c] = (acc / sum) as f32;
                }
            }
        }
    }
    out
}

#[test]
fn attention_matches_the_whole_score_matrix_across_block_edges() {
    // [batch, queries, keys, heads, head_dim] and the scores' amplitude: query counts that are
    // not multiples of the 128-query blocks, key counts across 512-key blocks, large scores
    // (the running maximum changes between key blocks; scores near 100 cost f32 a few 1e-6),
    // one key, one query.
    let cases = [
        ([2, 150, 1100, 3, 8], 3.0),
        ([1, 5, 513, 2, 40], 1.0),
        ([3, 129, 7, 1, 16], 6.0),
        ([2, 33, 1, 2, 4], 1.0),
        ([1, 1, 600, 4, 80], 2.0),
    ];
    for (name, device) in test_devices() {
        for (shape, amp) in cases {
            let [batch, tq, tk, heads, d] = shape;
            let w = heads * d;
            let (q, k, v) = (tokens(batch, tq, w, 1, amp), tokens(batch, tk, w, 2, amp), tokens(batch, tk, w, 3, 1.0));
            let t =
                |x: &[f32], len: usize| Tensor::<3>::from_data(TensorData::new(x.to_vec(), [batch, len, w]), &device);
            let got = values(multi_head_attention(t(&q, tq), t(&k, tk), t(&v, tk), heads));
            let want = reference(&q, &k, &v, shape);
            let err = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
            println!("{name} {shape:?}: attention max-abs error {err:.1e}");
            assert!(err < 1e-5, "{name} {shape:?}: attention max-abs error {err}");
        }
    }
}

/// Burn's own attention on `[b, t, h·d]` sequences (what `multi_head_attention` computes),
/// differentiated through its tensor operations under autodiff.
fn burn_reference(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize) -> Tensor<3> {
    let [b, tq, w] = q.dims();
    let tk = k.dims()[1];
    let split = |t: Tensor<3>, len: usize| t.reshape([b, len, heads, w / heads]).swap_dims(1, 2);
    let o = attention(split(q, tq), split(k, tk), split(v, tk), None, None, AttentionModuleOptions::default());
    o.swap_dims(1, 2).reshape([b, tq, w])
}

/// Inference runs the crate's CPU kernel, training its fused differentiable attention; both
/// agree with Burn's attention at a multi-view shape (6 views × 256 tokens, 8 heads of 40
/// channels).
#[cfg(feature = "train")]
#[test]
fn cpu_kernels_match_burn_attention() {
    let [batch, t, heads, d] = [2, 6 * 256, 8, 40];
    let w = heads * d;
    let (q, k, v) = (tokens(batch, t, w, 4, 2.0), tokens(batch, t, w, 5, 2.0), tokens(batch, t, w, 6, 1.0));
    for (name, device) in test_devices() {
        let ad = device.clone().autodiff();
        let run = |device: &w3d_diffusion::Device, ours: bool| {
            let t = |x: &[f32]| Tensor::<3>::from_data(TensorData::new(x.to_vec(), [batch, t, w]), device);
            let out = if ours {
                multi_head_attention(t(&q), t(&k), t(&v), heads)
            } else {
                burn_reference(t(&q), t(&k), t(&v), heads)
            };
            values(out)
        };
        let burn = run(&device, false);
        for (path, got) in [("inference", run(&device, true)), ("autodiff", run(&ad, true))] {
            let err = got.iter().zip(&burn).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
            println!("{name} {path}: vs Burn attention max-abs difference {err:.1e}");
            assert!(err < 1e-5, "{name} {path}: vs Burn attention {err}");
        }
    }
}

/// Gradients of `Σ out ∘ g` (a fixed random `g`) with respect to q, k and v: the fused
/// attention's backward against Burn's attention differentiated op by op, with and without
/// gradient checkpointing, at shapes that cross the 128-query and 512-key blocks, with one
/// key, and with large scores.
#[cfg(feature = "train")]
#[test]
fn fused_attention_gradients_match_burn_autodiff() {
    let cases = [([2, 200, 600, 2, 8], 1.0), ([3, 7, 1, 2, 4], 1.0), ([1, 130, 70, 1, 16], 6.0)];
    for (name, device) in test_devices() {
        for strategy in [GradientCheckpointingStrategy::Disabled, GradientCheckpointingStrategy::Balanced] {
            for (shape, amp) in cases {
                let [batch, tq, tk, heads, d] = shape;
                let w = heads * d;
                let (q, k, v) =
                    (tokens(batch, tq, w, 7, amp), tokens(batch, tk, w, 8, amp), tokens(batch, tk, w, 9, 1.0));
                let g = tokens(batch, tq, w, 10, 1.0);
                let ad = device.clone().autodiff();
                let run = |ours: bool| {
                    let t = |x: &[f32], len: usize| {
                        Tensor::<3>::from_data(TensorData::new(x.to_vec(), [batch, len, w]), &ad)
                            .with_gradient_checkpointing_strategy(strategy)
                            .require_grad()
                    };
                    let (tq_, tk_, tv_) = (t(&q, tq), t(&k, tk), t(&v, tk));
                    let out = if ours {
                        multi_head_attention(tq_.clone(), tk_.clone(), tv_.clone(), heads)
                    } else {
                        burn_reference(tq_.clone(), tk_.clone(), tv_.clone(), heads)
                    };
                    let gt = Tensor::<3>::from_data(TensorData::new(g.clone(), [batch, tq, w]), &ad)
                        .with_gradient_checkpointing_strategy(strategy);
                    let grads = (out.clone() * gt).sum().backward();
                    let grad = |t: &Tensor<3>| values(t.grad(&grads).expect("a gradient"));
                    [values(out), grad(&tq_), grad(&tk_), grad(&tv_)]
                };
                let (ours, burn) = (run(true), run(false));
                for (what, (a, b)) in ["output", "dq", "dk", "dv"].iter().zip(ours.iter().zip(&burn)) {
                    let err = relative_max_diff(a, b);
                    println!("{name} {strategy:?} {shape:?} {what}: relative max-abs difference {err:.1e}");
                    assert!(err < 1e-5, "{name} {strategy:?} {shape:?} {what}: {err}");
                }
            }
        }
    }
}
