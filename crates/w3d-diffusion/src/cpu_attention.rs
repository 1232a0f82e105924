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
    units.into_par_iter().zip(chunks).for_each_init(Scratch::default, |scratch, ((b, q0), out_rows)| {
        let rows = out_rows.len() / width;
        let q_rows = &q[b * seq_q + q0 * width..b * seq_q + (q0 + rows) * width];
        let k_seq = &k[b * seq_k..(b + 1) * seq_k];
        let v_seq = &v[b * seq_k..(b + 1) * seq_k];
        for h in 0..shape.heads {
            query_block_head(q_rows, k_seq, v_seq, out_rows, h, rows, scale, shape, scratch);
        }
    });
    out
}

/// Per-thread buffers of one work unit.
#[derive(Default)]
struct Scratch {
    scores: Vec<f32>,
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
                    for o in &mut out_rows[i * width + col..i * width + col + d] {
                        *o *= correction;
                    }
                }
            }
            scratch.row_max[i] = m_new;
        }
        // out_h[rows × d] (+)= P[rows × n] · V_h[n × d].
        gemm_f32(
            MatMut { data: &mut out_rows[col..], rows, cols: d, row_stride: width, col_stride: 1 },
            MatRef { data: scores, rows, cols: n, row_stride: n, col_stride: 1 },
            MatRef { data: &v_seq[k0 * width + col..], rows: n, cols: d, row_stride: width, col_stride: 1 },
            !first,
            1.0,
        );
    }
    for (i, &sum) in scratch.row_sum.iter().enumerate() {
        let inv = 1.0 / sum;
        for o in &mut out_rows[i * width + col..i * width + col + d] {
            *o *= inv;
        }
    }
}

/// A read-only strided matrix view: element `(r, c)` is `data[r·row_stride + c·col_stride]`.
struct MatRef<'a> {
    data: &'a [f32],
    rows: usize,
    cols: usize,
    row_stride: usize,
    col_stride: usize,
}

/// A writable strided matrix view, laid out as [`MatRef`].
struct MatMut<'a> {
    data: &'a mut [f32],
    rows: usize,
    cols: usize,
    row_stride: usize,
    col_stride: usize,
}

/// Index of the last element a strided view touches, `None` for an empty view.
fn last_index(rows: usize, cols: usize, row_stride: usize, col_stride: usize) -> Option<usize> {
    (rows > 0 && cols > 0).then(|| (rows - 1) * row_stride + (cols - 1) * col_stride)
}

/// `dst = beta·lhs·rhs` (or `dst += beta·lhs·rhs` with `accumulate`), single-threaded (the
/// caller parallelises over work units). A safe wrapper: the views' extents are checked
/// against their slices before the `gemm` crate reads or writes through raw pointers.
fn gemm_f32(dst: MatMut<'_>, lhs: MatRef<'_>, rhs: MatRef<'_>, accumulate: bool, beta: f32) {
    assert_eq!(lhs.rows, dst.rows, "gemm: lhs rows");
    assert_eq!(rhs.cols, dst.cols, "gemm: rhs cols");
    assert_eq!(lhs.cols, rhs.rows, "gemm: inner dimension");
    let Some(dst_last) = last_index(dst.rows, dst.cols, dst.row_stride, dst.col_stride) else { return };
    assert!(dst_last < dst.data.len(), "gemm: destination view out of bounds");
    if let Some(last) = last_index(lhs.rows, lhs.cols, lhs.row_stride, lhs.col_stride) {
        assert!(last < lhs.data.len(), "gemm: lhs view out of bounds");
    }
    if let Some(last) = last_index(rhs.rows, rhs.cols, rhs.row_stride, rhs.col_stride) {
        assert!(last < rhs.data.len(), "gemm: rhs view out of bounds");
    }
    let stride = |s: usize| isize::try_from(s).expect("gemm: stride fits isize");
    // SAFETY: every element the call reads or writes lies in its view (checked above against
    // the slices' lengths); `dst` is a unique borrow, so it aliases neither `lhs` nor `rhs`;
    // with an inner dimension of 0 and `accumulate` false the crate writes `dst` without
    // reading it.
    #[allow(unsafe_code)]
    unsafe {
        gemm::gemm(
            dst.rows,
            dst.cols,
            lhs.cols,
            dst.data.as_mut_ptr(),
            stride(dst.col_stride),
            stride(dst.row_stride),
            accumulate,
            lhs.data.as_ptr(),
            stride(lhs.col_stride),
            stride(lhs.row_stride),
            rhs.data.as_ptr(),
            stride(rhs.col_stride),
            stride(rhs.row_stride),
            1.0,
            beta,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
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

/// Replaces every `x` of `row` by `exp(x − shift)` and returns their sum; `shift` is at least
/// the row's maximum, so every argument is ≤ 0.
fn exp_shifted_sum(row: &mut [f32], shift: f32) -> f32 {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has the features the function is compiled for (checked just above).
        #[allow(unsafe_code)]
        return unsafe { exp_shifted_sum_avx2(row, shift) };
    }
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
    let mut lanes = [0.0f32; LANES];
    let mut chunks = row.chunks_exact_mut(LANES);
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
fn exp_scalar(x: f32) -> f32 {
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
