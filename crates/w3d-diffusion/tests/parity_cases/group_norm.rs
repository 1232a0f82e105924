//! `nn::GroupNorm` in training on flex (the crate's differentiable kernel) against the same
//! normalisation written with Burn's tensor operations and differentiated by Burn: output and
//! the gradients of the input, the scale and the shift, with and without the SiLU that
//! follows it in the resnet blocks.

use crate::common::{relative_max_diff, test_devices, values};
use burn::module::Param;
use burn::tensor::GradientCheckpointingStrategy;
use burn::tensor::activation::silu;
use w3d_diffusion::Tensor;
use w3d_diffusion::gaussian_noise;
use w3d_diffusion::nn::GroupNorm;

/// The normalisation as Burn's tensor operations (biased variance, as PyTorch).
fn reference(x: Tensor<4>, weight: Tensor<1>, bias: Tensor<1>, groups: usize, eps: f64) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let g = x.reshape([n, groups, (c / groups) * h * w]);
    let (var, mean) = g.clone().var_mean_bias(2);
    let g = (g - mean) / (var + eps).sqrt();
    g.reshape([n, c, h, w]) * weight.reshape([1, c, 1, 1]) + bias.reshape([1, c, 1, 1])
}

#[test]
fn training_group_norm_gradients_match_burn_autodiff() {
    // (n, c, h, w, groups, offset of the input's mean): several channels per group, one group,
    // one channel per group; an input far from zero mean.
    let cases = [(3, 8, 5, 7, 4, 0.0), (2, 6, 4, 4, 1, 0.0), (2, 4, 3, 3, 4, 0.0), (2, 8, 6, 6, 2, 20.0)];
    for (name, device) in test_devices() {
        for strategy in [GradientCheckpointingStrategy::Disabled, GradientCheckpointingStrategy::Balanced] {
            for (i, &(n, c, h, w, groups, offset)) in cases.iter().enumerate() {
                for then_silu in [false, true] {
                    let seed = 200 + 10 * i as u64;
                    let leaf4 = |t: Tensor<4>| t.autodiff().with_gradient_checkpointing_strategy(strategy);
                    let leaf1 = |t: Tensor<1>| t.autodiff().with_gradient_checkpointing_strategy(strategy);
                    let run = |ours: bool| {
                        let x = leaf4(gaussian_noise([n, c, h, w], seed, &device) + offset).require_grad();
                        let norm = GroupNorm {
                            weight: Param::from_tensor(leaf1(gaussian_noise([c], seed + 1, &device) + 1.0)),
                            bias: Param::from_tensor(leaf1(gaussian_noise([c], seed + 2, &device))),
                            groups,
                            eps: 1e-5,
                        };
                        let y = match (ours, then_silu) {
                            (true, true) => norm.forward_silu(x.clone()),
                            (true, false) => norm.forward(x.clone()),
                            (false, _) => {
                                let y = reference(x.clone(), norm.weight.val(), norm.bias.val(), groups, norm.eps);
                                if then_silu { silu(y) } else { y }
                            }
                        };
                        let g = leaf4(gaussian_noise([n, c, h, w], seed + 3, &device));
                        let grads = (y.clone() * g).sum().backward();
                        vec![
                            values(y),
                            values(x.grad(&grads).expect("input gradient")),
                            values(norm.weight.val().grad(&grads).expect("scale gradient")),
                            values(norm.bias.val().grad(&grads).expect("shift gradient")),
                        ]
                    };
                    let (ours, burn) = (run(true), run(false));
                    for (what, (a, b)) in ["output", "dx", "dweight", "dbias"].iter().zip(ours.iter().zip(&burn)) {
                        let err = relative_max_diff(a, b);
                        println!("{name} {strategy:?} case {i} silu {then_silu} {what}: relative difference {err:.1e}");
                        assert!(err < 2e-5, "{name} {strategy:?} case {i} silu {then_silu} {what}: {err}");
                    }
                }
            }
        }
    }
}
