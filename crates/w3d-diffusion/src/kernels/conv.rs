//! 2-D convolution and its gradients on the CPU, on plain `f32` slices: im2col + one GEMM per
//! image, the kernel [`crate::nn::Conv2d`] runs in training on Burn's flex backend.
//!
//! Why a kernel of our own: differentiating Burn's `conv2d` on flex computes the input's
//! gradient as a transposed convolution, whose flex kernel was the largest single cost of a
//! training step of the small UNet (`docs/benchmarks.md`, "Training step"). Here the forward,
//! the input gradient and the weight gradient are each one GEMM per image against the image's
//! column matrix (rebuilt in the backward rather than stored), and images are the work units.
//!
//! Layouts are PyTorch's: images `[n, c, h, w]`, weights `[o, c, k, k]`, all row-major.

use rayon::prelude::*;

use crate::kernels::conv_shape::ConvShape;
use crate::kernels::gemm::{MatMut, MatRef, gemm_f32};

/// `x` convolved with `weight` plus `bias`: `[n, o, ho, wo]`.
///
/// # Panics
/// If a slice's length does not match `shape` or the kernel does not fit (the caller checks).
pub(crate) fn conv2d(x: &[f32], weight: &[f32], bias: Option<&[f32]>, shape: ConvShape) -> Vec<f32> {
    check(x, weight, shape);
    let (patch, pixels) = (shape.patch(), shape.out_pixels());
    let image = shape.c_in * shape.height * shape.width;
    let mut out = vec![0.0f32; shape.batch * shape.c_out * pixels];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(shape.c_out * pixels).enumerate().for_each_init(Vec::new, |cols, (n, y)| {
        let x_n = &x[n * image..(n + 1) * image];
        let cols = columns(x_n, shape, cols);
        gemm_f32(
            MatMut { data: y, rows: shape.c_out, cols: pixels, row_stride: pixels, col_stride: 1 },
            MatRef { data: weight, rows: shape.c_out, cols: patch, row_stride: patch, col_stride: 1 },
            MatRef { data: cols, rows: patch, cols: pixels, row_stride: pixels, col_stride: 1 },
            false,
            1.0,
        );
        if let Some(bias) = bias {
            for (row, &b) in y.chunks_exact_mut(pixels).zip(bias) {
                row.iter_mut().for_each(|v| *v += b);
            }
        }
    });
    out
}

/// Gradients of [`conv2d`] given the output's gradient `d_out` (`[n, o, ho, wo]`): of the input
/// (`[n, c, h, w]`), the weight (`[o, c, k, k]`) and the bias (`[o]`), each only when asked.
///
/// # Panics
/// As [`conv2d`].
pub(crate) fn conv2d_backward(
    x: &[f32],
    weight: &[f32],
    d_out: &[f32],
    shape: ConvShape,
    want: [bool; 3],
) -> [Option<Vec<f32>>; 3] {
    check(x, weight, shape);
    let (patch, pixels) = (shape.patch(), shape.out_pixels());
    let image = shape.c_in * shape.height * shape.width;
    let out_image = shape.c_out * pixels;
    assert_eq!(d_out.len(), shape.batch * out_image, "output gradient length");
    let [want_x, want_w, want_b] = want;
    // Per image: the input gradient (written in place) and a partial weight gradient.
    let mut dx = want_x.then(|| vec![0.0f32; x.len()]);
    let mut dx_chunks: Vec<Option<&mut [f32]>> = match dx.as_mut() {
        Some(dx) => dx.chunks_mut(image.max(1)).map(Some).collect(),
        None => (0..shape.batch).map(|_| None).collect(),
    };
    dx_chunks.resize_with(shape.batch, || None);
    let partial_dw: Vec<Vec<f32>> = dx_chunks
        .into_par_iter()
        .enumerate()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(cols, d_cols), (n, dx_n)| {
                let dy_n = MatRef {
                    data: &d_out[n * out_image..(n + 1) * out_image],
                    rows: shape.c_out,
                    cols: pixels,
                    row_stride: pixels,
                    col_stride: 1,
                };
                let mut dw = Vec::new();
                if want_w {
                    // dW (c_out × patch) = dY_n · colsᵀ.
                    let cols = columns(&x[n * image..(n + 1) * image], shape, cols);
                    dw = vec![0.0f32; shape.c_out * patch];
                    gemm_f32(
                        MatMut { data: &mut dw, rows: shape.c_out, cols: patch, row_stride: patch, col_stride: 1 },
                        dy_n,
                        MatRef { data: cols, rows: pixels, cols: patch, row_stride: 1, col_stride: pixels },
                        false,
                        1.0,
                    );
                }
                if let Some(dx_n) = dx_n {
                    // d_cols (patch × pixels) = Wᵀ · dY_n, then scattered back onto the image.
                    let w_t = MatRef { data: weight, rows: patch, cols: shape.c_out, row_stride: 1, col_stride: patch };
                    if shape.pointwise() {
                        gemm_f32(
                            MatMut { data: dx_n, rows: patch, cols: pixels, row_stride: pixels, col_stride: 1 },
                            w_t,
                            dy_n,
                            false,
                            1.0,
                        );
                    } else {
                        // Written whole by the GEMM (no accumulation), so not cleared.
                        d_cols.resize(patch * pixels, 0.0);
                        gemm_f32(
                            MatMut { data: d_cols, rows: patch, cols: pixels, row_stride: pixels, col_stride: 1 },
                            w_t,
                            dy_n,
                            false,
                            1.0,
                        );
                        scatter_columns(d_cols, dx_n, shape);
                    }
                }
                dw
            },
        )
        .collect();
    // Each value summed in image order, not reduced per thread: the sum, and so training,
    // stays bit-for-bit reproducible (a resumed run repeats the uninterrupted one exactly).
    // The values are shared between the cores; the order of each one's sum is fixed.
    let dw = want_w.then(|| {
        let mut sum = vec![0.0f32; shape.c_out * patch];
        sum.par_chunks_mut(SUM_CHUNK).enumerate().for_each(|(i, sum)| {
            for part in &partial_dw {
                sum.iter_mut().zip(&part[i * SUM_CHUNK..]).for_each(|(s, p)| *s += p);
            }
        });
        sum
    });
    let db = want_b.then(|| {
        let mut sum = vec![0.0f32; shape.c_out];
        sum.par_iter_mut().enumerate().for_each(|(o, s)| {
            for dy_n in d_out.chunks_exact(out_image.max(1)) {
                *s += dy_n[o * pixels..(o + 1) * pixels].iter().sum::<f32>();
            }
        });
        sum
    });
    [dx, dw, db]
}

