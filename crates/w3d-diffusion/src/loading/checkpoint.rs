//! What every model of a diffusers / transformers checkpoint folder does alike, written once
//! (diffusers' `ModelMixin`): load a config with the tensors of a weights file, load a folder
//! (`config.json` + weights), build with seeded random weights, and save a folder the authors'
//! code loads. The models keep their own public `load` / `from_dir` / `random` / `save`
//! methods, each one line over these functions.

use std::path::Path;

use burn::module::Module;
use burn::tensor::Device;
use serde::Serialize;
use w3d_core::Error;

use crate::loading::config::{ClipTextConfig, ClipVisionConfig, UNetConfig, VaeConfig};
use crate::loading::weights::{
    NamedParam, ParamSource, Precision, SafetensorsFile, WeightStorage, collect_named, config_json, find_weights,
    write_checkpoint,
};

/// A model's `config.json`: read from a file and validated before anything is built.
pub(crate) trait ModelConfig: Serialize + Sized {
    /// Reads and parses `config.json` at `path`.
    fn read(path: &Path) -> Result<Self, Error>;
    /// Fails on a value the model cannot be built with.
    fn check(&self) -> Result<(), Error>;
}

macro_rules! model_config {
    ($($config:ty),*) => {$(
        impl ModelConfig for $config {
            fn read(path: &Path) -> Result<Self, Error> {
                <$config>::from_file(path)
            }
            fn check(&self) -> Result<(), Error> {
                self.validate()
            }
        }
    )*};
}
model_config!(UNetConfig, VaeConfig, ClipVisionConfig, ClipTextConfig);

/// A model stored as a checkpoint folder: a config, weights under the checkpoint's key names.
pub(crate) trait Checkpoint: Module + Sized {
    /// The model's `config.json`.
    type Config: ModelConfig;
    /// Stem of the weights file in a checkpoint folder (`diffusion_pytorch_model`, `model`).
    const WEIGHTS_STEM: &'static str;

    /// The model's key of a file key (legacy spellings renamed); the key itself by default.
    fn model_key(file_key: &str) -> String {
        file_key.to_owned()
    }

    /// Whether a file key holds a buffer the model does not use (accepted and ignored).
    fn is_buffer(_key: &str) -> bool {
        false
    }

    /// The model of `config` with its parameters from `p`.
    fn build(config: &Self::Config, p: &mut ParamSource) -> Result<Self, Error>;

    /// Records the checkpoint key of every parameter, in build order.
    fn set_names(&mut self, names: Vec<NamedParam>);

    /// The checkpoint key of every parameter, in build order.
    fn names(&self) -> &[NamedParam];

    /// The config this model was built from.
    fn config(&self) -> &Self::Config;

    /// The fields `config.json` adds to the config to name the class (`_class_name`, …).
    fn class_fields(&self) -> Vec<(&'static str, &'static str)>;
}

/// `config` with the tensors of the safetensors file `weights` (f32, f16 or bf16), held as
/// `storage` says. Fails listing every missing, unexpected or misshaped key.
pub(crate) fn load<M: Checkpoint>(
    config: &M::Config,
    weights: &Path,
    device: &Device,
    storage: WeightStorage,
) -> Result<M, Error> {
    config.check()?;
    let mut file = SafetensorsFile::open(weights)?;
    let p = ParamSource::from_file(&mut file, M::model_key, device).storing(storage);
    build_checked(config, p)
}

/// The model of `config` built from `p`, every key of `p` used (see [`ParamSource::finish`]).
pub(crate) fn build_checked<M: Checkpoint>(config: &M::Config, mut p: ParamSource) -> Result<M, Error> {
    p.ignore(M::is_buffer);
    let mut model = M::build(config, &mut p)?;
    model.set_names(p.take_names());
    p.finish()?;
    Ok(model)
}

/// `config.json` and the weights (or their `.fp16` variant) of the checkpoint folder `dir`.
pub(crate) fn from_dir<M: Checkpoint>(dir: &Path, device: &Device, storage: WeightStorage) -> Result<M, Error> {
    let config = M::Config::read(&dir.join("config.json"))?;
    load(&config, &find_weights(dir, M::WEIGHTS_STEM)?, device, storage)
}

/// `config` with seeded random weights (same seed, same values) held as `storage` says.
pub(crate) fn random<M: Checkpoint>(
    config: &M::Config,
    seed: u64,
    device: &Device,
    storage: WeightStorage,
) -> Result<M, Error> {
    config.check()?;
    let mut p = ParamSource::random(seed, device).storing(storage);
    let mut model = M::build(config, &mut p)?;
    model.set_names(p.take_names());
    Ok(model)
}

