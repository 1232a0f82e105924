//! The diffusion model from Python: `Generator` (image → 6 normal + 6 colour views),
//! `Pipeline` (image or views → textured mesh) and their results.

use std::path::PathBuf;
use std::sync::Arc;

use pyo3::prelude::*;
use wonder3d::diffusion::compute::Products;
use wonder3d::{ComputeDevice, Preset, TextureOptions};

use crate::arrays::{image_to_array, to_py_objects};
use crate::errors::{IntoPy, invalid};
use crate::job::{Reporter, run};
use crate::mesh::PyMesh;
use crate::stages::input_image;
use crate::views::PyViewSet;

/// The Wonder3D++ multi-view diffusion model, loaded once. weights: a checkpoint folder
/// (docs/weights.md) or a Hugging Face id such as "flamehaze1115/Wonder3D_plus" (downloaded
/// once into the Hugging Face cache; progress receives "download" events in bytes).
/// device: "cpu" or "wgpu" (a build with the wgpu feature). products: "auto" (the CLI's
/// default: bf16 matrix products where the CPU has AVX-512 BF16, f32 elsewhere), "f32" (the
/// reference arithmetic) or "bf16" (f32 with a warning on a CPU without it).
#[pyclass(name = "Generator", module = "wonder3d", frozen)]
pub struct PyGenerator {
    inner: Arc<wonder3d::Generator>,
    weights: String,
}

#[pymethods]
impl PyGenerator {
    #[new]
    #[pyo3(signature = (weights, device="cpu", products="auto", progress=None))]
    fn py_new(
        py: Python<'_>,
        weights: &Bound<'_, PyAny>,
        device: &str,
        products: &str,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Self> {
        let spec: String = if weights.hasattr("__fspath__")? {
            weights.extract::<PathBuf>()?.display().to_string()
        } else {
            weights.extract().map_err(|_| invalid("weights", "a folder or a Hugging Face id (str or os.PathLike)"))?
        };
        let device: ComputeDevice = device.parse().py_err()?;
        let products = match products {
            "auto" if Products::Bf16.supported() => Products::Bf16,
            "auto" => Products::F32,
            name => {
                let (products, note) = name.parse::<Products>().py_err()?.resolve();
                if let Some(note) = note {
                    PyErr::warn(
                        py,
                        &py.get_type::<pyo3::exceptions::PyUserWarning>(),
                        &std::ffi::CString::new(note)?,
                        1,
                    )?;
                }
                products
            }
        };
        let generator = run(py, progress, |reporter: &Reporter<'_>| {
            let dir = wonder3d::weights::resolve(&spec, &mut reporter.facade())?;
            let opened = device.open()?;
            let generator = wonder3d::Generator::load_on(dir, opened.device)?;
            let mut options = *generator.options();
            options.acceleration.pass.products = products;
            Ok(generator.with_options(options))
        })?;
        Ok(PyGenerator { inner: Arc::new(generator), weights: spec })
    }

    /// The 6 views of one image: a path, a PIL image or an (H, W, 3|4) array; an RGBA image
    /// whose alpha masks the object, or a photo whose background is removed first. steps,
    /// guidance, seed and draws override the sampling defaults for this call. progress
    /// receives "condition", one "denoise" event per step, and "decode". Ctrl-C stops it
    /// after the current step.
    #[pyo3(signature = (image, steps=None, guidance=None, seed=None, draws=None, progress=None))]
    #[allow(clippy::too_many_arguments)]
    fn generate(
        &self,
        py: Python<'_>,
        image: &Bound<'_, PyAny>,
        steps: Option<usize>,
        guidance: Option<f64>,
        seed: Option<u64>,
        draws: Option<usize>,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<PyGenerated> {
        let image = input_image(image, "image")?;
        let mut options = *self.inner.options();
        if let Some(steps) = steps {
            options.steps = steps;
        }
        if let Some(guidance) = guidance {
            options.guidance = guidance;
        }
        if let Some(seed) = seed {
            options.seed = seed;
        }
        if let Some(draws) = draws {
            options.draws = draws;
        }
        let generator = &self.inner;
        let generated = run(py, progress, |reporter: &Reporter<'_>| {
            // As `wonder3d generate` does: the photo prepared (background, framing) first,
            // then the model's own preprocessing of the framed RGBA image.
            let prepared = wonder3d::photo::prepare(&image, generator.prepare_options())?;
            generator.generate_with(&prepared.rgba, &options, &mut reporter.facade())
        })?;
        Ok(PyGenerated { inner: generated })
    }

    /// The sampling defaults: a dict of sampler, steps, guidance, eta, seed, draws.
    #[getter]
    fn options<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let o = self.inner.options();
        let dict = pyo3::types::PyDict::new(py);
        dict.set_item("sampler", format!("{:?}", o.sampler).to_lowercase())?;
        dict.set_item("steps", o.steps)?;
        dict.set_item("guidance", o.guidance)?;
        dict.set_item("eta", o.eta)?;
        dict.set_item("seed", o.seed)?;
        dict.set_item("draws", o.draws)?;
        dict.set_item("products", o.acceleration.pass.products.name())?;
        Ok(dict.into_any())
    }

    fn __repr__(&self) -> String {
        format!("Generator({:?})", self.weights)
    }
}

