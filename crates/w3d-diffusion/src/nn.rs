//! Building blocks shared by the UNet, the VAE and the CLIP encoder: linear layers, 2-D
//! convolutions (im2col + GEMM), GroupNorm, LayerNorm and multi-head attention.
//!
//! Images are `[batch, channels, height, width]`; token sequences are `[batch, tokens, width]`.

use burn::backend::DispatchDevice;
use burn::module::{Module, Param};
use burn::tensor::activation::{gelu, silu};
use burn::tensor::module::{attention, conv2d, layer_norm};
use burn::tensor::ops::{AttentionModuleOptions, ConvOptions, PadMode};
use burn::tensor::{DType, FloatDType, Tensor, TensorData, s};

use crate::flex_autodiff;
use crate::weights::{Init, ParamSource};

/// A fully connected layer `y = x·Wᵀ + b`; the weight is held transposed (`[in, out]`).
#[derive(Module, Debug)]
pub struct Linear {
    /// Weight, `[in, out]` (the transpose of the PyTorch `[out, in]` layout).
    pub weight: Param<Tensor<2>>,
    /// Bias, `[out]`.
    pub bias: Option<Param<Tensor<1>>>,
}

impl Linear {
    pub(crate) fn load(p: &mut ParamSource, key: &str, d_in: usize, d_out: usize, bias: bool) -> Self {
        Self::load_init(p, key, d_in, d_out, bias, Init::Uniform { fan_in: d_in })
    }

    /// As `load`, with `weight_init` for the weight of a randomly initialised model (the bias
    /// keeps PyTorch's default).
    pub(crate) fn load_init(
        p: &mut ParamSource,
        key: &str,
        d_in: usize,
        d_out: usize,
        bias: bool,
        weight_init: Init,
    ) -> Self {
        let weight = p.transposed_weight(&format!("{key}.weight"), d_out, &[d_in], weight_init);
        let bias = bias.then(|| p.param(&format!("{key}.bias"), [d_out], Init::Uniform { fan_in: d_in }));
        Self { weight, bias }
    }

    /// Applies the layer to the last dimension of `x`.
    pub fn forward<const D: usize>(&self, x: Tensor<D>) -> Tensor<D> {
        let dims = x.dims();
        let [d_in, d_out] = self.weight.dims();
        let rows = dims[..D - 1].iter().product();
        let (x, weight) = (x.reshape([rows, d_in]), as_f32(self.weight.val()));
        let bias = self.bias.as_ref().map(|b| b.val());
        let y = match crate::flex_autodiff::linear_applies(&x, &weight, bias.as_ref()) {
            // Training on the CPU: one differentiable node (`crate::cpu_linear`).
            Some(strategy) => crate::flex_autodiff::linear_op(x, weight, bias, strategy),
            None => {
                let y = x.matmul(weight);
                match bias {
                    Some(b) => y + b.unsqueeze::<2>(),
                    None => y,
                }
            }
        };
        let mut out = dims;
        out[D - 1] = d_out;
        y.reshape(out)
    }
}

/// `t` in f32: weights held in half precision ([`crate::WeightStorage::F16`]) are widened
/// where they are used, one layer at a time, so the arithmetic is f32 whatever the storage.
fn as_f32<const D: usize>(t: Tensor<D>) -> Tensor<D> {
    if t.dtype() == DType::F32 {
        return t;
    }
    widen_f16_on_cpu(&t).unwrap_or_else(|| t.cast(FloatDType::F32))
}

/// Values converted per parallel task by [`widen_f16_on_cpu`].
const WIDEN_CHUNK: usize = 1 << 16;

/// An f16 tensor on a CPU backend widened to f32 with the `half` crate's vectorised slice
/// conversion (F16C where the CPU has it), on all cores; `None` for other dtypes, devices or an
/// autodiff graph. Burn's `cast` on flex converts one element at a time on one core, which
/// cost several seconds of every real-size guided step with f16 weights (`docs/benchmarks.md`).
fn widen_f16_on_cpu<const D: usize>(t: &Tensor<D>) -> Option<Tensor<D>> {
    use half::slice::HalfFloatSliceExt;
    use rayon::prelude::*;
    if t.dtype() != DType::F16 || t.is_autodiff() || !on_cpu_backend(&t.device()) {
        return None;
    }
    let data = t.clone().into_data();
    let narrow = data.as_slice::<half::f16>().ok()?;
    let mut wide = vec![0.0f32; narrow.len()];
    wide.par_chunks_mut(WIDEN_CHUNK)
        .zip(narrow.par_chunks(WIDEN_CHUNK))
        .for_each(|(wide, narrow)| narrow.convert_to_f32_slice(wide));
    Some(Tensor::from_data(TensorData::new(wide, t.shape()), &t.device()))
}

