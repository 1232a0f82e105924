//! The optimiser and what it needs from Burn's module tree: PyTorch's AdamW with gradient-norm
//! clipping, the visitors that collect gradients and values and set them back, the training
//! draws' random stream.

use burn::module::{ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::tensor::{GradientCheckpointingStrategy, Gradients, Tensor};
use rayon::prelude::*;
use std::collections::HashMap;
use w3d_core::Error;

/// AdamW moments of one parameter, flattened.
#[derive(Clone, Debug)]
pub(crate) struct Moments {
    pub(crate) first: Tensor<1>,
    pub(crate) second: Tensor<1>,
}

/// The global gradient norm (f64 over the per-tensor sums of squares, as PyTorch's
/// `clip_grad_norm_`) and the factor `min(1, max / (norm + 1e-6))` the gradients are scaled
/// by (1 without a maximum). A non-finite norm is an error.
pub(crate) fn clip_factor(grads: &HashMap<ParamId, Tensor<1>>, max: Option<f64>) -> Result<(f64, f64), Error> {
    // The per-tensor sums in parallel, added up in the map's order as before.
    let tensors: Vec<&Tensor<1>> = grads.values().collect();
    let squares: Vec<f32> = tensors.into_par_iter().map(|g| (g.clone() * g.clone()).sum().into_scalar()).collect();
    let total: f64 = squares.into_iter().fold(0.0, |total, sq| total + sq as f64);
    let norm = total.sqrt();
    if !norm.is_finite() {
        return Err(Error::invalid("gradients", format!("a finite norm (found {norm}); lower the learning rate")));
    }
    Ok((norm, max.map_or(1.0, |max| (max / (norm + 1e-6)).min(1.0))))
}

/// The next output of the SplitMix64 generator whose state is `state` (advanced): the random
/// stream of training draws, a plain `u64` so a checkpoint can store and restore it.
pub(crate) fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The value of a one-element loss, refused when not finite.
pub(crate) fn scalar(loss: &Tensor<1>) -> Result<f32, Error> {
    let values = loss
        .clone()
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| Error::invalid("loss", format!("a readable f32 scalar ({e:?})")))?;
    match values.first() {
        Some(v) if v.is_finite() => Ok(*v),
        v => Err(Error::invalid("loss", format!("a finite value (found {v:?}); lower the learning rate"))),
    }
}

/// Sets `require_grad` on the trainable parameters only.
pub(crate) struct RequireGrad<'a> {
    pub(crate) trainable: &'a HashMap<ParamId, (String, bool)>,
    /// Put every parameter on autodiff with Burn's balanced checkpointing strategy (the
    /// trainer's device, and so every tensor made on it, then carries the strategy too:
    /// operands must share one).
    pub(crate) checkpointing: bool,
}

impl ModuleMapper for RequireGrad<'_> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let trains = self.trainable.contains_key(&param.id);
        let param = if self.checkpointing {
            param.map(|t| t.autodiff().with_gradient_checkpointing_strategy(GradientCheckpointingStrategy::Balanced))
        } else {
            param
        };
        param.set_require_grad(trains)
    }
}

/// Gradients of the trainable parameters, flattened, on the inner (non-autodiff) device.
pub(crate) struct CollectGrads<'a> {
    pub(crate) grads: &'a Gradients,
    pub(crate) trainable: &'a HashMap<ParamId, (String, bool)>,
    /// Id, the parameter's dims, the flattened gradient.
    pub(crate) out: Vec<(ParamId, Vec<usize>, Tensor<1>)>,
}

impl ModuleVisitor for CollectGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if !self.trainable.contains_key(&param.id) {
            return;
        }
        if let Some(g) = param.val().grad(self.grads) {
            let dims = g.dims().to_vec();
            let n = g.shape().num_elements();
            self.out.push((param.id, dims, g.reshape([n])));
        }
    }
}

/// The current values of the trainable parameters, flattened, on the inner device.
pub(crate) struct CollectValues<'a> {
    pub(crate) trainable: &'a HashMap<ParamId, (String, bool)>,
    pub(crate) out: Vec<(ParamId, Tensor<1>)>,
}

