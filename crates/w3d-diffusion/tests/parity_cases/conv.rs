//! The im2col + GEMM convolution equals the backend's `conv2d` for every kernel / stride /
//! padding the models use, on both CPU backends; so does the differentiable convolution
//! `nn::Conv2d` runs in training on flex, values and gradients.

use crate::common::{max_abs, max_abs_diff, relative_max_diff, test_devices, values};
use burn::module::Param;
#[cfg(feature = "train")]
use burn::tensor::GradientCheckpointingStrategy;
use w3d_diffusion::gaussian_noise;
use w3d_diffusion::nn::{Conv2d, ConvAlgorithm, im2col_conv2d};
use w3d_diffusion::{Tensor, TensorData};

#[test]
fn im2col_matches_direct_convolution() {
    // (c_in, c_out, h, w, kernel, stride, padding)
    let cases = [
        (5, 7, 9, 11, 3, 1, 1),
        (5, 7, 10, 12, 3, 2, 1),
        (4, 6, 9, 9, 3, 2, 0),
        (6, 3, 8, 5, 1, 1, 0),
        (3, 8, 12, 18, 6, 6, 0),
        // Images smaller than the kernel's reach (taps that read only padding).
        (3, 4, 1, 2, 3, 1, 1),
        (3, 4, 2, 1, 5, 1, 2),
    ];
    for (name, device) in test_devices() {
        for (i, &(c_in, c_out, h, w, k, s, p)) in cases.iter().enumerate() {
            let seed = 10 * i as u64;
            let x = gaussian_noise([2, c_in, h, w], seed, &device);
            let weight: Tensor<4> = gaussian_noise([c_out, c_in, k, k], seed + 1, &device);
            let bias: Tensor<1> = gaussian_noise([c_out], seed + 2, &device);
            let ours = im2col_conv2d(x.clone(), weight.clone(), Some(bias.clone()), s, p);
            let reference = burn::tensor::module::conv2d(
                x,
                weight,
                Some(bias),
                burn::tensor::ops::ConvOptions::new([s, s], [p, p], [1, 1], 1),
            );
            let err = max_abs_diff(ours, reference.clone()) / max_abs(reference).max(1.0);
            assert!(err < 1e-5, "{name} case {i}: relative error {err}");
        }
    }
}

/// Output and the gradients of `Σ y ∘ g` (a fixed random `g`) with respect to the input,
/// weight and bias: `Conv2d`'s default path under autodiff (on flex, the crate's kernel)
/// against Burn's `conv2d` differentiated by Burn, with and without gradient checkpointing
/// and with and without a bias.
#[cfg(feature = "train")]
#[test]
fn training_convolution_gradients_match_burn_autodiff() {
    // (c_in, c_out, h, w, kernel, stride, padding, bias)
    let cases = [
        (5, 7, 9, 11, 3, 1, 1, true),
        (5, 7, 10, 12, 3, 2, 1, true),
        (4, 6, 9, 9, 3, 2, 0, false),
        (6, 3, 8, 5, 1, 1, 0, true),
        (3, 8, 12, 18, 6, 6, 0, false),
        (3, 4, 1, 2, 3, 1, 1, true),
        (3, 4, 2, 1, 5, 1, 2, false),
        (4, 5, 6, 7, 5, 1, 2, true),
    ];
    for (name, device) in test_devices() {
        for strategy in [GradientCheckpointingStrategy::Disabled, GradientCheckpointingStrategy::Balanced] {
            for (i, &(c_in, c_out, h, w, k, s, p, with_bias)) in cases.iter().enumerate() {
                let seed = 100 + 10 * i as u64;
                let leaf = |t: Tensor<4>| t.autodiff().with_gradient_checkpointing_strategy(strategy);
                let run = |algorithm: ConvAlgorithm| {
                    let x = leaf(gaussian_noise([3, c_in, h, w], seed, &device)).require_grad();
                    let conv = Conv2d {
                        weight: Param::from_tensor(leaf(gaussian_noise([c_out, c_in, k, k], seed + 1, &device))),
                        bias: with_bias.then(|| {
                            let b: Tensor<1> = gaussian_noise([c_out], seed + 2, &device);
                            Param::from_tensor(b.autodiff().with_gradient_checkpointing_strategy(strategy))
                        }),
                        stride: s,
                        padding: p,
                    };
                    let y = conv.forward_with(x.clone(), algorithm);
                    let g = leaf(gaussian_noise(y.dims(), seed + 3, &device));
                    let grads = (y.clone() * g).sum().backward();
                    let mut out = vec![values(y), values(x.grad(&grads).expect("input gradient"))];
                    out.push(values(conv.weight.val().grad(&grads).expect("weight gradient")));
                    if let Some(b) = &conv.bias {
                        out.push(values(b.val().grad(&grads).expect("bias gradient")));
                    }
                    out
                };
                let (ours, burn) = (run(ConvAlgorithm::Auto), run(ConvAlgorithm::Direct));
                for (what, (a, b)) in ["output", "dx", "dw", "db"].iter().zip(ours.iter().zip(&burn)) {
                    let err = relative_max_diff(a, b);
                    println!("{name} {strategy:?} case {i} {what}: relative max-abs difference {err:.1e}");
                    assert!(err < 1e-5, "{name} {strategy:?} case {i} {what}: {err}");
                }
            }
        }
    }
}

#[test]
fn im2col_convolution_of_a_known_image() {
    // A 3x3 box filter over a 4x4 ramp with zero padding: the centre pixels are 9× the mean.
    let device = w3d_diffusion::default_device();
    let x = Tensor::<4>::from_data(TensorData::new((0..16).map(|v| v as f32).collect(), [1, 1, 4, 4]), &device);
    let w = Tensor::<4>::ones([1, 1, 3, 3], &device);
    let y = im2col_conv2d(x, w, None, 1, 1).into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(y[5], 45.0, "0+1+2+4+5+6+8+9+10");
    assert_eq!(y[0], 10.0, "0+1+4+5");
}

/// `nn::in_groups` (the memory-bounded feed-forward of the transformer blocks) gives what the
/// function gives on the whole batch, for groups that divide the rows and groups that do not.
#[test]
fn row_groups_give_the_whole_batch_result() {
    for (name, device) in test_devices() {
        let x = gaussian_noise([7, 5, 6], 3, &device);
        let w = gaussian_noise([6, 4], 4, &device);
        let f = |t: Tensor<3>| {
            let [n, tokens, _] = t.dims();
            burn::tensor::activation::gelu(t.reshape([n * tokens, 6]).matmul(w.clone())).reshape([n, tokens, 4])
        };
        let whole = f(x.clone());
        for group in [0, 1, 2, 3, 7, 9] {
            let grouped = w3d_diffusion::nn::in_groups(x.clone(), group, f);
            let err = max_abs_diff(grouped, whole.clone());
            assert!(err <= 1e-6, "{name}: groups of {group}: {err}");
        }
        assert!(max_abs(whole) > 0.1);
    }
}
