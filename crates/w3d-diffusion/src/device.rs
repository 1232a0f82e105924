//! Choosing where the models run at run time: [`ComputeDevice`] names a device (the CLI's
//! `--device cpu|wgpu`) and [`ComputeDevice::open`] turns it into a Burn [`Device`] with a
//! description of what was found.
//!
//! The CPU is always there (Burn's `flex` backend). The GPU goes through Burn's wgpu backend
//! (Vulkan, Metal, DirectX 12), which is compiled only with this crate's `wgpu` feature, so a
//! build without it answers `wgpu` with an error that says how to get it instead of
//! silently running on the CPU. Software Vulkan drivers (Mesa's lavapipe / llvmpipe) are
//! accepted and reported as such: they run the same shaders as a GPU, which is how the GPU
//! path is checked on machines without one (`cargo xtask gpu-check`, `docs/gpu.md`), but they
//! are much slower than the CPU backend.

use std::fmt;
use std::str::FromStr;

use w3d_core::Error;

use burn::tensor::Device;

/// Where the diffusion models run. `Cpu` is the default; the names are the CLI's `--device`
/// values ([`ComputeDevice::NAMES`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[non_exhaustive]
pub enum ComputeDevice {
    /// The CPU through Burn's `flex` backend ([`crate::default_device`]), on all cores.
    #[default]
    Cpu,
    /// The system's preferred wgpu adapter through Burn's wgpu backend (feature `wgpu`).
    Wgpu,
}

/// A [`ComputeDevice`] opened for use: the Burn device and what it is.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct OpenedDevice {
    /// The Burn device to load models and create tensors on.
    pub device: Device,
    /// Which device was chosen.
    pub kind: ComputeDevice,
    /// A one-line description for logs: the backend, and for wgpu the adapter's name, driver
    /// and graphics API.
    pub description: String,
    /// Whether the adapter is a software (CPU) implementation of a GPU API, such as Mesa's
    /// llvmpipe: correct but far slower than [`ComputeDevice::Cpu`].
    pub software: bool,
}

impl ComputeDevice {
    /// Every device name [`ComputeDevice::from_name`] accepts, in declaration order.
    pub const NAMES: [&'static str; 2] = ["cpu", "wgpu"];

    /// The device's name (`"cpu"`, `"wgpu"`).
    pub fn name(self) -> &'static str {
        match self {
            ComputeDevice::Cpu => "cpu",
            ComputeDevice::Wgpu => "wgpu",
        }
    }

    /// The device called `name` (one of [`ComputeDevice::NAMES`], ASCII case-insensitive).
    pub fn from_name(name: &str) -> Result<ComputeDevice, Error> {
        match name.to_ascii_lowercase().as_str() {
            "cpu" => Ok(ComputeDevice::Cpu),
            "wgpu" | "gpu" => Ok(ComputeDevice::Wgpu),
            _ => Err(Error::invalid("device", format!("one of cpu, wgpu (found {name:?})"))),
        }
    }

    /// Whether this build can open the device at all: `Cpu` always, `Wgpu` only with the
    /// `wgpu` feature (whether an adapter exists is known only when [`ComputeDevice::open`]
    /// asks the driver).
    pub fn is_compiled(self) -> bool {
        match self {
            ComputeDevice::Cpu => true,
            ComputeDevice::Wgpu => cfg!(feature = "wgpu"),
        }
    }

    /// Opens the device. For `Wgpu` the first call initialises Burn's wgpu runtime on the
    /// preferred adapter (a hardware GPU when there is one; the `CUBECL_WGPU_DEFAULT_DEVICE`
    /// variable overrides the choice, see `docs/gpu.md`) and later calls return the same
    /// device. Errors: `Wgpu` in a build without the `wgpu` feature, or no usable adapter
    /// (the driver's message is included).
    pub fn open(self) -> Result<OpenedDevice, Error> {
        match self {
            ComputeDevice::Cpu => Ok(OpenedDevice {
                device: default_device(),
                kind: self,
                description: format!(
                    "cpu (Burn flex backend, {} threads)",
                    std::thread::available_parallelism().map_or(1, |n| n.get())
                ),
                software: false,
            }),
            ComputeDevice::Wgpu => open_wgpu(),
        }
    }
}

impl fmt::Display for ComputeDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for ComputeDevice {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self, Error> {
        ComputeDevice::from_name(s)
    }
}

#[cfg(not(feature = "wgpu"))]
fn open_wgpu() -> Result<OpenedDevice, Error> {
    Err(Error::invalid(
        "device wgpu",
        "a build with the `wgpu` feature (`cargo install wonder3d-cli --features wgpu`, see \
         docs/gpu.md); this build runs on the CPU only",
    ))
}

#[cfg(feature = "wgpu")]
fn open_wgpu() -> Result<OpenedDevice, Error> {
    use std::sync::OnceLock;

    // Burn's wgpu runtime can be initialised once per process; the first outcome is kept.
    static OPENED: OnceLock<Result<OpenedDevice, String>> = OnceLock::new();
    OPENED
        .get_or_init(|| {
            let (device, setup) = Device::wgpu_options()
                .init_with_setup()
                .map_err(|e| format!("a wgpu adapter (Vulkan, Metal or DirectX 12): {e}"))?;
            let info = setup.adapter.get_info();
            let software = info.device_type == burn::tensor::wgpu::wgpu::DeviceType::Cpu;
            let mut description = format!("wgpu: {} ({:?}", info.name, info.backend);
            if !info.driver_info.is_empty() {
                description.push_str(&format!(", {}", info.driver_info));
            }
            description.push(')');
            if software {
                description.push_str(", a software adapter: far slower than --device cpu");
            }
            Ok(OpenedDevice { device, kind: ComputeDevice::Wgpu, description, software })
        })
        .clone()
        .map_err(|expected| Error::invalid("device wgpu", expected))
}

/// A hardware GPU through wgpu (feature `wgpu`): `None` when no adapter exists or when the
/// only one is a software (CPU) adapter such as Mesa llvmpipe, which is far slower than
/// [`crate::default_device`]. Shares the runtime [`ComputeDevice::open`] initialises.
#[cfg(feature = "wgpu")]
pub fn gpu_device() -> Option<Device> {
    ComputeDevice::Wgpu.open().ok().filter(|o| !o.software).map(|o| o.device)
}

/// The default CPU device: Burn's `flex` backend (gemm-crate matmul, rayon threads), measured
/// faster than `ndarray` on this crate's models (see `docs/benchmarks.md`).
pub fn default_device() -> Device {
    Device::flex()
}

/// Burn's `ndarray` CPU backend (feature `ndarray`; deprecated in Burn 0.22): the second CPU
/// backend the parity tests and benches run on when the feature is on.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
pub fn ndarray_device() -> Device {
    Device::ndarray()
}
