//! The GEGLU gate of the transformer blocks' feed-forward, `hidden · gelu(gate)` with
//! `[hidden, gate]` the two halves of each row of the projection, and its gradient, on plain
//! `f32` slices, on all cores.
//!
//! Why a kernel of our own: written with tensor operations the gate is a slice, the exact GELU
//! (itself five element-wise operations on a GPU backend, one on flex) and a product, and its
//! gradient a product, GELU's own backward and a slice assignment into zeros, each a pass over
//! the activations; on flex the passes below 256 K values run on one core, which was about a
//! quarter of the serial time of the small model's training step (`docs/benchmarks.md`,
//! "Training step"). Here the forward is one pass and the backward one.
//!
//! The arithmetic is Burn flex's, operation for operation (`0.5·x·(1 + erf(x/√2))` with
//! `libm`'s `erff`, and the derivative `cdf + x·pdf` with `pdf = e^{−x²/2}/√(2π)`), so the
//! results are bit-identical to the tensor-operation path (`tests/parity_cases/geglu.rs`).

use rayon::prelude::*;

/// Rows handed to one parallel task: small enough to share the work of a 16×16 latent's
/// projection between two cores, large enough that the scheduling is negligible.
const ROWS_PER_TASK: usize = 64;

/// `erf(x/√2)`, with the error function Burn flex's GELU uses.
#[inline]
fn erf_scaled(x: f32) -> f32 {
    libm::erff(x / core::f32::consts::SQRT_2)
}

/// `gelu(x)`, exact (error-function) form, from `erf = erf_scaled(x)`, as Burn flex computes it.
#[inline]
fn gelu(x: f32, erf: f32) -> f32 {
    0.5 * x * (1.0 + erf)
}

#[cfg(feature = "train")]
/// `d gelu(x) / dx` from `erf = erf_scaled(x)`, as Burn flex's `gelu_backward` computes it.
#[inline]
fn gelu_derivative(x: f32, erf: f32) -> f32 {
    let inv_sqrt_2pi: f32 = 1.0 / (2.0 * core::f32::consts::PI).sqrt();
    let cdf = 0.5 * (1.0 + erf);
    let pdf = inv_sqrt_2pi * (-0.5 * x * x).exp();
    cdf + x * pdf
}

/// The gate of every row of `projection` (rows of `2·inner` values: `inner` hidden values,
/// then `inner` gate values): rows of `inner` values `hidden · gelu(gate)`.
pub(crate) fn geglu(projection: &[f32], inner: usize) -> Vec<f32> {
    assert!(inner > 0 && projection.len().is_multiple_of(2 * inner), "rows of 2·inner values");
    let rows = projection.len() / (2 * inner);
    let mut out = vec![0.0f32; rows * inner];
    out.par_chunks_mut(ROWS_PER_TASK * inner).zip(projection.par_chunks(ROWS_PER_TASK * 2 * inner)).for_each(
        |(out, projection)| {
            for (out, row) in out.chunks_exact_mut(inner).zip(projection.chunks_exact(2 * inner)) {
                let (hidden, gate) = row.split_at(inner);
                for ((o, &h), &g) in out.iter_mut().zip(hidden).zip(gate) {
                    *o = h * gelu(g, erf_scaled(g));
                }
            }
        },
    );
    out
}

#[cfg(feature = "train")]
/// The gradient of [`geglu`] with respect to `projection`, given the gradient `d_out` of its
/// output: per row, `d_out · gelu(gate)` for the hidden half and `d_out · hidden · gelu′(gate)`
/// for the gate half.
pub(crate) fn geglu_backward(projection: &[f32], d_out: &[f32], inner: usize) -> Vec<f32> {
    assert!(inner > 0 && projection.len().is_multiple_of(2 * inner), "rows of 2·inner values");
    assert_eq!(d_out.len() * 2, projection.len(), "output gradient length");
    let mut d_projection = vec![0.0f32; projection.len()];
    d_projection
        .par_chunks_mut(ROWS_PER_TASK * 2 * inner)
        .zip(projection.par_chunks(ROWS_PER_TASK * 2 * inner))
        .zip(d_out.par_chunks(ROWS_PER_TASK * inner))
        .for_each(|((d_projection, projection), d_out)| {
            let rows = d_projection.chunks_exact_mut(2 * inner).zip(projection.chunks_exact(2 * inner));
            for ((d_row, row), d_out) in rows.zip(d_out.chunks_exact(inner)) {
                let (hidden, gate) = row.split_at(inner);
                let (d_hidden, d_gate) = d_row.split_at_mut(inner);
                for i in 0..inner {
                    let (h, g, dy) = (hidden[i], gate[i], d_out[i]);
                    // One error function for both halves (Burn evaluates it twice).
                    let erf = erf_scaled(g);
                    d_hidden[i] = dy * gelu(g, erf);
                    d_gate[i] = (dy * h) * gelu_derivative(g, erf);
                }
            }
        });
    d_projection
}
