//! Streaming `.safetensors` weight loading with diffusers / transformers key names.
//!
//! The header is parsed once; each tensor is then read from disk on its own (seek + read) and
//! converted to f32 (from F32, F16 or BF16), so peak memory stays near one copy of the weights
//! plus the largest single tensor. Every requested key is checked for presence and shape, every
//! file key must be used, and all problems are reported together by name.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use burn::module::{Module, ModuleVisitor, Param, ParamId};
use burn::tensor::{DType, Device, Tensor, TensorCreationOptions, TensorData};
use safetensors::tensor::{Dtype, Metadata, TensorInfo};
use w3d_core::Error;

/// A `.safetensors` file opened for streaming reads: the header is in memory, the data is not.
#[derive(Debug)]
pub struct SafetensorsFile {
    path: PathBuf,
    file: File,
    data_start: u64,
    tensors: BTreeMap<String, TensorInfo>,
}

/// The weights file `<stem>.safetensors` (or the diffusers fp16 variant
/// `<stem>.fp16.safetensors`) in a model folder such as `unet/`. A folder holding only the
/// PyTorch pickle `<stem>.bin` gets an error saying how to convert it (pickles are not read).
pub fn find_weights(dir: &Path, stem: &str) -> Result<PathBuf, Error> {
    for name in [format!("{stem}.safetensors"), format!("{stem}.fp16.safetensors")] {
        let path = dir.join(name);
        if path.is_file() {
            return Ok(path);
        }
    }
    let expected = format!("{stem}.safetensors or {stem}.fp16.safetensors");
    let bin = dir.join(format!("{stem}.bin"));
    if bin.is_file() {
        return Err(Error::format(
            &bin,
            "weights",
            format!(
                "{expected} (PyTorch .bin pickles are not read; convert once with `python -c \"import torch, safetensors.torch as s; s.save_file(torch.load('{stem}.bin'), '{stem}.safetensors')\"` in that folder)"
            ),
        ));
    }
    Err(Error::format(dir, "weights", format!("a weights file {expected}")))
}

/// The first tensor of a safetensors header that the format's own validation refused, with
/// what was expected of it: a known dtype, a shape, two offsets, a byte length of
/// `elements × dtype size`, each tensor starting where the previous one ended. `None` when
/// the header is not a JSON object or every entry looks right (the error is elsewhere).
fn culprit_tensor(header: &[u8]) -> Option<(String, String)> {
    let value: serde_json::Value = serde_json::from_slice(header).ok()?;
    let mut entries: Vec<(&String, &serde_json::Value)> =
        value.as_object()?.iter().filter(|(name, _)| name.as_str() != "__metadata__").collect();
    let offsets = |v: &serde_json::Value| -> Option<(u64, u64)> {
        let o = v.get("data_offsets")?.as_array()?;
        Some((o.first()?.as_u64()?, o.get(1)?.as_u64()?))
    };
    for (name, entry) in &entries {
        let bad = |what: String| Some((name.to_string(), what));
        let size = match entry.get("dtype").and_then(|d| d.as_str()) {
            Some("F64" | "I64" | "U64") => 8,
            Some("F32" | "I32" | "U32") => 4,
            Some("F16" | "BF16" | "I16" | "U16") => 2,
            Some("I8" | "U8" | "BOOL" | "F8_E4M3" | "F8_E5M2") => 1,
            other => return bad(format!("a known dtype (found {other:?})")),
        };
        let Some(shape) = entry.get("shape").and_then(|s| s.as_array()) else {
            return bad("a shape: an array of sizes".into());
        };
        let Some(dims) = shape.iter().map(|d| d.as_u64()).collect::<Option<Vec<u64>>>() else {
            return bad(format!("a shape of whole sizes (found {shape:?})"));
        };
        let Some((begin, end)) = offsets(entry) else {
            return bad("data_offsets: two byte offsets [begin, end]".into());
        };
        let elements = dims.iter().try_fold(1u64, |n, &d| n.checked_mul(d));
        let bytes = elements.and_then(|n| n.checked_mul(size));
        if end < begin || bytes != Some(end - begin) {
            return bad(format!(
                "data_offsets [{begin}, {end}] spanning shape {dims:?} × {size} bytes = {} bytes",
                bytes.map_or("more than 2⁶⁴".to_string(), |b| b.to_string())
            ));
        }
    }
    entries.sort_by_key(|(_, entry)| offsets(entry).map_or(0, |(begin, _)| begin));
    let mut next = 0;
    for (name, entry) in entries {
        let (begin, end) = offsets(entry)?;
        if begin != next {
            return Some((
                name.clone(),
                format!("data starting at byte {next}, where the previous tensor ends (found {begin})"),
            ));
        }
        next = end;
    }
    None
}