impl ModuleVisitor for CollectValues<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.trainable.contains_key(&param.id) {
            let value = param.val().inner();
            let n = value.shape().num_elements();
            self.out.push((param.id, value.reshape([n])));
        }
    }
}

/// Replaces the parameters found in `values` (flattened) by those values.
pub(crate) struct SetValues<'a> {
    pub(crate) values: &'a HashMap<ParamId, Tensor<1>>,
}

impl ModuleMapper for SetValues<'_> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some(value) = self.values.get(&param.id) else { return param };
        param.map(|tensor| {
            let dims = tensor.dims();
            value.clone().reshape(dims)
        })
    }
}

/// PyTorch's AdamW (decoupled weight decay, bias-corrected moments) on clipped gradients;
/// [`AdamW::into_updates`] computes the step.
pub(crate) struct AdamW<'a> {
    pub(crate) grads: HashMap<ParamId, Tensor<1>>,
    pub(crate) moments: &'a mut HashMap<ParamId, Moments>,
    /// The learning rate of each parameter (its group's).
    pub(crate) lr_of: &'a dyn Fn(ParamId) -> f64,
    pub(crate) clip: f64,
    pub(crate) betas: (f64, f64),
    pub(crate) weight_decay: f64,
    pub(crate) epsilon: f64,
    pub(crate) step: usize,
}

impl AdamW<'_> {
    /// Every parameter's new moments (stored) and update, computed in parallel over the
    /// parameters. Each parameter gets the same tensor operations as one after the other, so
    /// the same bits; in sequence, on one core, they were about a tenth of the small UNet's
    /// training step (`docs/benchmarks.md`, "Training step").
    pub(crate) fn into_updates(self) -> AdamWUpdates {
        let work: Vec<(ParamId, Tensor<1>, Option<Moments>, f64)> =
            self.grads.into_iter().map(|(id, grad)| (id, grad, self.moments.remove(&id), (self.lr_of)(id))).collect();
        let (b1, b2) = self.betas;
        let bias1 = 1.0 - b1.powi(self.step as i32);
        let bias2 = 1.0 - b2.powi(self.step as i32);
        let (clip, epsilon, weight_decay) = (self.clip, self.epsilon, self.weight_decay);
        let done: Vec<(ParamId, Moments, Tensor<1>, f64)> = work
            .into_par_iter()
            .map(|(id, grad, moments, lr)| {
                let grad = grad * clip;
                let moments = match moments {
                    Some(m) => Moments {
                        first: m.first * b1 + grad.clone() * (1.0 - b1),
                        second: m.second * b2 + grad.clone() * grad * (1.0 - b2),
                    },
                    None => Moments { first: grad.clone() * (1.0 - b1), second: grad.clone() * grad * (1.0 - b2) },
                };
                let denom = moments.second.clone().sqrt() / bias2.sqrt() + epsilon;
                let delta = moments.first.clone() / denom * (lr / bias1);
                (id, moments, delta, 1.0 - lr * weight_decay)
            })
            .collect();
        let mut updates = HashMap::with_capacity(done.len());
        for (id, moments, delta, decay) in done {
            self.moments.insert(id, moments);
            updates.insert(id, (delta, decay));
        }
        AdamWUpdates { updates }
    }
}

/// The parameters' AdamW updates ([`AdamW::into_updates`]); mapping a module by them applies
/// them.
pub(crate) struct AdamWUpdates {
    /// Per parameter: the step to subtract and the decoupled weight decay's factor
    /// `1 − lr·λ`.
    pub(crate) updates: HashMap<ParamId, (Tensor<1>, f64)>,
}

impl ModuleMapper for AdamWUpdates {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some((delta, weight_decay)) = self.updates.remove(&param.id) else { return param };
        param.map(|tensor| {
            let dims = tensor.dims();
            // The updated weight keeps the checkpointing strategy the trainer put it on.
            let strategy = tensor.gradient_checkpointing_strategy();
            let inner = tensor.inner();
            let n = inner.shape().num_elements();
            let updated = Tensor::from_inner((inner.reshape([n]) * weight_decay - delta).reshape(dims));
            match strategy {
                Some(strategy) => updated.with_gradient_checkpointing_strategy(strategy),
                None => updated,
            }
            .require_grad()
        })
    }
}
