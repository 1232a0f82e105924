//! Scaled dot-product attention on the CPU, on plain `f32` slices: the kernel
//! [`crate::nn::multi_head_attention`] runs on Burn's CPU backends when no gradient is tracked.
//!
//! Why a kernel of our own: the multi-view attention of a guided step (four groups × 8 heads ×
//! 6144 queries × 6144 keys at the 32×32 level) is where a CPU spends most of that step. The
//! backends' attention evaluates the softmax one scalar `expf` at a time between two GEMMs;
//! measured at the real-size shapes it ran at 27–69 GFLOP/s, against a GEMM peak of about
//! 185 GFLOP/s on the same cores (`docs/benchmarks.md`, "The attention kernel"). Here each
//! block of queries streams over blocks of keys with an online softmax (the flash-attention
//! recurrence), both products are `gemm` calls on cache-sized blocks, and the exponentials
//! are a polynomial the compiler vectorises.
//!
//! The arithmetic is the textbook one, `softmax(q·kᵀ/√d)·v`, evaluated in f32 with the running
//! maximum subtracted before every exponential, so the result matches an implementation that
//! materialises the whole score matrix to f32 rounding.

use rayon::prelude::*;

use crate::kernels::gemm::{MatMut, MatRef, gemm_f32};

/// Queries per work unit: the rows of one score block.
const QUERY_BLOCK: usize = 128;
/// Keys per score block. `QUERY_BLOCK × KEY_BLOCK` scores (256 KiB) stay in a core's L2 cache
/// between the two products; blocks from 64 × 256 to 256 × 1024 were timed at the multi-view
/// UNet's shapes, and 128 × 512 was among the fastest at every level.
const KEY_BLOCK: usize = 512;

/// Shape of a multi-head attention on token-major slices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct AttentionShape {
    /// Independent sequences (the batch).
    pub batch: usize,
    /// Query tokens per sequence.
    pub queries: usize,
    /// Key (and value) tokens per sequence.
    pub keys: usize,
    /// Heads; each uses `head_dim` consecutive channels of a token.
    pub heads: usize,
    /// Channels per head.
    pub head_dim: usize,
}

impl AttentionShape {
    fn width(&self) -> usize {
        self.heads * self.head_dim
    }
}

/// `softmax(q·kᵀ/√d)·v` per sequence and head. `q` is `[batch, queries, heads·head_dim]`,
/// `k` and `v` are `[batch, keys, heads·head_dim]`, all row-major (the layout the projections
/// produce, so no transpose is needed); returns `[batch, queries, heads·head_dim]`.
///
/// # Panics
/// If a slice's length does not match `shape` (a programming error: the caller builds both).
pub(crate) fn attention(q: &[f32], k: &[f32], v: &[f32], shape: AttentionShape) -> Vec<f32> {
    attention_impl(q, k, v, shape, None)
}

#[cfg(feature = "train")]
/// [`attention`] that also returns, per sequence, query and head, the log of the softmax's
/// normaliser `lse = max + ln Σ exp(s − max)` over that query's scores `s` (`[batch, queries,
/// heads]`): what [`attention_backward`] needs to recompute the attention weights exactly
/// without storing them.
pub(crate) fn attention_with_lse(q: &[f32], k: &[f32], v: &[f32], shape: AttentionShape) -> (Vec<f32>, Vec<f32>) {
    let mut lse = vec![0.0f32; shape.batch * shape.queries * shape.heads];
    let out = attention_impl(q, k, v, shape, Some(&mut lse));
    (out, lse)
}

