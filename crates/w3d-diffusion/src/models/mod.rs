//! The models, each a Burn module loading diffusers' or transformers' files: the UNet's blocks
//! ([`blocks`]), the CLIP towers and tokenizer ([`clip`]), the multi-view cross-domain UNet
//! ([`unet`]), the VAE ([`vae`]), and the refinement enhancer's ControlNet ([`controlnet`]) and
//! IP-Adapter ([`ip_adapter`]), which build on the UNet.

pub mod blocks;
pub mod clip;

pub mod unet;
pub mod vae;

pub mod controlnet;
pub mod ip_adapter;