/// Weight-gradient values one parallel task sums over the images.
const SUM_CHUNK: usize = 1 << 14;

fn check(x: &[f32], weight: &[f32], shape: ConvShape) {
    assert!(shape.output().is_some(), "convolution kernel larger than the padded image");
    assert_eq!(x.len(), shape.batch * shape.c_in * shape.height * shape.width, "input length");
    assert_eq!(weight.len(), shape.c_out * shape.patch(), "weight length");
}

/// The column matrix of one image (`[c·k², ho·wo]`, row `(c·k + ky)·k + kx` holding the input
/// pixel each output pixel's kernel tap `(ky, kx)` reads, 0 in the padding); the image itself
/// for a pointwise convolution, else built in `buffer`.
fn columns<'a>(x_n: &'a [f32], shape: ConvShape, buffer: &'a mut Vec<f32>) -> &'a [f32] {
    if shape.pointwise() {
        return x_n;
    }
    let (ho, wo) = shape.output().expect("checked");
    let (k, h, w) = (shape.kernel, shape.height, shape.width);
    if let Some(taps) = SameSizeTaps::of(shape) {
        // Every entry is written below, so the buffer's old values need no clearing.
        buffer.resize(shape.patch() * ho * wo, 0.0);
        for (row, cols) in buffer.chunks_exact_mut(h * w).enumerate() {
            let c = row / (k * k);
            let tap = taps.tap(row % (k * k));
            let plane = &x_n[c * h * w..(c + 1) * h * w];
            cols[..tap.dst.start].fill(0.0);
            cols[tap.dst.clone()].copy_from_slice(&plane[tap.src.clone()]);
            cols[tap.dst.end..].fill(0.0);
            tap.clear_wrapped(cols, w);
        }
        return buffer;
    }
    buffer.clear();
    buffer.resize(shape.patch() * ho * wo, 0.0);
    for (row, cols) in buffer.chunks_exact_mut(ho * wo).enumerate() {
        let (c, ky, kx) = (row / (k * k), row / k % k, row % k);
        let plane = &x_n[c * h * w..(c + 1) * h * w];
        let (ox_range, ix0) = tap_columns(kx, w, wo, shape);
        for (oy, out_row) in cols.chunks_exact_mut(wo).enumerate() {
            let Some(iy) = tap_source(oy, ky, h, shape) else { continue };
            let line = &plane[iy * w..(iy + 1) * w];
            let out = &mut out_row[ox_range.clone()];
            if shape.stride == 1 {
                out.copy_from_slice(&line[ix0..ix0 + out.len()]);
            } else {
                for (v, &x) in out.iter_mut().zip(line[ix0..].iter().step_by(shape.stride)) {
                    *v = x;
                }
            }
        }
    }
    buffer
}