/// The views a Generator made of one image.
#[pyclass(name = "Generated", module = "wonder3d", frozen)]
pub struct PyGenerated {
    inner: wonder3d::Generated,
}

#[pymethods]
impl PyGenerated {
    /// The 6 generated views (normals, colours, masks) with their rig.
    #[getter]
    fn views(&self) -> PyViewSet {
        PyViewSet::new(self.inner.views.clone())
    }

    /// (S, S, 3|4) float32: the conditioning image the model saw.
    #[getter]
    fn input<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        image_to_array(py, &self.inner.input, false)
    }

    /// Writes the view set, input.png and views.png (a contact sheet) into a new folder, as
    /// `wonder3d generate --out` does, all at once.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| self.inner.save(&path)).py_err()
    }

    fn __repr__(&self) -> String {
        format!("Generated({})", self.views().__repr__())
    }
}

/// The whole job: an image (with a Generator) or a ViewSet → closed mesh → UV atlas and
/// baked texture. starts: fits tried on views passed to from_views (run() uses the
/// generated-view default, 4).
#[pyclass(name = "Pipeline", module = "wonder3d", frozen)]
pub struct PyPipeline {
    inner: wonder3d::Pipeline,
}

#[pymethods]
impl PyPipeline {
    #[new]
    #[pyo3(signature = (generator=None, preset="default", starts=None, texture_size=None, texture=true))]
    fn py_new(
        generator: Option<&PyGenerator>,
        preset: &str,
        starts: Option<usize>,
        texture_size: Option<u32>,
        texture: bool,
    ) -> PyResult<Self> {
        let mut pipeline = wonder3d::Pipeline::new().with_preset(preset.parse::<Preset>().py_err()?);
        if let Some(starts) = starts {
            pipeline = pipeline.with_starts(starts);
        }
        if texture {
            let mut options = TextureOptions::default();
            if let Some(size) = texture_size {
                options = options.with_size(size);
            }
            options.validate().py_err()?;
            pipeline = pipeline.with_texture_options(options);
        } else {
            pipeline = pipeline.without_texture();
        }
        if let Some(generator) = generator {
            pipeline = pipeline.with_model(Arc::clone(&generator.inner));
        }
        Ok(PyPipeline { inner: pipeline })
    }

    /// One image (path, PIL image or array) → generated views → textured mesh. Needs a
    /// generator.
    #[pyo3(signature = (image, progress=None))]
    fn run(&self, py: Python<'_>, image: &Bound<'_, PyAny>, progress: Option<Py<PyAny>>) -> PyResult<PyOutput> {
        if !self.inner.has_model() {
            return Err(invalid("Pipeline.run", "a Pipeline(generator=Generator(...)); use from_views for views"));
        }
        let image = input_image(image, "image")?;
        let pipeline = &self.inner;
        run(py, progress, |reporter: &Reporter<'_>| pipeline.from_image(&image, &mut reporter.facade()))
            .map(|inner| PyOutput { inner })
    }

    /// A view set → closed mesh → textured mesh.
    #[pyo3(signature = (views, progress=None))]
    #[allow(clippy::wrong_self_convention, reason = "the facade's Pipeline::from_views, by name")]
    fn from_views(&self, py: Python<'_>, views: &PyViewSet, progress: Option<Py<PyAny>>) -> PyResult<PyOutput> {
        let pipeline = &self.inner;
        run(py, progress, |reporter: &Reporter<'_>| pipeline.from_views(&views.inner, &mut reporter.facade()))
            .map(|inner| PyOutput { inner })
    }

    fn __repr__(&self) -> String {
        format!("Pipeline({:?})", self.inner)
    }
}

/// What a Pipeline made.
#[pyclass(name = "Output", module = "wonder3d", frozen)]
pub struct PyOutput {
    inner: wonder3d::Output,
}

#[pymethods]
impl PyOutput {
    /// The textured mesh (the closed mesh when texturing was off).
    #[getter]
    fn mesh(&self) -> PyMesh {
        PyMesh::new(self.inner.mesh.clone())
    }

    /// The closed mesh before texturing.
    #[getter]
    fn geometry(&self) -> PyMesh {
        PyMesh::new(self.inner.geometry.clone())
    }

    /// The views the mesh was made from (generated ones for run()).
    #[getter]
    fn views(&self) -> PyViewSet {
        PyViewSet::new(self.inner.views.clone())
    }

    /// The conditioning image the model saw, or None for from_views.
    #[getter]
    fn input<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.inner.input.as_ref().map(|i| image_to_array(py, i, false)).transpose()
    }

    /// The report as a dict: preset, triangles, seconds per stage, reconstruction,
    /// texture and generation details (the keys of report.json).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py_objects(py, &self.inner.report, "report")
    }

    /// Writes the mesh (.glb, .obj or .ply), all at once.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| self.inner.save(&path)).py_err()
    }

    fn __repr__(&self) -> String {
        format!("Output({})", self.mesh().__repr__())
    }
}
