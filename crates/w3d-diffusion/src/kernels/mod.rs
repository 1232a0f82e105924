//! CPU kernels for Burn's flex backend: plain `f32` slices in and out, parallel over rayon's
//! pool, each with the backward pass training needs. They replace Burn's own operations where
//! those were measured slower on the models' shapes (`docs/architecture.md` lists each kernel,
//! what it replaces and its measured gain). The layers in [`crate::nn`] decide when a kernel
//! takes a call ([`dispatch`]); in training, [`autodiff`] wraps the kernels as differentiable
//! operations on Burn's autodiff backend.

// The GEMM building block, the convolutions' shape, running work on the pool, and the
// tensor-level dispatch.
pub(crate) mod conv_shape;
pub(crate) mod dispatch;
pub(crate) mod gemm;
pub(crate) mod pool;

// The kernels, each forward and backward; those only training uses behind feature `train`.
pub(crate) mod attention;
pub(crate) mod bf16;
#[cfg(feature = "train")]
pub(crate) mod conv;
pub(crate) mod geglu;
#[cfg(feature = "train")]
pub(crate) mod group_norm;
#[cfg(feature = "train")]
pub(crate) mod linear;
pub(crate) mod token_merge;

// The kernels as differentiable operations of Burn's autodiff on flex (feature `train`).
#[cfg(feature = "train")]
pub(crate) mod autodiff;