/// The adjoint of [`columns`]: adds each column-matrix entry onto the input pixel it was read
/// from.
fn scatter_columns(d_cols: &mut [f32], dx_n: &mut [f32], shape: ConvShape) {
    let (ho, wo) = shape.output().expect("checked");
    let (k, h, w) = (shape.kernel, shape.height, shape.width);
    if let Some(taps) = SameSizeTaps::of(shape) {
        // Each tap's entries in the order the general loop below adds them, so the sums are
        // the same bits; the wrapped entries are cleared first so that they add nothing.
        for (row, cols) in d_cols.chunks_exact_mut(h * w).enumerate() {
            let c = row / (k * k);
            let tap = taps.tap(row % (k * k));
            tap.clear_wrapped(cols, w);
            let plane = &mut dx_n[c * h * w..(c + 1) * h * w];
            for (x, &v) in plane[tap.src.clone()].iter_mut().zip(&cols[tap.dst.clone()]) {
                *x += v;
            }
        }
        return;
    }
    for (row, cols) in d_cols.chunks_exact(ho * wo).enumerate() {
        let (c, ky, kx) = (row / (k * k), row / k % k, row % k);
        let plane = &mut dx_n[c * h * w..(c + 1) * h * w];
        let (ox_range, ix0) = tap_columns(kx, w, wo, shape);
        for (oy, out_row) in cols.chunks_exact(wo).enumerate() {
            let Some(iy) = tap_source(oy, ky, h, shape) else { continue };
            let line = &mut plane[iy * w..(iy + 1) * w];
            let values = &out_row[ox_range.clone()];
            if shape.stride == 1 {
                // Contiguous on both sides: vectorised (a `step_by(1)` iterator is not).
                for (x, &v) in line[ix0..ix0 + values.len()].iter_mut().zip(values) {
                    *x += v;
                }
            } else {
                for (x, &v) in line[ix0..].iter_mut().step_by(shape.stride).zip(values) {
                    *x += v;
                }
            }
        }
    }
}

/// The kernel taps of a stride-1 convolution whose output has the input's size (a 3×3 kernel
/// with padding 1): each tap's column-matrix row is the input plane shifted by a fixed offset,
/// so it is one contiguous copy, with the entries whose horizontal shift wrapped round to the
/// neighbouring image row cleared after. At the UNet's small levels (8×8 pixels) copying row by
/// row cost a library call per eight values.
struct SameSizeTaps {
    kernel: usize,
    padding: usize,
    height: usize,
    width: usize,
}

/// One tap of [`SameSizeTaps`]: column-matrix entries `dst` read input pixels `src` (a range of
/// the same length, in flattened `h·w` order); the others read the zero padding.
struct Tap {
    dst: std::ops::Range<usize>,
    src: std::ops::Range<usize>,
    /// Horizontal offset of the tap in pixels (`kx − padding`).
    dx: isize,
}

impl SameSizeTaps {
    fn of(shape: ConvShape) -> Option<Self> {
        let same = shape.stride == 1 && shape.kernel == 2 * shape.padding + 1 && shape.kernel > 1;
        same.then_some(Self { kernel: shape.kernel, padding: shape.padding, height: shape.height, width: shape.width })
    }

    /// Tap `t = ky·k + kx`.
    fn tap(&self, t: usize) -> Tap {
        let (ky, kx) = (t / self.kernel, t % self.kernel);
        let p = self.padding as isize;
        let (dy, dx) = (ky as isize - p, kx as isize - p);
        let n = self.height * self.width;
        let shift = dy * self.width as isize + dx;
        // An image smaller than the kernel's reach leaves a tap nothing but padding.
        let offset = shift.unsigned_abs().min(n);
        let len = n - offset;
        let (dst0, src0) = if shift >= 0 { (0, offset) } else { (offset, 0) };
        Tap { dst: dst0..dst0 + len, src: src0..src0 + len, dx }
    }
}

impl Tap {
    /// Zeroes the entries of `cols` (one tap's row, `w` wide image rows) whose source pixel lies
    /// beyond the left or right edge: the flat shift took them from the neighbouring row.
    fn clear_wrapped(&self, cols: &mut [f32], w: usize) {
        let edge = self.dx.unsigned_abs().min(w);
        if edge == 0 {
            return;
        }
        for row in cols.chunks_exact_mut(w) {
            let wrapped = if self.dx < 0 { &mut row[..edge] } else { &mut row[w - edge..] };
            wrapped.fill(0.0);
        }
    }
}

/// The input row kernel row `ky` of output row `oy` reads, `None` in the padding.
fn tap_source(oy: usize, ky: usize, h: usize, shape: ConvShape) -> Option<usize> {
    (oy * shape.stride + ky).checked_sub(shape.padding).filter(|&iy| iy < h)
}

/// For kernel column `kx`: the output columns whose tap lies inside the image (a range, as
/// `ix = ox·s + kx − p` grows with `ox`) and the input column the first of them reads.
fn tap_columns(kx: usize, w: usize, wo: usize, shape: ConvShape) -> (std::ops::Range<usize>, usize) {
    let (s, p) = (shape.stride, shape.padding);
    // First ox with ox·s + kx ≥ p; then all ox with ox·s + kx − p < w.
    let first = p.saturating_sub(kx).div_ceil(s);
    let end = (w + p).saturating_sub(kx).div_ceil(s).min(wo);
    if first >= end {
        return (0..0, 0);
    }
    (first..end, first * s + kx - p)
}