/// The forward pass; writes the normalisers into `lse` when asked.
fn attention_impl(q: &[f32], k: &[f32], v: &[f32], shape: AttentionShape, lse: Option<&mut [f32]>) -> Vec<f32> {
    let width = shape.width();
    assert_eq!(q.len(), shape.batch * shape.queries * width, "query length");
    assert_eq!(k.len(), shape.batch * shape.keys * width, "key length");
    assert_eq!(v.len(), shape.batch * shape.keys * width, "value length");
    let mut out = vec![0.0f32; q.len()];
    if out.is_empty() {
        return out;
    }
    if shape.keys == 0 {
        // No key to attend to: PyTorch's SDPA gives NaN here (0/0); say it the same way.
        out.fill(f32::NAN);
        return out;
    }
    let scale = 1.0 / (shape.head_dim as f32).sqrt();
    let seq_q = shape.queries * width;
    let seq_k = shape.keys * width;
    // One unit = one block of queries of one sequence, all heads: its output rows are one
    // contiguous chunk of `out`, so units write disjoint memory.
    let units: Vec<(usize, usize)> =
        (0..shape.batch).flat_map(|b| (0..shape.queries).step_by(QUERY_BLOCK).map(move |q0| (b, q0))).collect();
    let mut chunks: Vec<&mut [f32]> = Vec::with_capacity(units.len());
    let mut rest = out.as_mut_slice();
    for &(_, q0) in &units {
        let rows = QUERY_BLOCK.min(shape.queries - q0);
        let (chunk, tail) = rest.split_at_mut(rows * width);
        chunks.push(chunk);
        rest = tail;
    }
    // The normalisers of a unit are `rows × heads` consecutive values, in the units' order.
    let mut lse_chunks: Vec<Option<&mut [f32]>> = Vec::with_capacity(units.len());
    match lse {
        Some(lse) => {
            assert_eq!(lse.len(), shape.batch * shape.queries * shape.heads, "lse length");
            let mut rest = lse;
            for chunk in &chunks {
                let (head, tail) = rest.split_at_mut(chunk.len() / width * shape.heads);
                lse_chunks.push(Some(head));
                rest = tail;
            }
        }
        None => lse_chunks.resize_with(units.len(), || None),
    }
    units.into_par_iter().zip(chunks).zip(lse_chunks).for_each_init(
        Scratch::default,
        |scratch, (((b, q0), out_rows), mut lse_rows)| {
            let rows = out_rows.len() / width;
            let q_rows = &q[b * seq_q + q0 * width..b * seq_q + (q0 + rows) * width];
            let k_seq = &k[b * seq_k..(b + 1) * seq_k];
            let v_seq = &v[b * seq_k..(b + 1) * seq_k];
            for h in 0..shape.heads {
                query_block_head(q_rows, k_seq, v_seq, out_rows, h, rows, scale, shape, scratch);
                if let Some(lse_rows) = lse_rows.as_deref_mut() {
                    for (i, (&m, &l)) in scratch.row_max.iter().zip(&scratch.row_sum).enumerate() {
                        lse_rows[i * shape.heads + h] = m + l.ln();
                    }
                }
            }
        },
    );
    out
}

