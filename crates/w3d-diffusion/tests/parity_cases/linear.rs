//! `nn::Linear` in training on flex (the crate's differentiable kernel, `cpu_linear`) against
//! the same layer written with Burn's `matmul` and bias broadcast and differentiated by Burn:
//! the output and the gradients of the input, the weight and the bias, with and without
//! gradient checkpointing and a bias, at row counts that do and do not fill the kernel's
//! blocks.

use crate::common::{relative_max_diff, test_devices, values};
use burn::module::Param;
use burn::tensor::GradientCheckpointingStrategy;
use w3d_diffusion::Tensor;
use w3d_diffusion::gaussian_noise;
use w3d_diffusion::nn::Linear;

#[test]
fn training_linear_gradients_match_burn_autodiff() {
    // (sequences, tokens, in, out, bias): rows (sequences · tokens) below, at and above one
    // task's 64; output widths below, at and above one weight-gradient task's 32 columns.
    let cases = [(2, 5, 7, 3, true), (3, 64, 16, 32, false), (2, 70, 24, 80, true), (1, 1, 1, 1, true)];
    for (name, device) in test_devices() {
        for strategy in [GradientCheckpointingStrategy::Disabled, GradientCheckpointingStrategy::Balanced] {
            for (i, &(b, t, d_in, d_out, with_bias)) in cases.iter().enumerate() {
                let seed = 400 + 10 * i as u64;
                let run = |fused: bool| {
                    let leaf3 = |x: Tensor<3>| x.autodiff().with_gradient_checkpointing_strategy(strategy);
                    let x = leaf3(gaussian_noise([b, t, d_in], seed, &device)).require_grad();
                    let weight: Tensor<2> = gaussian_noise([d_in, d_out], seed + 1, &device);
                    let bias: Option<Tensor<1>> = with_bias.then(|| gaussian_noise([d_out], seed + 2, &device));
                    let layer = Linear {
                        weight: Param::from_tensor(weight.autodiff().with_gradient_checkpointing_strategy(strategy)),
                        bias: bias
                            .map(|b| Param::from_tensor(b.autodiff().with_gradient_checkpointing_strategy(strategy))),
                    };
                    let y = if fused {
                        layer.forward(x.clone())
                    } else {
                        let y = x.clone().reshape([b * t, d_in]).matmul(layer.weight.val());
                        let y = match &layer.bias {
                            Some(bias) => y + bias.val().unsqueeze::<2>(),
                            None => y,
                        };
                        y.reshape([b, t, d_out])
                    };
                    let g = leaf3(gaussian_noise([b, t, d_out], seed + 3, &device));
                    let grads = (y.clone() * g).sum().backward();
                    let mut out = vec![values(y), values(x.grad(&grads).expect("input gradient"))];
                    out.push(values(layer.weight.val().grad(&grads).expect("weight gradient")));
                    if let Some(bias) = &layer.bias {
                        out.push(values(bias.val().grad(&grads).expect("bias gradient")));
                    }
                    out
                };
                let (ours, burn) = (run(true), run(false));
                for (what, (a, b)) in ["output", "dx", "dw", "db"].iter().zip(ours.iter().zip(&burn)) {
                    let err = relative_max_diff(a, b);
                    println!("{name} {strategy:?} case {i} {what}: relative max-abs difference {err:.1e}");
                    assert!(err < 1e-5, "{name} {strategy:?} case {i} {what}: {err}");
                }
            }
        }
    }
}