/// Largest header accepted (the format's own limit).
const MAX_HEADER: u64 = 100_000_000;

impl SafetensorsFile {
    /// Opens `path` and parses its header; fails on a malformed or truncated file.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref().to_path_buf();
        let mut file = File::open(&path).map_err(|e| Error::io(&path, e))?;
        let file_len = file.metadata().map_err(|e| Error::io(&path, e))?.len();
        let mut len_bytes = [0u8; 8];
        file.read_exact(&mut len_bytes)
            .map_err(|_| Error::format(&path, "header length", format!("8 bytes (file has {file_len})")))?;
        let header_len = u64::from_le_bytes(len_bytes);
        if header_len > MAX_HEADER || 8 + header_len > file_len {
            return Err(Error::format(
                &path,
                "header",
                format!(
                    "{header_len} header bytes after the length (file has {file_len} bytes in all): truncated or not safetensors"
                ),
            ));
        }
        let mut header = vec![0u8; header_len as usize];
        file.read_exact(&mut header).map_err(|e| Error::io(&path, e))?;
        // Deserializing validates the header (contiguous offsets, sizes matching shapes and dtypes).
        let metadata: Metadata = serde_json::from_slice(&header).map_err(|e| match culprit_tensor(&header) {
            Some((name, expected)) => Error::format(&path, format!("header: tensor {name:?}"), expected),
            None => Error::format(&path, "header", format!("a valid safetensors header ({e})")),
        })?;
        let data_start = 8 + header_len;
        let tensors: BTreeMap<String, TensorInfo> =
            metadata.tensors().into_iter().map(|(name, info)| (name, info.clone())).collect();
        let data_len = tensors.values().map(|t| t.data_offsets.1 as u64).max().unwrap_or(0);
        if data_start + data_len > file_len {
            return Err(Error::format(
                &path,
                "data",
                format!("{data_len} data bytes as the header declares (file has {}): truncated", file_len - data_start),
            ));
        }
        Ok(Self { path, file, data_start, tensors })
    }

    /// The file this was opened from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Every tensor name with its shape.
    pub fn shapes(&self) -> impl Iterator<Item = (&str, &[usize])> {
        self.tensors.iter().map(|(k, v)| (k.as_str(), v.shape.as_slice()))
    }

    /// Reads one tensor as f32 values (row-major) and its shape.
    pub fn read_f32(&mut self, key: &str) -> Result<(Vec<f32>, Vec<usize>), Error> {
        let info = self.tensors.get(key).ok_or_else(|| Error::format(&self.path, key, "a tensor of that name"))?;
        let (begin, end) = info.data_offsets;
        let shape = info.shape.clone();
        let dtype = info.dtype;
        let mut bytes = vec![0u8; end - begin];
        self.file.seek(SeekFrom::Start(self.data_start + begin as u64)).map_err(|e| Error::io(&self.path, e))?;
        self.file.read_exact(&mut bytes).map_err(|e| Error::io(&self.path, e))?;
        let values: Vec<f32> = match dtype {
            Dtype::F32 => bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect(),
            Dtype::F16 => bytes.chunks_exact(2).map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32()).collect(),
            Dtype::BF16 => bytes.chunks_exact(2).map(|b| half::bf16::from_le_bytes([b[0], b[1]]).to_f32()).collect(),
            other => return Err(Error::format(&self.path, key, format!("F32, F16 or BF16 data (found {other:?})"))),
        };
        Ok((values, shape))
    }
}

/// How a parameter is initialised when no file is given (random weights for shape / speed /
/// memory checks at the real sizes).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Init {
    /// Uniform in `±1/√fan_in` (PyTorch's default for linear and conv weights).
    Uniform { fan_in: usize },
    /// All ones (norm scales).
    Ones,
    /// All zeros (norm shifts).
    Zeros,
}