#[cfg(feature = "train")]
/// Gradients of [`attention`] with respect to `q`, `k` and `v` (each in its input's layout),
/// given the forward's output `out`, its normalisers `lse` ([`attention_with_lse`]) and the
/// gradient `d_out` of the output.
///
/// The attention weights are recomputed block by block from `lse` (`p = exp(s − lse)`, exact to
/// f32 rounding) instead of being stored, as flash attention's backward does; per block of
/// queries and keys, with `D = rowsum(dO ∘ O)`: `dV += pᵀ·dO`, `dp = dO·Vᵀ`,
/// `ds = p ∘ (dp − D)`, `dQ += scale·ds·K`, `dK += scale·dsᵀ·Q`. Work units are (sequence,
/// head) pairs, each accumulating its own `dK`/`dV` columns.
///
/// # Panics
/// If a slice's length does not match `shape` (a programming error: the caller builds all).
#[allow(clippy::too_many_arguments)]
pub(crate) fn attention_backward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    out: &[f32],
    lse: &[f32],
    d_out: &[f32],
    shape: AttentionShape,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (width, d, heads) = (shape.width(), shape.head_dim, shape.heads);
    let (seq_q, seq_k) = (shape.queries * width, shape.keys * width);
    assert_eq!(q.len(), shape.batch * seq_q, "query length");
    assert_eq!(out.len(), q.len(), "output length");
    assert_eq!(d_out.len(), q.len(), "output gradient length");
    assert_eq!(k.len(), shape.batch * seq_k, "key length");
    assert_eq!(v.len(), k.len(), "value length");
    assert_eq!(lse.len(), shape.batch * shape.queries * heads, "lse length");
    let scale = 1.0 / (d as f32).sqrt();
    let units: Vec<(usize, usize)> = (0..shape.batch).flat_map(|b| (0..heads).map(move |h| (b, h))).collect();
    let parts: Vec<HeadGradients> = units
        .par_iter()
        .map_init(BackwardScratch::default, |scratch, &(b, h)| {
            let col = h * d;
            let (q_seq, o_seq, do_seq) =
                (&q[b * seq_q..(b + 1) * seq_q], &out[b * seq_q..(b + 1) * seq_q], &d_out[b * seq_q..(b + 1) * seq_q]);
            let (k_seq, v_seq) = (&k[b * seq_k..(b + 1) * seq_k], &v[b * seq_k..(b + 1) * seq_k]);
            let mut g = HeadGradients {
                dq: vec![0.0; shape.queries * d],
                dk: vec![0.0; shape.keys * d],
                dv: vec![0.0; shape.keys * d],
            };
            for q0 in (0..shape.queries).step_by(QUERY_BLOCK) {
                let rows = QUERY_BLOCK.min(shape.queries - q0);
                // This block's queries and output gradients, head `h`'s columns (rows × d).
                let q_view =
                    MatRef { data: &q_seq[q0 * width + col..], rows, cols: d, row_stride: width, col_stride: 1 };
                let do_view =
                    MatRef { data: &do_seq[q0 * width + col..], rows, cols: d, row_stride: width, col_stride: 1 };
                // D_i = Σ_c dO_ic · O_ic, and the normalisers of the block's queries.
                scratch.delta.clear();
                scratch.delta.extend((0..rows).map(|i| {
                    let at = (q0 + i) * width + col;
                    do_seq[at..at + d].iter().zip(&o_seq[at..at + d]).map(|(a, b)| a * b).sum::<f32>()
                }));
                scratch.lse.clear();
                scratch.lse.extend((0..rows).map(|i| lse[(b * shape.queries + q0 + i) * heads + h]));
                for k0 in (0..shape.keys).step_by(KEY_BLOCK) {
                    let n = KEY_BLOCK.min(shape.keys - k0);
                    scratch.p.resize(rows * n, 0.0);
                    scratch.dp.resize(rows * n, 0.0);
                    let (p, dp) = (&mut scratch.p[..rows * n], &mut scratch.dp[..rows * n]);
                    let k_block = &k_seq[k0 * width + col..];
                    // p = exp(scale · Q·Kᵀ − lse).
                    gemm_f32(
                        MatMut { data: p, rows, cols: n, row_stride: n, col_stride: 1 },
                        q_view,
                        MatRef { data: k_block, rows: d, cols: n, row_stride: 1, col_stride: width },
                        false,
                        scale,
                    );
                    for (row, &shift) in p.chunks_exact_mut(n).zip(&scratch.lse) {
                        exp_shifted_sum(row, shift);
                    }
                    // dV_j (+)= pᵀ · dO_i.
                    gemm_f32(
                        MatMut { data: &mut g.dv[k0..], rows: n, cols: d, row_stride: 1, col_stride: shape.keys },
                        MatRef { data: p, rows: n, cols: rows, row_stride: 1, col_stride: n },
                        do_view,
                        q0 > 0,
                        1.0,
                    );
                    // dp = dO_i · V_jᵀ, then ds = p ∘ (dp − D) in place.
                    gemm_f32(
                        MatMut { data: dp, rows, cols: n, row_stride: n, col_stride: 1 },
                        do_view,
                        MatRef { data: &v_seq[k0 * width + col..], rows: d, cols: n, row_stride: 1, col_stride: width },
                        false,
                        1.0,
                    );
                    for ((ds_row, p_row), &delta) in dp.chunks_exact_mut(n).zip(p.chunks_exact(n)).zip(&scratch.delta) {
                        for (ds, &p) in ds_row.iter_mut().zip(p_row) {
                            *ds = p * (*ds - delta);
                        }
                    }
                    // dQ_i (+)= scale · ds · K_j.
                    gemm_f32(
                        MatMut { data: &mut g.dq[q0..], rows, cols: d, row_stride: 1, col_stride: shape.queries },
                        MatRef { data: dp, rows, cols: n, row_stride: n, col_stride: 1 },
                        MatRef { data: k_block, rows: n, cols: d, row_stride: width, col_stride: 1 },
                        k0 > 0,
                        scale,
                    );
                    // dK_j (+)= scale · dsᵀ · Q_i.
                    gemm_f32(
                        MatMut { data: &mut g.dk[k0..], rows: n, cols: d, row_stride: 1, col_stride: shape.keys },
                        MatRef { data: dp, rows: n, cols: rows, row_stride: 1, col_stride: n },
                        q_view,
                        q0 > 0,
                        scale,
                    );
                }
            }
            g
        })
        .collect();
    let mut dq = vec![0.0f32; q.len()];
    let mut dk = vec![0.0f32; k.len()];
    let mut dv = vec![0.0f32; v.len()];
    for (&(b, h), g) in units.iter().zip(&parts) {
        let col = h * d;
        scatter_head(&mut dq[b * seq_q..(b + 1) * seq_q], &g.dq, width, col, d);
        scatter_head(&mut dk[b * seq_k..(b + 1) * seq_k], &g.dk, width, col, d);
        scatter_head(&mut dv[b * seq_k..(b + 1) * seq_k], &g.dv, width, col, d);
    }
    (dq, dk, dv)
}

