//! 2-D convolution (PyTorch `nn.Conv2d`): the backend's kernel, im2col + one GEMM, or in
//! training on flex the crate's differentiable kernel.

use burn::backend::DispatchDevice;
use burn::module::{Module, Param};
use burn::tensor::module::conv2d;
use burn::tensor::ops::{ConvOptions, PadMode};
use burn::tensor::{Tensor, s};

#[cfg(feature = "train")]
use crate::kernels::autodiff;
use crate::kernels::bf16;
use crate::kernels::dispatch::as_f32;
use crate::loading::weights::{Init, ParamSource};

/// How a 2-D convolution is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ConvAlgorithm {
    /// Per backend, from per-layer timings of the UNet's shapes (`docs/benchmarks.md`): on
    /// flex [`ConvAlgorithm::Im2col`] for stride-1 convolutions whose column buffer stays at
    /// most [`IM2COL_MAX_FLOATS`] values and [`ConvAlgorithm::Direct`] otherwise; on ndarray
    /// (whose own conv2d is several times slower) always im2col; on GPU backends the backend's
    /// conv2d. In training (autodiff) on flex, the crate's differentiable im2col kernel, whose
    /// gradients are one GEMM per image each; elsewhere in training the backend's conv2d.
    #[default]
    Auto,
    /// Patches gathered by slicing (im2col) and multiplied with one GEMM: 1.1-4.7x faster than
    /// the backend kernel on CPU at the UNet's 4x4-16x16 levels, 1.6x slower at 32x32 with
    /// 320+ channels (the column buffer outgrows the caches).
    Im2col,
    /// The backend's own `conv2d`, in f32 whatever [`crate::compute::Products`] the pass asks
    /// for.
    Direct,
}

/// Largest im2col column buffer (`n · c · k² · h_out · w_out` values) [`ConvAlgorithm::Auto`]
/// still uses im2col for.
pub const IM2COL_MAX_FLOATS: usize = 4 << 20;

/// A 2-D convolution with square kernel, stride and zero padding (PyTorch `nn.Conv2d`).
#[derive(Module, Debug)]
pub struct Conv2d {
    /// Weight, `[out, in, k, k]`.
    pub weight: Param<Tensor<4>>,
    /// Bias, `[out]`.
    pub bias: Option<Param<Tensor<1>>>,
    /// Stride in pixels.
    pub stride: usize,
    /// Zero padding on each side in pixels.
    pub padding: usize,
}

impl Conv2d {
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn load(
        p: &mut ParamSource,
        key: &str,
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
        padding: usize,
        bias: bool,
    ) -> Self {
        let fan_in = c_in * kernel * kernel;
        let weight = p.param(&format!("{key}.weight"), [c_out, c_in, kernel, kernel], Init::Uniform { fan_in });
        let bias = bias.then(|| p.param(&format!("{key}.bias"), [c_out], Init::Uniform { fan_in }));
        Self { weight, bias, stride, padding }
    }

    /// Applies the convolution with the default algorithm.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.forward_with(x, ConvAlgorithm::default())
    }

    /// Applies the convolution with the given algorithm (all give the same result up to f32
    /// rounding).
    ///
    /// At inference on the CPU, with [`crate::compute::Products::Bf16`] asked for by the pass
    /// and supported by the CPU, [`ConvAlgorithm::Auto`] and [`ConvAlgorithm::Im2col`] run
    /// as im2col + one product with bf16 factors and f32 sums, whatever the column matrix's
    /// size: it is built in bf16 straight from the image, a few hundred pixels at a time where
    /// the images are large, and the weight is rounded straight from the dtype it is held in.
    pub fn forward_with(&self, x: Tensor<4>, algorithm: ConvAlgorithm) -> Tensor<4> {
        let bias = self.bias.as_ref().map(|b| b.val());
        let weight = self.weight.val();
        if algorithm != ConvAlgorithm::Direct
            && bf16::applies(&x, &weight)
            && let Some(g) = bf16::conv_geometry(&x, &weight, self.stride, self.padding)
        {
            return bf16::conv2d_tensor(x, weight, bias, g);
        }
        let weight = as_f32(weight);
        let (s, p) = (self.stride, self.padding);
        let algorithm = match algorithm {
            ConvAlgorithm::Auto => {
                let [n, c, h, w] = x.dims();
                let [_, _, k, _] = weight.dims();
                let out = ((h + 2 * p).saturating_sub(k) / s + 1) * ((w + 2 * p).saturating_sub(k) / s + 1);
                match x.device().inner().as_dispatch() {
                    // Training on flex: the crate's differentiable im2col kernel, whose input
                    // gradient is one GEMM per image (`kernels::autodiff`).
                    #[cfg(feature = "train")]
                    DispatchDevice::Flex(_) if x.is_autodiff() => {
                        match autodiff::conv2d_applies(&x, &weight, bias.as_ref(), s, p) {
                            Some(strategy) => return autodiff::conv2d_op(x, weight, bias, s, p, strategy),
                            None => ConvAlgorithm::Direct,
                        }
                    }
                    // Training elsewhere: the backend's conv2d has a native backward (two
                    // convolutions); im2col by slicing would scatter each of the k² slices into
                    // a zeroed copy of the input, several times slower.
                    _ if x.is_autodiff() => ConvAlgorithm::Direct,
                    #[cfg(feature = "ndarray")]
                    DispatchDevice::NdArray(_) => ConvAlgorithm::Im2col,
                    DispatchDevice::Flex(_) if s == 1 && n * c * k * k * out <= IM2COL_MAX_FLOATS => {
                        ConvAlgorithm::Im2col
                    }
                    _ => ConvAlgorithm::Direct,
                }
            }
            other => other,
        };
        match algorithm {
            ConvAlgorithm::Auto | ConvAlgorithm::Direct => {
                conv2d(x, weight, bias, ConvOptions::new([s, s], [p, p], [1, 1], 1))
            }
            ConvAlgorithm::Im2col => im2col_conv2d(x, weight, bias, s, p),
        }
    }
}

/// Convolution as im2col + one GEMM: `x [n, c, h, w]`, `weight [o, c, k, k]`.
pub fn im2col_conv2d(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    stride: usize,
    padding: usize,
) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let [o, _, k, _] = weight.dims();
    let ho = (h + 2 * padding - k) / stride + 1;
    let wo = (w + 2 * padding - k) / stride + 1;
    let w2 = weight.reshape([1, o, c * k * k]);
    let cols = if k == 1 && stride == 1 && padding == 0 {
        x.reshape([n, c, h * w])
    } else {
        let xp = if padding > 0 { x.pad((padding, padding, padding, padding), PadMode::Constant(0.0)) } else { x };
        let mut patches = Vec::with_capacity(k * k);
        for ky in 0..k {
            for kx in 0..k {
                let (y1, x1) = (ky + stride * (ho - 1) + 1, kx + stride * (wo - 1) + 1);
                let step = stride as isize;
                patches.push(xp.clone().slice(s![.., .., ky..y1;step, kx..x1;step]));
            }
        }
        let cols: Tensor<5> = Tensor::stack(patches, 2);
        cols.reshape([n, c * k * k, ho * wo])
    };
    let mut y = w2.matmul(cols);
    if let Some(b) = bias {
        y = y + b.reshape([1, o, 1]);
    }
    y.reshape([n, o, ho, wo])
}
