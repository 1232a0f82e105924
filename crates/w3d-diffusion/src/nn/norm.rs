//! Group and layer normalisation (PyTorch `nn.GroupNorm`, `nn.LayerNorm`).

use burn::module::{Module, Param};
use burn::tensor::Tensor;
use burn::tensor::activation::silu;
use burn::tensor::module::layer_norm;

#[cfg(feature = "train")]
use crate::kernels::autodiff;
use crate::loading::weights::{Init, ParamSource};

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
    /// kernel (`kernels::autodiff`); elsewhere Burn's tensor operations.
    fn forward_maybe_silu(&self, x: Tensor<4>, then_silu: bool) -> Tensor<4> {
        #[cfg(feature = "train")]
        {
            let (weight, bias) = (self.weight.val(), self.bias.val());
            if let Some(strategy) = autodiff::group_norm_applies(&x, &weight, &bias, self.groups) {
                return autodiff::group_norm_op(x, weight, bias, self.groups, self.eps, then_silu, strategy);
            }
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
