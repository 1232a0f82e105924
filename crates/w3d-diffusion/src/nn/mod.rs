//! Building blocks shared by the UNet, the VAE and the CLIP encoder: linear layers, 2-D
//! convolutions (im2col + GEMM), GroupNorm, LayerNorm, the GEGLU activation and multi-head
//! attention, each under its PyTorch name.
//!
//! Images are `[batch, channels, height, width]`; token sequences are `[batch, tokens, width]`.

mod activation;
mod attention;
mod conv;
mod linear;
mod norm;

pub use activation::geglu;
pub use attention::{ATTENTION_MAX_SCORES, causal_multi_head_attention, in_groups, multi_head_attention};
pub use conv::{Conv2d, ConvAlgorithm, IM2COL_MAX_FLOATS, im2col_conv2d};
pub use linear::Linear;
pub use norm::{GroupNorm, LayerNorm};