/// Writes `config.json` and `<stem>.safetensors` (the checkpoint's keys, PyTorch layouts, in
/// `precision`) into `dir`, each under a temporary name first and then renamed.
pub(crate) fn save<M: Checkpoint>(model: &M, dir: &Path, precision: Precision) -> Result<(), Error> {
    let tensors = collect_named(model, model.names())?;
    let config = config_json(model.config(), &model.class_fields())?;
    write_checkpoint(dir, &format!("{}.safetensors", M::WEIGHTS_STEM), &tensors, &config, precision)
}

/// The public loading and saving methods of a [`Checkpoint`] model, each one call of the
/// functions above, so every model offers the same ones under the same documentation:
/// `checkpoint_methods!(Config, "folder/")` inside the model's `impl` block.
macro_rules! checkpoint_methods {
    ($config:ty, $folder:literal) => {
        #[doc = concat!(
                            "Loads `config` with the weights of the safetensors file `weights` (f32, f16 or ",
                            "bf16, the checkpoint's key names). Fails listing every missing, unexpected or ",
                            "misshaped key."
                        )]
        pub fn load(
            config: &$config,
            weights: impl AsRef<std::path::Path>,
            device: &burn::tensor::Device,
        ) -> Result<Self, w3d_core::Error> {
            $crate::loading::checkpoint::load(
                config,
                weights.as_ref(),
                device,
                $crate::loading::weights::WeightStorage::F32,
            )
        }

        #[doc = concat!(
                            "Loads `config.json` and the weights (or their `.fp16.safetensors` variant) from a ",
                            "checkpoint's `", $folder, "` folder."
                        )]
        pub fn from_dir(
            dir: impl AsRef<std::path::Path>,
            device: &burn::tensor::Device,
        ) -> Result<Self, w3d_core::Error> {
            Self::from_dir_with(dir, device, $crate::loading::weights::WeightStorage::F32)
        }

        /// [`Self::from_dir`] with the linear and convolution weights held as `storage` says
        /// ([`WeightStorage`](crate::WeightStorage): f16 halves the model's memory; the
        /// arithmetic stays f32).
        pub fn from_dir_with(
            dir: impl AsRef<std::path::Path>,
            device: &burn::tensor::Device,
            storage: $crate::loading::weights::WeightStorage,
        ) -> Result<Self, w3d_core::Error> {
            $crate::loading::checkpoint::from_dir(dir.as_ref(), device, storage)
        }

        /// `config` with seeded random weights (same seed, same values): for shape, speed and
        /// memory checks at real sizes without a checkpoint.
        pub fn random(config: &$config, seed: u64, device: &burn::tensor::Device) -> Result<Self, w3d_core::Error> {
            Self::random_with(config, seed, device, $crate::loading::weights::WeightStorage::F32)
        }

        /// [`Self::random`] with the weights held in `storage` (see [`Self::from_dir_with`]).
        pub fn random_with(
            config: &$config,
            seed: u64,
            device: &burn::tensor::Device,
            storage: $crate::loading::weights::WeightStorage,
        ) -> Result<Self, w3d_core::Error> {
            $crate::loading::checkpoint::random(config, seed, device, storage)
        }

        #[doc = concat!(
                            "Writes `config.json` and the weights (f32, PyTorch layouts, the keys of ",
                            "[`Self::named_parameters`]) into `dir`, a checkpoint's `", $folder, "` folder that ",
                            "[`Self::from_dir`] and the reference implementation load. Each file is written ",
                            "under a temporary name and renamed, so an interrupted save never leaves a truncated ",
                            "file under the real name."
                        )]
        pub fn save(&self, dir: impl AsRef<std::path::Path>) -> Result<(), w3d_core::Error> {
            self.save_with(dir, $crate::loading::weights::Precision::F32)
        }

        /// [`Self::save`] with the weights in `precision`.
        pub fn save_with(
            &self,
            dir: impl AsRef<std::path::Path>,
            precision: $crate::loading::weights::Precision,
        ) -> Result<(), w3d_core::Error> {
            $crate::loading::checkpoint::save(self, dir.as_ref(), precision)
        }

        /// The checkpoint key of every parameter, in build order.
        pub fn named_parameters(&self) -> &[$crate::loading::weights::NamedParam] {
            &self.names
        }

        /// The config this model was built from.
        pub fn config(&self) -> &$config {
            &self.config
        }
    };
}
pub(crate) use checkpoint_methods;
