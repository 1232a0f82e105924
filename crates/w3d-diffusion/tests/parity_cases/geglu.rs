//! `nn::geglu` (the crate's one-pass kernel on the CPU backends, a single differentiable
//! operation in training on flex) against the same gate written with Burn's tensor operations
//! (slice, `gelu`, product), differentiated by Burn: the output and the gradient of the
//! projection, in inference and in training with and without gradient checkpointing. The
//! kernel repeats flex's arithmetic operation for operation, so on flex they agree bit for bit.

use crate::common::{relative_max_diff, test_devices, values};
#[cfg(feature = "train")]
use burn::tensor::GradientCheckpointingStrategy;
use burn::tensor::activation::gelu;
use w3d_diffusion::gaussian_noise;
use w3d_diffusion::nn::geglu;
use w3d_diffusion::{Tensor, TensorData};

fn reference(projection: Tensor<3>) -> Tensor<3> {
    let [n, t, two_inner] = projection.dims();
    let inner = two_inner / 2;
    let hidden = projection.clone().slice([0..n, 0..t, 0..inner]);
    let gate = projection.slice([0..n, 0..t, inner..two_inner]);
    hidden * gelu(gate)
}

/// Tolerance: none on flex (the same arithmetic), f32 rounding elsewhere (other backends'
/// error functions differ in the last bits).
fn tolerance(device: &str) -> f32 {
    if device == "flex" { 0.0 } else { 1e-5 }
}

#[test]
fn geglu_matches_burn_operations_in_inference() {
    // (images, tokens, inner): a row count that is not a multiple of the kernel's task size,
    // one row, an inner width of one.
    for (name, device) in test_devices() {
        for (i, &(n, t, inner)) in [(3, 70, 40), (1, 1, 8), (2, 5, 1)].iter().enumerate() {
            let projection = gaussian_noise([n, t, 2 * inner], 300 + i as u64, &device) * 3.0;
            let (ours, burn) = (values(geglu(projection.clone())), values(reference(projection)));
            let err = relative_max_diff(&ours, &burn);
            assert!(err <= tolerance(name), "{name} case {i}: relative difference {err:e}");
        }
    }
}

#[cfg(feature = "train")]
#[test]
fn training_geglu_gradients_match_burn_autodiff() {
    for (name, device) in test_devices() {
        for strategy in [GradientCheckpointingStrategy::Disabled, GradientCheckpointingStrategy::Balanced] {
            for (i, &(n, t, inner)) in [(3, 70, 40), (2, 5, 1)].iter().enumerate() {
                let seed = 310 + 10 * i as u64;
                let leaf = |t: Tensor<3>| t.autodiff().with_gradient_checkpointing_strategy(strategy);
                let run = |ours: bool| {
                    let projection = leaf(gaussian_noise([n, t, 2 * inner], seed, &device) * 3.0).require_grad();
                    let y = if ours { geglu(projection.clone()) } else { reference(projection.clone()) };
                    let g = leaf(gaussian_noise([n, t, inner], seed + 1, &device));
                    let grads = (y.clone() * g).sum().backward();
                    [values(y), values(projection.grad(&grads).expect("projection gradient"))]
                };
                let (ours, burn) = (run(true), run(false));
                for (what, (a, b)) in ["output", "gradient"].iter().zip(ours.iter().zip(&burn)) {
                    let err = relative_max_diff(a, b);
                    assert!(err <= tolerance(name), "{name} {strategy:?} case {i} {what}: relative difference {err:e}");
                }
            }
        }
    }
}

/// The training gradient against central differences of the inference output (f64 sums of
/// the f32 values): a check of the derivative that does not rely on Burn's.
#[cfg(feature = "train")]
#[test]
fn geglu_gradient_matches_finite_differences() {
    let device = w3d_diffusion::default_device();
    let inner = 3;
    let projection: Vec<f32> = (0..2 * inner * 2).map(|i| (i as f32 * 0.7).sin() * 2.5).collect();
    let d_out: Vec<f32> = (0..inner * 2).map(|i| 0.3 + (i as f32 * 1.3).cos()).collect();
    let tensor = |v: &[f32], last: usize| Tensor::<3>::from_data(TensorData::new(v.to_vec(), [1, 2, last]), &device);
    let x = tensor(&projection, 2 * inner).autodiff().require_grad();
    let grads = (geglu(x.clone()) * tensor(&d_out, inner).autodiff()).sum().backward();
    let grad = values(x.grad(&grads).expect("projection gradient"));
    let objective = |p: &[f32]| -> f64 {
        values(geglu(tensor(p, 2 * inner))).iter().zip(&d_out).map(|(&o, &d)| o as f64 * d as f64).sum()
    };
    for i in 0..projection.len() {
        let step = 1e-2f32;
        let (mut up, mut down) = (projection.clone(), projection.clone());
        up[i] += step;
        down[i] -= step;
        let numeric = (objective(&up) - objective(&down)) / (2.0 * step as f64);
        assert!((numeric - grad[i] as f64).abs() < 2e-3, "value {i}: {numeric} vs {}", grad[i]);
    }
}
