//! A fully connected layer and its gradients on the CPU, on plain `f32` slices: the kernel
//! [`crate::nn::Linear`] runs in training on Burn's flex backend.
//!
//! Why a kernel of our own: flex multiplies the transformer blocks' token matrices (a few
//! hundred rows at the small UNet's 8×8 level) on the calling thread, and differentiates the
//! product through transposed copies and two more such products, so the layers' forward and
//! backward ran on one core while the other waited: about a third of that serial time of a
//! training step of the small UNet (`docs/benchmarks.md`, "Training step"). Here each product
//! is split over the cores: the forward and the input's gradient by blocks of rows, the
//! weight's gradient by blocks of its output columns (each written whole by one task, so the
//! sums need no reduction and stay reproducible).
//!
//! Layouts: inputs `[rows, in]`, the weight as the layer holds it, `[in, out]`, outputs
//! `[rows, out]`, all row-major.

use rayon::prelude::*;

use crate::kernels::gemm::{MatMut, MatRef, gemm_f32};

/// Rows of the input (and output) one parallel task multiplies.
const ROWS_PER_TASK: usize = 64;
/// Output columns of the weight's gradient one parallel task computes.
const COLUMNS_PER_TASK: usize = 32;

/// Shape of a fully connected layer applied to `rows` rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct LinearShape {
    /// Rows (tokens of all sequences).
    pub rows: usize,
    /// Input features.
    pub d_in: usize,
    /// Output features.
    pub d_out: usize,
}

/// `x·W + b`: `[rows, out]`.
///
/// # Panics
/// If a slice's length does not match `shape` (the caller checks).
pub(crate) fn linear(x: &[f32], weight: &[f32], bias: Option<&[f32]>, shape: LinearShape) -> Vec<f32> {
    check(x, weight, bias, shape);
    let LinearShape { d_in, d_out, .. } = shape;
    let mut out = vec![0.0f32; shape.rows * d_out];
    if out.is_empty() {
        return out;
    }
    if d_in == 0 {
        // No input features: every row is the bias.
        if let Some(bias) = bias {
            out.chunks_exact_mut(d_out).for_each(|row| row.copy_from_slice(bias));
        }
        return out;
    }
    out.par_chunks_mut(ROWS_PER_TASK * d_out).zip(x.par_chunks(ROWS_PER_TASK * d_in)).for_each(|(y, x)| {
        let rows = y.len() / d_out;
        gemm_f32(
            MatMut { data: y, rows, cols: d_out, row_stride: d_out, col_stride: 1 },
            MatRef { data: x, rows, cols: d_in, row_stride: d_in, col_stride: 1 },
            MatRef { data: weight, rows: d_in, cols: d_out, row_stride: d_out, col_stride: 1 },
            false,
            1.0,
        );
        if let Some(bias) = bias {
            for row in y.chunks_exact_mut(d_out) {
                row.iter_mut().zip(bias).for_each(|(v, &b)| *v += b);
            }
        }
    });
    out
}

/// Gradients of [`linear`] given the output's gradient `d_out` (`[rows, out]`): of the input
/// (`[rows, in]`), the weight (`[in, out]`) and the bias (`[out]`), each only when asked.
///
/// # Panics
/// As [`linear`].
pub(crate) fn linear_backward(
    x: &[f32],
    weight: &[f32],
    d_out: &[f32],
    shape: LinearShape,
    want: [bool; 3],
) -> [Option<Vec<f32>>; 3] {
    check(x, weight, None, shape);
    let LinearShape { rows, d_in, d_out: n_out } = shape;
    assert_eq!(d_out.len(), rows * n_out, "output gradient length");
    let [want_x, want_w, want_b] = want;
    let dx = want_x.then(|| {
        let mut dx = vec![0.0f32; rows * d_in];
        if !dx.is_empty() {
            dx.par_chunks_mut(ROWS_PER_TASK * d_in).zip(d_out.par_chunks(ROWS_PER_TASK * n_out.max(1))).for_each(
                |(dx, dy)| {
                    let r = dx.len() / d_in;
                    // dX = dY · Wᵀ.
                    gemm_f32(
                        MatMut { data: dx, rows: r, cols: d_in, row_stride: d_in, col_stride: 1 },
                        MatRef { data: dy, rows: r, cols: n_out, row_stride: n_out, col_stride: 1 },
                        MatRef { data: weight, rows: n_out, cols: d_in, row_stride: 1, col_stride: n_out },
                        false,
                        1.0,
                    );
                },
            );
        }
        dx
    });
    // Column blocks of the weight's gradient (and of the bias's): task `j` owns output columns
    // `j·COLUMNS_PER_TASK..`, so both are written by strided views into one buffer each.
    let blocks = n_out.div_ceil(COLUMNS_PER_TASK);
    let dw = want_w.then(|| {
        let mut dw = vec![0.0f32; d_in * n_out];
        if !dw.is_empty() {
            let parts: Vec<(usize, Vec<f32>)> = (0..blocks)
                .into_par_iter()
                .map(|j| {
                    let c0 = j * COLUMNS_PER_TASK;
                    let cols = COLUMNS_PER_TASK.min(n_out - c0);
                    let mut part = vec![0.0f32; d_in * cols];
                    // dW[:, c0..c0 + cols] = Xᵀ · dY[:, c0..c0 + cols].
                    gemm_f32(
                        MatMut { data: &mut part, rows: d_in, cols, row_stride: cols, col_stride: 1 },
                        MatRef { data: x, rows: d_in, cols: rows, row_stride: 1, col_stride: d_in },
                        MatRef { data: &d_out[c0..], rows, cols, row_stride: n_out, col_stride: 1 },
                        false,
                        1.0,
                    );
                    (c0, part)
                })
                .collect();
            for (c0, part) in parts {
                let cols = part.len() / d_in.max(1);
                for (row, values) in dw.chunks_exact_mut(n_out).zip(part.chunks_exact(cols.max(1))) {
                    row[c0..c0 + cols].copy_from_slice(values);
                }
            }
        }
        dw
    });
    let db = want_b.then(|| {
        let mut db = vec![0.0f32; n_out];
        db.par_chunks_mut(COLUMNS_PER_TASK).enumerate().for_each(|(j, sums)| {
            let c0 = j * COLUMNS_PER_TASK;
            for row in d_out.chunks_exact(n_out) {
                sums.iter_mut().zip(&row[c0..]).for_each(|(s, &v)| *s += v);
            }
        });
        db
    });
    [dx, dw, db]
}

fn check(x: &[f32], weight: &[f32], bias: Option<&[f32]>, shape: LinearShape) {
    assert_eq!(x.len(), shape.rows * shape.d_in, "input length");
    assert_eq!(weight.len(), shape.d_in * shape.d_out, "weight length");
    if let Some(bias) = bias {
        assert_eq!(bias.len(), shape.d_out, "bias length");
    }
}