enum Source<'a> {
    File {
        file: &'a mut SafetensorsFile,
        renamed: BTreeMap<String, String>,
        used: BTreeSet<String>,
    },
    Random {
        state: u64,
    },
    /// Values in memory by key (another model's parameters, in PyTorch layout).
    Values {
        values: HashMap<String, (Vec<usize>, Vec<f32>)>,
        used: BTreeSet<String>,
    },
}

/// Seeded initialiser values (uniform ±1/√fan_in, or constant), advancing `state`.
fn random_values(state: &mut u64, n: usize, init: Init) -> Vec<f32> {
    match init {
        Init::Ones => vec![1.0; n],
        Init::Zeros => vec![0.0; n],
        Init::Uniform { fan_in } => {
            let bound = 1.0 / (fan_in.max(1) as f64).sqrt();
            (0..n)
                .map(|_| {
                    *state ^= *state << 13;
                    *state ^= *state >> 7;
                    *state ^= *state << 17;
                    let u = (*state >> 11) as f64 / (1u64 << 53) as f64;
                    ((2.0 * u - 1.0) * bound) as f32
                })
                .collect()
        }
    }
}

/// `values` of a convolution weight `[o, c_found, k, k]` widened to `[o, c, k, k]` with zero
/// input channels (the image-latent channels a 4-channel UNet gains).
fn widen_channels(values: &[f32], found: &[usize], c: usize) -> Vec<f32> {
    let (o, cf, kk) = (found[0], found[1], found[2] * found[3]);
    let mut out = vec![0.0f32; o * c * kk];
    for i in 0..o {
        for j in 0..cf {
            out[(i * c + j) * kk..(i * c + j + 1) * kk]
                .copy_from_slice(&values[(i * cf + j) * kk..(i * cf + j + 1) * kk]);
        }
    }
    out
}

/// Hands out parameters by diffusers key, from a file or from a seeded random initialiser,
/// collecting every missing / misshaped key so [`ParamSource::finish`] reports them all.
pub(crate) struct ParamSource<'a> {
    source: Source<'a>,
    device: Device,
    missing: Vec<String>,
    wrong: Vec<String>,
    unreadable: Vec<String>,
    /// Tensors holding NaN or infinite values (a damaged or diverged checkpoint), by key.
    non_finite: Vec<String>,
    names: Vec<NamedParam>,
    /// Keys a model may lack in the source, initialised fresh from this seeded state instead.
    fresh: Option<(u64, FreshKeys<'a>)>,
    /// Accept `conv_in.weight` with fewer input channels, widened with zeros.
    widen_conv_in: bool,
    /// How linear and convolution weights are held in memory.
    storage: WeightStorage,
}

/// Which keys a source may lack (see [`ParamSource::with_fresh`]).
type FreshKeys<'a> = Box<dyn Fn(&str) -> bool + 'a>;

/// Where one parameter of a built model lives in a diffusers / transformers checkpoint: its
/// key and, for a weight held transposed (`[d_in, d_out]`), the PyTorch shape it is stored in.
/// Training selects parameters by key (stage presets) and checkpoints are written under them.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedParam {
    /// The parameter's id in the Burn module tree.
    pub id: ParamId,
    /// The checkpoint key (e.g. `down_blocks.0.attentions.0.proj_in.weight`).
    pub key: String,
    /// `Some(shape)` when the module holds the transpose of the PyTorch `[d_out, …]` layout.
    pub torch_shape: Option<Vec<usize>>,
}

impl<'a> ParamSource<'a> {
    /// Parameters from `file`. `rename` maps a legacy file key to its current name (or
    /// returns it unchanged); keys for which `ignore` is true are allowed to stay unused.
    pub(crate) fn from_file(file: &'a mut SafetensorsFile, rename: impl Fn(&str) -> String, device: &Device) -> Self {
        let renamed = file.tensors.keys().map(|k| (rename(k), k.clone())).collect();
        Self::from_source(Source::File { file, renamed, used: BTreeSet::new() }, device)
    }

    /// Seeded random parameters (same seed, same values).
    pub(crate) fn random(seed: u64, device: &Device) -> Self {
        Self::from_source(Source::Random { state: seed ^ 0x5DEE_CE66_D1CE_4E5B }, device)
    }

