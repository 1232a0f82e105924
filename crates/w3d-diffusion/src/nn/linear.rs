//! The fully connected layer (PyTorch `nn.Linear`).

use burn::module::{Module, Param};
use burn::tensor::Tensor;

#[cfg(feature = "train")]
use crate::kernels::autodiff;
use crate::kernels::bf16;
use crate::kernels::dispatch::as_f32;
use crate::loading::weights::{Init, ParamSource};

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
    ///
    /// At inference on the CPU, with [`crate::compute::Products::Bf16`] asked for by the pass
    /// and supported by the CPU, the product runs with bf16 factors and f32 sums (the weight
    /// rounded straight from the dtype it is held in); otherwise in f32.
    pub fn forward<const D: usize>(&self, x: Tensor<D>) -> Tensor<D> {
        let dims = x.dims();
        let [d_in, d_out] = self.weight.dims();
        let rows = dims[..D - 1].iter().product();
        let weight = self.weight.val();
        if bf16::applies(&x, &weight) {
            let mut out = dims;
            out[D - 1] = d_out;
            let bias = self.bias.as_ref().map(|b| b.val());
            return bf16::linear_tensor(x.reshape([rows, d_in]), weight, bias).reshape(out);
        }
        let (x, weight) = (x.reshape([rows, d_in]), as_f32(weight));
        let bias = self.bias.as_ref().map(|b| b.val());
        let mut out = dims;
        out[D - 1] = d_out;
        // Training on the CPU: one differentiable node (`kernels::linear`).
        #[cfg(feature = "train")]
        if let Some(strategy) = autodiff::linear_applies(&x, &weight, bias.as_ref()) {
            return autodiff::linear_op(x, weight, bias, strategy).reshape(out);
        }
        let y = x.matmul(weight);
        let y = match bias {
            Some(b) => y + b.unsqueeze::<2>(),
            None => y,
        };
        y.reshape(out)
    }
}