#[cfg(feature = "train")]
/// One (sequence, head) unit's gradients, `[head_dim, tokens]` each (column-major per token,
/// so that their GEMMs' rows are tokens, not the head's few channels).
struct HeadGradients {
    dq: Vec<f32>,
    dk: Vec<f32>,
    dv: Vec<f32>,
}

#[cfg(feature = "train")]
/// Per-thread buffers of one backward unit.
#[derive(Default)]
struct BackwardScratch {
    p: Vec<f32>,
    dp: Vec<f32>,
    delta: Vec<f32>,
    lse: Vec<f32>,
}

#[cfg(feature = "train")]
/// Copies a head's `[d, tokens]` values into columns `col..col + d` of a token-major sequence
/// of rows `width` wide.
fn scatter_head(seq: &mut [f32], head: &[f32], width: usize, col: usize, d: usize) {
    let tokens = seq.len() / width.max(1);
    for (c, values) in head.chunks_exact(tokens.max(1)).take(d).enumerate() {
        for (row, &v) in seq.chunks_exact_mut(width).zip(values) {
            row[col + c] = v;
        }
    }
}

/// Per-thread buffers of one work unit.
#[derive(Default)]
struct Scratch {
    scores: Vec<f32>,
    acc: Vec<f32>,
    row_max: Vec<f32>,
    row_sum: Vec<f32>,
}

/// One head of one block of `rows` queries: streams over the key blocks, keeping per query the
/// running maximum `m`, the running sum `l` of `exp(s − m)` and the unnormalised output (in
/// `out_rows`, the head's columns), rescaled by `exp(m_old − m_new)` whenever the maximum grows.
#[allow(clippy::too_many_arguments)]
fn query_block_head(
    q_rows: &[f32],
    k_seq: &[f32],
    v_seq: &[f32],
    out_rows: &mut [f32],
    head: usize,
    rows: usize,
    scale: f32,
    shape: AttentionShape,
    scratch: &mut Scratch,
) {
    let (width, d) = (shape.width(), shape.head_dim);
    let col = head * d;
    scratch.scores.resize(rows * KEY_BLOCK, 0.0);
    // The head's unnormalised output, column-major (`acc[c·rows + i]`): the GEMM's rows are
    // then the block's queries, not the head's few channels, so its kernels run full width.
    scratch.acc.clear();
    scratch.acc.resize(rows * d, 0.0);
    scratch.row_max.clear();
    scratch.row_max.resize(rows, f32::NEG_INFINITY);
    scratch.row_sum.clear();
    scratch.row_sum.resize(rows, 0.0);
    for k0 in (0..shape.keys).step_by(KEY_BLOCK) {
        let n = KEY_BLOCK.min(shape.keys - k0);
        let scores = &mut scratch.scores[..rows * n];
        // scores[rows × n] = scale · Q_h · K_hᵀ (K rows read with swapped strides).
        gemm_f32(
            MatMut { data: scores, rows, cols: n, row_stride: n, col_stride: 1 },
            MatRef { data: &q_rows[col..], rows, cols: d, row_stride: width, col_stride: 1 },
            MatRef { data: &k_seq[k0 * width + col..], rows: d, cols: n, row_stride: 1, col_stride: width },
            false,
            scale,
        );
        let first = k0 == 0;
        for (i, row) in scores.chunks_exact_mut(n).enumerate() {
            let block_max = max_of(row);
            let m_old = scratch.row_max[i];
            let m_new = m_old.max(block_max);
            let block_sum = exp_shifted_sum(row, m_new);
            if first {
                scratch.row_sum[i] = block_sum;
            } else {
                let correction = exp_scalar(m_old - m_new);
                scratch.row_sum[i] = scratch.row_sum[i] * correction + block_sum;
                if correction != 1.0 {
                    for o in scratch.acc[i..].iter_mut().step_by(rows) {
                        *o *= correction;
                    }
                }
            }
            scratch.row_max[i] = m_new;
        }
        // acc[rows × d] (+)= P[rows × n] · V_h[n × d].
        gemm_f32(
            MatMut { data: &mut scratch.acc, rows, cols: d, row_stride: 1, col_stride: rows },
            MatRef { data: scores, rows, cols: n, row_stride: n, col_stride: 1 },
            MatRef { data: &v_seq[k0 * width + col..], rows: n, cols: d, row_stride: width, col_stride: 1 },
            !first,
            1.0,
        );
    }
    for (i, &sum) in scratch.row_sum.iter().enumerate() {
        let inv = 1.0 / sum;
        for (o, &a) in
            out_rows[i * width + col..i * width + col + d].iter_mut().zip(scratch.acc[i..].iter().step_by(rows))
        {
            *o = a * inv;
        }
    }
}

