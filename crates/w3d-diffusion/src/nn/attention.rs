//! Multi-head scaled dot-product attention over token sequences: the crate's CPU kernel in
//! inference, its differentiable version in training on flex, Burn's `attention` elsewhere.

use burn::tensor::module::attention;
use burn::tensor::ops::AttentionModuleOptions;
use burn::tensor::{Tensor, TensorData, s};

#[cfg(feature = "train")]
use crate::kernels::autodiff;
use crate::kernels::dispatch::{cpu_inference_f32, cpu_values};

/// Largest attention score matrix (`batch · heads · queries · keys` values) computed at once;
/// longer query sequences are processed in chunks of queries (the multi-view attention at
/// 32×32 latents has 6 × 1024 keys per query, and backends without a tiled kernel, such as
/// ndarray, materialise the whole score matrix).
pub const ATTENTION_MAX_SCORES: usize = 1 << 25;

/// `f` applied to groups of at most `group` rows (first dimension) of `x` and the results
/// concatenated: `f(x)` for an `f` that treats rows independently, with the memory of
/// `group` rows at a time. Runs `f(x)` once when `x` has at most `group` rows.
pub fn in_groups(x: Tensor<3>, group: usize, f: impl Fn(Tensor<3>) -> Tensor<3>) -> Tensor<3> {
    let [rows, t, d] = x.dims();
    let group = group.max(1);
    if rows <= group {
        return f(x);
    }
    let parts =
        (0..rows).step_by(group).map(|start| f(x.clone().slice([start..(start + group).min(rows), 0..t, 0..d])));
    Tensor::cat(parts.collect(), 0)
}

/// Scaled dot-product attention over token sequences: `q [b, tq, h·d]`, `k`/`v [b, tk, h·d]`
/// split into `heads` heads, softmax scale `1/√d`; returns `[b, tq, h·d]`.
///
/// On Burn's CPU backends without a gradient to track (inference) this runs the crate's own
/// kernel: each block of 128 queries streams over blocks of 512 keys with an online softmax
/// (the flash-attention recurrence), both products are `gemm` calls on cache-sized blocks and
/// the exponentials are vectorised; at the multi-view UNet's shapes it is 1.7–3.5× faster
/// than the backends' attention and on par with torch 2.4.1's (`docs/benchmarks.md`, "The attention
/// kernel"). In training on flex the same kernel is one differentiable operation whose
/// backward recomputes the attention weights block by block (flash attention's backward).
/// Elsewhere (GPU backends, training on ndarray) it is Burn's `attention`, with queries
/// processed in chunks so that at most [`ATTENTION_MAX_SCORES`] scores exist at a time.
pub fn multi_head_attention(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize) -> Tensor<3> {
    let [b, tq, _] = q.dims();
    crate::compute::record(crate::compute::WorkKind::AttentionScores, (b * heads * tq * k.dims()[1]) as u64);
    if cpu_kernel_applies(&q, &k, &v) {
        return cpu_kernel_attention(q, k, v, heads);
    }
    #[cfg(feature = "train")]
    if let Some(strategy) = autodiff::attention_applies(&q, &k, &v) {
        return autodiff::attention(q, k, v, heads, strategy);
    }
    burn_attention(q, k, v, heads, AttentionModuleOptions::default())
}

/// [`multi_head_attention`] of a sequence over itself with a causal mask: query `i` attends to
/// keys `0..=i` only (a decoder-style self-attention, as CLIP's text tower uses). `q`, `k`, `v`
/// are `[b, t, h·d]`; returns `[b, t, h·d]`. Always Burn's `attention` with `is_causal` (the
/// crate's CPU kernel has no mask; the sequences this serves are short, e.g. 77 text tokens).
pub fn causal_multi_head_attention(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize) -> Tensor<3> {
    burn_attention(q, k, v, heads, AttentionModuleOptions { is_causal: true, ..Default::default() })
}

/// Burn's `attention` on `[b, t, h·d]` sequences split into `heads` heads, with queries in
/// chunks so that at most [`ATTENTION_MAX_SCORES`] scores exist at a time (a chunk of queries
/// `start..end` under a causal mask would be misaligned, so causal calls run in one piece).
fn burn_attention(
    q: Tensor<3>,
    k: Tensor<3>,
    v: Tensor<3>,
    heads: usize,
    options: AttentionModuleOptions,
) -> Tensor<3> {
    let [b, tq, width] = q.dims();
    let tk = k.dims()[1];
    let d = width / heads;
    let split = |t: Tensor<3>, len: usize| t.reshape([b, len, heads, d]).swap_dims(1, 2);
    let (q, k, v) = (split(q, tq), split(k, tk), split(v, tk));
    let chunk = (ATTENTION_MAX_SCORES / (b * heads * tk).max(1)).max(1);
    let o = if chunk >= tq || options.is_causal {
        attention(q, k, v, None, None, options)
    } else {
        let parts = (0..tq)
            .step_by(chunk)
            .map(|start| {
                let end = (start + chunk).min(tq);
                let q = q.clone().slice(s![.., .., start..end, ..]);
                attention(q, k.clone(), v.clone(), None, None, options)
            })
            .collect();
        Tensor::cat(parts, 2)
    };
    o.swap_dims(1, 2).reshape([b, tq, width])
}

/// Whether [`cpu_kernel_attention`] takes the call: every tensor is one the crate's CPU
/// inference kernels take ([`cpu_inference_f32`]; otherwise Burn's op runs).
fn cpu_kernel_applies(q: &Tensor<3>, k: &Tensor<3>, v: &Tensor<3>) -> bool {
    cpu_inference_f32(q) && cpu_inference_f32(k) && cpu_inference_f32(v)
}

/// The attention through [`crate::kernels::attention`]. The tensors are taken by value: the
/// projections that produce them hold no other reference, so on flex their values move out
/// without a copy.
fn cpu_kernel_attention(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize) -> Tensor<3> {
    let device = q.device();
    let [batch, queries, width] = q.dims();
    let keys = k.dims()[1];
    let shape = crate::kernels::attention::AttentionShape { batch, queries, keys, heads, head_dim: width / heads };
    let out = crate::kernels::attention::attention(&cpu_values(q), &cpu_values(k), &cpu_values(v), shape);
    Tensor::from_data(TensorData::new(out, [batch, queries, width]), &device)
}