    /// Parameters from `values` (key → PyTorch shape and values).
    pub(crate) fn from_values(values: HashMap<String, (Vec<usize>, Vec<f32>)>, device: &Device) -> Self {
        Self::from_source(Source::Values { values, used: BTreeSet::new() }, device)
    }

    /// Parameters from `source`, f32, nothing recorded yet.
    fn from_source(source: Source<'a>, device: &Device) -> Self {
        Self {
            source,
            device: device.clone(),
            missing: Vec::new(),
            wrong: Vec::new(),
            unreadable: Vec::new(),
            non_finite: Vec::new(),
            names: Vec::new(),
            fresh: None,
            widen_conv_in: false,
            storage: WeightStorage::F32,
        }
    }

    /// Keys for which `fresh` is true may be missing from the source: they get the seeded
    /// random initialisation instead.
    pub(crate) fn with_fresh(mut self, seed: u64, fresh: impl Fn(&str) -> bool + 'a) -> Self {
        self.fresh = Some((seed ^ 0x5DEE_CE66_D1CE_4E5B, Box::new(fresh)));
        self
    }

    /// Holds linear and convolution weights as `storage` says (each converted as it is read,
    /// so a model never exists in f32 as a whole); biases, norms and embeddings stay f32.
    pub(crate) fn storing(mut self, storage: WeightStorage) -> Self {
        self.storage = storage;
        self
    }

    /// Whether the source holds `key` in f16.
    fn stored_as_f16(&self, key: &str) -> bool {
        match &self.source {
            Source::File { file, renamed, .. } => {
                renamed.get(key).and_then(|k| file.tensors.get(k)).is_some_and(|t| t.dtype == Dtype::F16)
            }
            Source::Values { .. } | Source::Random { .. } => false,
        }
    }

    /// The weight tensor (linear or convolution) of `key` in its storage format.
    fn weight_tensor<const D: usize>(&self, key: &str, values: Vec<f32>, shape: [usize; D]) -> Tensor<D> {
        let half = match self.storage {
            WeightStorage::F32 => false,
            WeightStorage::F16 => true,
            WeightStorage::AsStored => self.stored_as_f16(key),
        };
        match half {
            false => Tensor::from_data(TensorData::new(values, shape), &self.device),
            true => {
                let halves: Vec<half::f16> = values.into_iter().map(half::f16::from_f32).collect();
                let options = TensorCreationOptions::new(self.device.clone()).with_dtype(DType::F16);
                Tensor::from_data(TensorData::new(halves, shape), options)
            }
        }
    }

    /// Accepts a `conv_in.weight` with fewer input channels, widened with zeros.
    pub(crate) fn widening_conv_in(mut self) -> Self {
        self.widen_conv_in = true;
        self
    }

    /// The fallback for a key the source lacks: fresh values when allowed, else recorded
    /// as missing.
    fn absent(&mut self, key: &str, shape: &[usize], init: Init) -> Option<Vec<f32>> {
        match &mut self.fresh {
            Some((state, fresh)) if fresh(key) => Some(random_values(state, shape.iter().product(), init)),
            _ => {
                self.missing.push(format!("{key} {shape:?}"));
                None
            }
        }
    }

    /// Whether a stored shape `found` is accepted for `shape` (the 1×1-convolution form of a
    /// linear weight, or a narrower `conv_in` when widening), with the values' fix-up.
    fn accepts(&self, key: &str, shape: &[usize], found: &[usize]) -> Option<Option<usize>> {
        let squeezed: &[usize] =
            if found.len() == shape.len() + 2 && found.ends_with(&[1, 1]) { &found[..shape.len()] } else { found };
        if squeezed == shape {
            return Some(None);
        }
        let widen = self.widen_conv_in
            && key == "conv_in.weight"
            && found.len() == 4
            && shape.len() == 4
            && found[0] == shape[0]
            && found[2..] == shape[2..]
            && found[1] < shape[1];
        widen.then(|| Some(shape[1]))
    }