/// Lanes of the reductions below: eight independent accumulators let the compiler keep one
/// SIMD register per reduction (a single scalar accumulator would serialise the loop).
const LANES: usize = 8;

/// The largest value of `row` (−∞ for an empty row).
fn max_of(row: &[f32]) -> f32 {
    let mut lanes = [f32::NEG_INFINITY; LANES];
    let mut chunks = row.chunks_exact(LANES);
    for chunk in &mut chunks {
        for (m, &x) in lanes.iter_mut().zip(chunk) {
            *m = if x > *m { x } else { *m };
        }
    }
    let tail = chunks.remainder().iter().fold(f32::NEG_INFINITY, |m, &x| m.max(x));
    lanes.iter().fold(tail, |m, &x| m.max(x))
}

/// Lanes of [`exp_shifted_sum`]'s sum: one AVX-512 register (the same lanes, and so the same
/// bits, whichever instructions the CPU has).
const EXP_LANES: usize = 16;

/// Replaces every `x` of `row` by `exp(x − shift)` and returns their sum; `shift` is at least
/// the row's maximum, so every argument is ≤ 0.
fn exp_shifted_sum(row: &mut [f32], shift: f32) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has the feature the function is compiled for (checked just above).
            #[allow(unsafe_code)]
            return unsafe { exp_shifted_sum_avx512(row, shift) };
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            // SAFETY: as above.
            #[allow(unsafe_code)]
            return unsafe { exp_shifted_sum_avx2(row, shift) };
        }
    }
    exp_shifted_sum_portable(row, shift)
}

/// [`exp_shifted_sum_portable`] compiled for AVX-512 (sixteen lanes per instruction).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn exp_shifted_sum_avx512(row: &mut [f32], shift: f32) -> f32 {
    exp_shifted_sum_portable(row, shift)
}

/// [`exp_shifted_sum_portable`] compiled for AVX2 + FMA (eight lanes per instruction).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn exp_shifted_sum_avx2(row: &mut [f32], shift: f32) -> f32 {
    exp_shifted_sum_portable(row, shift)
}

#[inline(always)]
fn exp_shifted_sum_portable(row: &mut [f32], shift: f32) -> f32 {
    let mut lanes = [0.0f32; EXP_LANES];
    let mut chunks = row.chunks_exact_mut(EXP_LANES);
    for chunk in &mut chunks {
        for (s, x) in lanes.iter_mut().zip(chunk.iter_mut()) {
            *x = exp_scalar(*x - shift);
            *s += *x;
        }
    }
    let mut sum = 0.0;
    for x in chunks.into_remainder() {
        *x = exp_scalar(*x - shift);
        sum += *x;
    }
    lanes.iter().sum::<f32>() + sum
}

/// `eˣ` for `x ≤ 0`, without branches, casts or library calls so that loops over it
/// vectorise: `x = n·ln2 + r` with `|r| ≤ ln2/2`, `eʳ` by a degree-6 polynomial (Cephes'
/// `expf` coefficients, relative error below 2e-7) and `2ⁿ` assembled in the exponent bits.
/// Arguments below −87.3 (where `eˣ` is no longer a normal f32) give about 1e-38 instead of a
/// subnormal: nothing next to the sum's own term of 1.
#[inline(always)]
pub(crate) fn exp_scalar(x: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding 1.5·2²³ rounds to the nearest integer n and leaves n in the low mantissa bits of
    // the sum (bits 0x4B40_0000 + n), from which 2ⁿ's exponent field n + 127 is read directly.
    const ROUND: f32 = 12_582_912.0;
    const ROUND_BITS: u32 = 0x4B40_0000;
    let x = x.max(-87.3);
    let t = x * LOG2_E + ROUND;
    let n = t - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.987_569_1e-4;
    let p = p * r + 1.398_2e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 1.666_666_5e-1;
    let p = p * r + 5e-1;
    let e = p * r * r + r + 1.0;
    let pow2 = f32::from_bits(t.to_bits().wrapping_sub(ROUND_BITS).wrapping_add(127) << 23);
    e * pow2
}
