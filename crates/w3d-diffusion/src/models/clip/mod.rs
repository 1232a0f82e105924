//! CLIP (transformers `CLIPVisionModelWithProjection`, `CLIPTextModel`, `CLIPTokenizer`): the
//! transformer encoder both towers share (`encoder`), the image tower with its
//! preprocessing ([`vision`]), the text tower ([`text`]) and its BPE tokenizer ([`tokenizer`]).

pub(crate) mod encoder;
pub mod tokenizer;

pub mod text;
pub mod vision;