    /// Values of `key` with `shape` (row-major f32), or `None` when the file lacks the key,
    /// holds another shape or cannot be read (recorded and reported by `finish`). Nothing of
    /// the config's size is allocated then: a config may claim any width (a `hidden_size` of
    /// 400000 asks for 640 GB), and only the file's own, size-checked tensors are trusted.
    fn values(&mut self, key: &str, shape: &[usize], init: Init) -> Option<Vec<f32>> {
        let n: usize = shape.iter().product();
        let found = match &mut self.source {
            Source::Random { state } => return Some(random_values(state, n, init)),
            Source::File { file, renamed, used } => {
                let Some(file_key) = renamed.get(key).cloned() else {
                    return self.absent(key, shape, init);
                };
                used.insert(file_key.clone());
                file.tensors[&file_key].shape.clone()
            }
            Source::Values { values, used } => {
                let Some((found, _)) = values.get(key) else {
                    return self.absent(key, shape, init);
                };
                used.insert(key.to_string());
                found.clone()
            }
        };
        // Linear weights stored as 1x1 convolutions ([out, in, 1, 1]) are accepted.
        let Some(widen) = self.accepts(key, shape, &found) else {
            self.wrong.push(format!("{key}: expected {shape:?}, found {found:?}"));
            return None;
        };
        let values = match &mut self.source {
            Source::File { file, renamed, .. } => match file.read_f32(&renamed[key]) {
                // A NaN or infinity in the weights would surface only as a NaN output pixel
                // or a loss blamed on the learning rate; one pass over the values read names
                // the tensor instead.
                Ok((values, _)) => match values.iter().position(|v| !v.is_finite()) {
                    Some(i) => {
                        self.non_finite.push(format!("{key} ({} at index {i})", values[i]));
                        return None;
                    }
                    None => values,
                },
                Err(e) => {
                    self.unreadable.push(format!("{key}: {e}"));
                    return None;
                }
            },
            Source::Values { values, .. } => values.get(key).map(|(_, v)| v.clone()).unwrap_or_default(),
            Source::Random { .. } => unreachable!("random sources returned above"),
        };
        Some(match widen {
            Some(c) => widen_channels(&values, &found, c),
            None => values,
        })
    }

    /// A parameter tensor of `shape`. Where the file lacks it (an error `finish` reports
    /// before the model can run) the placeholder has every side 1.
    pub(crate) fn param<const D: usize>(&mut self, key: &str, shape: [usize; D], init: Init) -> Param<Tensor<D>> {
        let tensor = match self.values(key, &shape, init) {
            // 4-D parameters are convolution kernels.
            Some(values) if D == 4 => self.weight_tensor(key, values, shape),
            Some(values) => Tensor::from_data(TensorData::new(values, shape), &self.device),
            None => Tensor::zeros([1; D], &self.device),
        };
        let param = Param::from_tensor(tensor);
        self.names.push(NamedParam { id: param.id, key: key.to_string(), torch_shape: None });
        param
    }

    /// A weight stored PyTorch-style as `[d_out, in_shape…]` (a linear layer, or a
    /// convolution applied as one), returned transposed as `[d_in, d_out]` with `d_in` the
    /// product of `in_shape`, so the forward pass is `x · W`. Placeholder as in `param`.
    pub(crate) fn transposed_weight(
        &mut self,
        key: &str,
        d_out: usize,
        in_shape: &[usize],
        init: Init,
    ) -> Param<Tensor<2>> {
        let d_in: usize = in_shape.iter().product();
        let shape: Vec<usize> = std::iter::once(d_out).chain(in_shape.iter().copied()).collect();
        let tensor = match self.values(key, &shape, init) {
            Some(w) => {
                let mut t = vec![0.0f32; w.len()];
                for o in 0..d_out {
                    for i in 0..d_in {
                        t[i * d_out + o] = w[o * d_in + i];
                    }
                }
                self.weight_tensor(key, t, [d_in, d_out])
            }
            None => Tensor::zeros([1, 1], &self.device),
        };
        let param = Param::from_tensor(tensor);
        self.names.push(NamedParam { id: param.id, key: key.to_string(), torch_shape: Some(shape) });
        param
    }

    /// The key of every parameter built so far, in build order.
    pub(crate) fn take_names(&mut self) -> Vec<NamedParam> {
        std::mem::take(&mut self.names)
    }

    /// Marks file keys matching `ignore` as used (buffers such as CLIP's `position_ids`).
    pub(crate) fn ignore(&mut self, ignore: impl Fn(&str) -> bool) {
        if let Source::File { renamed, used, .. } = &mut self.source {
            for (name, file_key) in renamed.iter() {
                if ignore(name) {
                    used.insert(file_key.clone());
                }
            }
        }
    }