/// Whether `device` is Burn's flex backend (with or without autodiff).
pub(crate) fn on_flex(device: &burn::tensor::Device) -> bool {
    matches!(device.clone().inner().as_dispatch(), DispatchDevice::Flex(_))
}

/// Whether `device` belongs to one of Burn's CPU backends (flex; ndarray with the feature),
/// where the crate's own CPU kernels may run on the tensors' memory.
fn on_cpu_backend(device: &burn::tensor::Device) -> bool {
    match device.clone().inner().as_dispatch() {
        DispatchDevice::Flex(_) => true,
        #[cfg(feature = "ndarray")]
        DispatchDevice::NdArray(_) => true,
        _ => false,
    }
}

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
    /// The backend's own `conv2d`.
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
    pub fn forward_with(&self, x: Tensor<4>, algorithm: ConvAlgorithm) -> Tensor<4> {
        let bias = self.bias.as_ref().map(|b| b.val());
        let weight = as_f32(self.weight.val());
        let (s, p) = (self.stride, self.padding);
        let algorithm = match algorithm {
            ConvAlgorithm::Auto => {
                let [n, c, h, w] = x.dims();
                let [_, _, k, _] = weight.dims();
                let out = ((h + 2 * p).saturating_sub(k) / s + 1) * ((w + 2 * p).saturating_sub(k) / s + 1);
                match x.device().inner().as_dispatch() {
                    // Training on flex: the crate's differentiable im2col kernel, whose input
                    // gradient is one GEMM per image (`flex_autodiff`).
                    DispatchDevice::Flex(_) if x.is_autodiff() => {
                        match flex_autodiff::conv2d_applies(&x, &weight, bias.as_ref(), s, p) {
                            Some(strategy) => return flex_autodiff::conv2d_op(x, weight, bias, s, p, strategy),
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

/// Group normalisation over `[n, c, h, w]` with per-channel affine parameters (biased
/// variance, as PyTorch). In training on flex it runs as one differentiable kernel, SiLU
/// included for [`GroupNorm::forward_silu`]; elsewhere as Burn's tensor operations.
#[derive(Module, Debug)]
pub struct GroupNorm {
    /// Scale, `[c]`.
    pub weight: Param<Tensor<1>>,
    /// Shift, `[c]`.
    pub bias: Param<Tensor<1>>,
    /// Number of groups.
    pub groups: usize,
    /// Added to the variance.
    pub eps: f64,
}

impl GroupNorm {
    pub(crate) fn load(p: &mut ParamSource, key: &str, groups: usize, channels: usize, eps: f64) -> Self {
        let weight = p.param(&format!("{key}.weight"), [channels], Init::Ones);
        let bias = p.param(&format!("{key}.bias"), [channels], Init::Zeros);
        Self { weight, bias, groups, eps }
    }

    /// Normalises each group of channels of each image to zero mean, unit variance.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.forward_maybe_silu(x, false)
    }

    /// `silu(forward(x))`.
    pub fn forward_silu(&self, x: Tensor<4>) -> Tensor<4> {
        self.forward_maybe_silu(x, true)
    }

    /// The normalisation, then SiLU when `then_silu`. In training on flex, one differentiable
    /// kernel (`flex_autodiff`); elsewhere Burn's tensor operations.
    fn forward_maybe_silu(&self, x: Tensor<4>, then_silu: bool) -> Tensor<4> {
        let (weight, bias) = (self.weight.val(), self.bias.val());
        if let Some(strategy) = flex_autodiff::group_norm_applies(&x, &weight, &bias, self.groups) {
            return flex_autodiff::group_norm_op(x, weight, bias, self.groups, self.eps, then_silu, strategy);
        }
        let y = self.composed(x);
        if then_silu { silu(y) } else { y }
    }

    /// The normalisation written with Burn's tensor operations.
    fn composed(&self, x: Tensor<4>) -> Tensor<4> {
        let [n, c, h, w] = x.dims();
        let g = self.groups;
        let x = x.reshape([n, g, (c / g) * h * w]);
        let (var, mean) = x.clone().var_mean_bias(2);
        let x = (x - mean) / (var + self.eps).sqrt();
        let x = x.reshape([n, c, h, w]);
        x * self.weight.val().reshape([1, c, 1, 1]) + self.bias.val().reshape([1, c, 1, 1])
    }
}

/// Layer normalisation over the last dimension.
#[derive(Module, Debug)]
pub struct LayerNorm {
    /// Scale, `[d]`.
    pub weight: Param<Tensor<1>>,
    /// Shift, `[d]`.
    pub bias: Param<Tensor<1>>,
    /// Added to the variance.
    pub eps: f64,
}

impl LayerNorm {
    pub(crate) fn load(p: &mut ParamSource, key: &str, dim: usize, eps: f64) -> Self {
        let weight = p.param(&format!("{key}.weight"), [dim], Init::Ones);
        let bias = p.param(&format!("{key}.bias"), [dim], Init::Zeros);
        Self { weight, bias, eps }
    }

    /// Normalises the last dimension.
    pub fn forward<const D: usize>(&self, x: Tensor<D>) -> Tensor<D> {
        layer_norm(x, self.weight.val(), Some(self.bias.val()), self.eps)
    }
}

/// The GEGLU gate `hidden · gelu(gate)` (exact GELU) of the halves `[hidden, gate]` of the
/// last dimension of `projection`: `[n, t, 2·inner]` → `[n, t, inner]`.
///
/// On Burn's CPU backends this is the crate's kernel (one pass, on all cores), in training on
/// flex a single differentiable operation with a one-pass backward; elsewhere Burn's slice,
/// `gelu` and product. The kernel's arithmetic is flex's, so the values are the same either
/// way.
pub fn geglu(projection: Tensor<3>) -> Tensor<3> {
    let [n, t, two_inner] = projection.dims();
    let inner = two_inner / 2;
    if inner > 0 && cpu_inference_f32(&projection) {
        let device = projection.device();
        let out = crate::cpu_geglu::geglu(&cpu_values(projection), inner);
        return Tensor::from_data(TensorData::new(out, [n, t, inner]), &device);
    }
    if let Some(strategy) = flex_autodiff::geglu_applies(&projection) {
        return flex_autodiff::geglu_op(projection, strategy);
    }
    let hidden = projection.clone().slice([0..n, 0..t, 0..inner]);
    let gate = projection.slice([0..n, 0..t, inner..two_inner]);
    hidden * gelu(gate)
}

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
    if cpu_kernel_applies(&q, &k, &v) {
        return cpu_kernel_attention(q, k, v, heads);
    }
    if let Some(strategy) = flex_autodiff::attention_applies(&q, &k, &v) {
        return flex_autodiff::attention(q, k, v, heads, strategy);
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

/// Whether the crate's CPU inference kernels (attention, GEGLU) may take `t`: f32 values on a
/// CPU backend, with no autodiff graph to keep.
fn cpu_inference_f32<const D: usize>(t: &Tensor<D>) -> bool {
    t.dtype() == DType::F32 && !t.is_autodiff() && on_cpu_backend(&t.device())
}

/// The values of a tensor [`cpu_inference_f32`] accepted. Taken by value: a tensor that holds
/// its values alone (the output of a projection) on flex gives them up without a copy.
fn cpu_values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32 values (checked by cpu_inference_f32)")
}

/// The attention through [`crate::cpu_attention`]. The tensors are taken by value: the
/// projections that produce them hold no other reference, so on flex their values move out
/// without a copy.
fn cpu_kernel_attention(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize) -> Tensor<3> {
    let device = q.device();
    let [batch, queries, width] = q.dims();
    let keys = k.dims()[1];
    let shape = crate::cpu_attention::AttentionShape { batch, queries, keys, heads, head_dim: width / heads };
    let out = crate::cpu_attention::attention(&cpu_values(q), &cpu_values(k), &cpu_values(v), shape);
    Tensor::from_data(TensorData::new(out, [batch, queries, width]), &device)
}