    /// Ok if every requested key was present with the right shape and every file key was
    /// used; otherwise one error listing every missing, unexpected and misshaped key.
    pub(crate) fn finish(self) -> Result<(), Error> {
        let (path, unexpected): (PathBuf, Vec<String>) = match self.source {
            Source::Random { .. } => return Ok(()),
            Source::File { file, renamed, used } => (
                file.path().to_path_buf(),
                renamed
                    .iter()
                    .filter(|(_, f)| !used.contains(*f))
                    .map(|(name, f)| if name == f { f.clone() } else { format!("{f} (read as {name})") })
                    .collect(),
            ),
            Source::Values { values, used } => {
                (PathBuf::from("<source model>"), values.keys().filter(|k| !used.contains(*k)).cloned().collect())
            }
        };
        if self.missing.is_empty()
            && self.wrong.is_empty()
            && unexpected.is_empty()
            && self.unreadable.is_empty()
            && self.non_finite.is_empty()
        {
            return Ok(());
        }
        let mut report = String::from("keys and shapes matching the model config;");
        for (title, list) in [
            ("missing", &self.missing),
            ("wrong shape", &self.wrong),
            ("unexpected", &unexpected),
            ("unreadable", &self.unreadable),
            ("not finite (NaN or infinite values)", &self.non_finite),
        ] {
            if !list.is_empty() {
                report.push_str(&format!("\n  {} {title}: {}", list.len(), list.join(", ")));
            }
        }
        Err(Error::format(path, "weights", report))
    }
}

/// Every float parameter of a module by id: `(dims, values)`.
pub(crate) fn parameter_values<M: Module>(module: &M) -> HashMap<ParamId, (Vec<usize>, Vec<f32>)> {
    struct Collect(HashMap<ParamId, (Vec<usize>, Vec<f32>)>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let tensor = param.val();
            let dims = tensor.dims().to_vec();
            // A tensor converts to f32 data of its own element count; anything else would be a
            // Burn invariant broken, kept visible as an empty entry that `collect_named` reports.
            let values = tensor.into_data().convert::<f32>().try_to_vec::<f32>().unwrap_or_default();
            self.0.insert(param.id, (dims, values));
        }
    }
    let mut collect = Collect(HashMap::new());
    module.visit(&mut collect);
    collect.0
}

/// A tensor under its checkpoint key, in PyTorch layout, as f32 values.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedValues {
    /// The checkpoint key.
    pub key: String,
    /// The PyTorch shape (`[d_out, …]` for linear and convolution weights).
    pub shape: Vec<usize>,
    /// Row-major values.
    pub values: Vec<f32>,
}

impl NamedValues {
    /// Values of the parameter `named` (Burn dims `dims`) turned into its PyTorch layout.
    pub(crate) fn from_param(named: &NamedParam, dims: Vec<usize>, values: Vec<f32>) -> Result<Self, Error> {
        if values.len() != dims.iter().product::<usize>() {
            return Err(Error::invalid(named.key.clone(), format!("f32 values for shape {dims:?}")));
        }
        let key = named.key.clone();
        match &named.torch_shape {
            Some(shape) if dims.len() == 2 => {
                let [d_in, d_out] = [dims[0], dims[1]];
                let mut t = vec![0.0f32; values.len()];
                for i in 0..d_in {
                    for o in 0..d_out {
                        t[o * d_in + i] = values[i * d_out + o];
                    }
                }
                Ok(Self { key, shape: shape.clone(), values: t })
            }
            Some(_) => Err(Error::invalid(key, format!("a transposed 2-D weight (found dims {dims:?})"))),
            None => Ok(Self { key, shape: dims, values }),
        }
    }
}

/// The parameters of `module` under their checkpoint keys, in PyTorch layout.
pub(crate) fn collect_named<M: Module>(module: &M, names: &[NamedParam]) -> Result<Vec<NamedValues>, Error> {
    let mut values = parameter_values(module);
    names
        .iter()
        .map(|named| {
            let (dims, v) = values
                .remove(&named.id)
                .ok_or_else(|| Error::invalid(named.key.clone(), "a parameter of the model being saved"))?;
            NamedValues::from_param(named, dims, v)
        })
        .collect()
}

/// Writes `config.json` and `weights_file` (f32 safetensors) into `dir` (created if missing),
/// both under temporary names first and then renamed.
pub(crate) fn write_checkpoint(
    dir: &Path,
    weights_file: &str,
    tensors: &[NamedValues],
    config: &serde_json::Value,
    precision: Precision,
) -> Result<(), Error> {
    write_checkpoint_named(dir, weights_file, tensors, "config.json", config, precision)
}

/// How a loaded model holds its linear and convolution weights (over 99.9 % of its
/// parameters) in memory; biases, norms and embeddings stay f32, and every layer widens its
/// weight to f32 when it runs, so the arithmetic is f32 whatever the storage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum WeightStorage {
    /// f32: the values of an f32 checkpoint exactly, 4 bytes each. What training needs (the
    /// optimizer updates the stored values), so the default of the `from_dir` loaders.
    #[default]
    F32,
    /// f16 for every weight: half the memory; weights of an f32 checkpoint are rounded to the
    /// nearest f16 (a relative change of at most 2⁻¹¹).
    F16,
    /// As the checkpoint stores each weight: f16 ones stay f16 (exact, and half the memory:
    /// the published Wonder3D weights and the shipped small model are f16), f32 and bf16 ones
    /// become f32. Lossless, so what generation uses (`wonder3d::Generator`).
    AsStored,
}

/// The number format weights are written in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Precision {
    /// 32-bit floats: exactly the values the model computes with.
    #[default]
    F32,
    /// IEEE half precision (what the published Wonder3D weights use): half the bytes; each
    /// value rounded to the nearest f16 (a relative change of at most 2⁻¹¹).
    F16,
}

/// As [`write_checkpoint`] with the JSON file named `json_file`.
pub(crate) fn write_checkpoint_named(
    dir: &Path,
    weights_file: &str,
    tensors: &[NamedValues],
    json_file: &str,
    config: &serde_json::Value,
    precision: Precision,
) -> Result<(), Error> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let encode = |values: &[f32]| -> Vec<u8> {
        match precision {
            Precision::F32 => values.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Precision::F16 => values.iter().flat_map(|x| half::f16::from_f32(*x).to_le_bytes()).collect(),
        }
    };
    let dtype = match precision {
        Precision::F32 => Dtype::F32,
        Precision::F16 => Dtype::F16,
    };
    let bytes: Vec<(String, Vec<usize>, Vec<u8>)> =
        tensors.iter().map(|t| (t.key.clone(), t.shape.clone(), encode(&t.values))).collect();
    let views = bytes
        .iter()
        .map(|(k, shape, b)| {
            safetensors::tensor::TensorView::new(dtype, shape.clone(), b).map(|view| (k.clone(), view))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| Error::invalid("checkpoint", format!("consistent tensor shapes ({e})")))?;
    let weights = safetensors::tensor::serialize(views, None)
        .map_err(|e| Error::invalid("checkpoint", format!("a serialisable set of tensors ({e})")))?;
    let config = serde_json::to_vec_pretty(config)
        .map_err(|e| Error::invalid("config", format!("a serialisable config ({e})")))?;
    let (weights_path, config_path) = (dir.join(weights_file), dir.join(json_file));
    w3d_core::io::write_atomic_all(&[(&weights_path, &weights), (&config_path, &config)])
}

/// `config` as a JSON object with `extra` fields added (class names a loader looks for; a
/// value is written as a one-element list when the key is `architectures`).
pub(crate) fn config_json<C: serde::Serialize>(config: &C, extra: &[(&str, &str)]) -> Result<serde_json::Value, Error> {
    let mut value =
        serde_json::to_value(config).map_err(|e| Error::invalid("config", format!("a serialisable config ({e})")))?;
    if let Some(map) = value.as_object_mut() {
        for (key, v) in extra {
            let v = if *key == "architectures" { serde_json::json!([v]) } else { serde_json::json!(v) };
            map.insert((*key).to_string(), v);
        }
    }
    Ok(value)
}

#[cfg(feature = "train")]
/// The id of every float parameter of `module`.
pub(crate) fn collect_named_ids<M: Module>(module: &M) -> Vec<ParamId> {
    struct Ids(Vec<ParamId>);
    impl ModuleVisitor for Ids {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.push(param.id);
        }
    }
    let mut ids = Ids(Vec::new());
    module.visit(&mut ids);
    ids.0
}
