//! The stages as functions: `reconstruct`, `texture`, `evaluate`, `prepare_image`, `refine`,
//! each the same call the CLI makes, so the numbers are the CLI's.

use std::path::PathBuf;

use pyo3::prelude::*;
use wonder3d::refine::{DiffusionEnhancer, Enhancer, IdentityEnhancer, OracleEnhancer, RefineOptions, RefineStep};
use wonder3d::{Image, Pipeline, PrepareOptions, Preset, Progress, Stage, TextureOptions};

use crate::arrays::{image_to_array, to_py_objects};
use crate::errors::{IntoPy, invalid};
use crate::job::{ProgressEvent, Reporter, run};
use crate::mesh::PyMesh;
use crate::views::PyViewSet;

/// A preset by name.
fn preset(name: &str) -> PyResult<Preset> {
    name.parse::<Preset>().py_err()
}

/// The closed mesh of a view set (`wonder3d reconstruct`): initialisation from the normal
/// maps, then the coarse optimisation with continuous remeshing, untangling and polishing.
/// preset: "fast", "default" or "quality"; starts: fits tried, the best kept (views from
/// generation gain from 4). progress(event) receives one ProgressEvent per step. Releases
/// the GIL; Ctrl-C stops it within milliseconds (KeyboardInterrupt).
#[pyfunction]
#[pyo3(signature = (views, preset="default", starts=1, progress=None))]
pub fn reconstruct(
    py: Python<'_>,
    views: &PyViewSet,
    preset: &str,
    starts: usize,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyMesh> {
    let pipeline = Pipeline::new().with_preset(self::preset(preset)?).with_starts(starts).without_texture();
    let output =
        run(py, progress, |reporter: &Reporter<'_>| pipeline.from_views(&views.inner, &mut reporter.facade()))?;
    Ok(PyMesh::new(output.mesh))
}

/// A UV atlas and a size × size texture baked from the views' colours (`wonder3d texture`):
/// the returned mesh has vertices split along chart seams, uvs, normals and the texture.
/// The mesh must be in the views' frame (as `reconstruct` returns it).
#[pyfunction]
#[pyo3(signature = (mesh, views, size=None, progress=None))]
pub fn texture(
    py: Python<'_>,
    mesh: &PyMesh,
    views: &PyViewSet,
    size: Option<u32>,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyMesh> {
    let mut options = TextureOptions::default();
    if let Some(size) = size {
        options = options.with_size(size);
    }
    options.validate().py_err()?;
    let mut geometry = mesh.inner.clone().without_attributes();
    geometry.orient_outward();
    let textured = run(py, progress, |reporter: &Reporter<'_>| {
        wonder3d::texture::bake_with_progress(&geometry, &views.inner, &options, &mut |stage| {
            reporter.report(Progress::new(Stage::Texture(stage.into()), 0, 1, None).into())
        })
    })?;
    Ok(PyMesh::new(textured.mesh))
}

/// Geometry metrics of a prediction against a ground truth, the keys and values of
/// `wonder3d eval --json`: chamfer (and both directions), fscore/precision/recall at 0.01
/// and 0.02, volume IoU at 64³ and 128³, normal consistency, samples, seed. The ground
/// truth is normalised into the unit cube; the prediction too with normalize_pred=True.
#[pyfunction]
#[pyo3(signature = (pred, gt, samples=None, seed=0, normalize_pred=false))]
pub fn evaluate<'py>(
    py: Python<'py>,
    pred: &PyMesh,
    gt: &PyMesh,
    samples: Option<usize>,
    seed: u64,
    normalize_pred: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let mut options = wonder3d::eval::EvalOptions::default().with_seed(seed).with_normalize_pred(false);
    if let Some(samples) = samples {
        options = options.with_samples(samples);
    }
    let (mut pred, mut gt) = (pred.inner.clone(), gt.inner.clone());
    wonder3d::check_surface(&pred, "pred").py_err()?;
    wonder3d::check_surface(&gt, "gt").py_err()?;
    pred.orient_outward();
    gt.orient_outward();
    gt.normalize_unit_cube();
    if normalize_pred {
        pred.normalize_unit_cube();
    }
    let metrics = py.detach(|| wonder3d::eval::evaluate(&pred, &gt, &options)).py_err()?;
    to_py_objects(py, &metrics, "metrics")
}

/// An image argument: a path (str or os.PathLike), a PIL image, or an (H, W, 3|4) array
/// (uint8, or float in [0, 1]).
pub fn input_image(value: &Bound<'_, PyAny>, name: &str) -> PyResult<Image> {
    let py = value.py();
    if value.is_instance_of::<pyo3::types::PyString>() || value.hasattr("__fspath__")? {
        let path: PathBuf = value.extract()?;
        return py.detach(|| Image::read(&path)).py_err();
    }
    let array = if value.hasattr("convert")? && value.hasattr("mode")? {
        // A PIL image: its RGBA pixels.
        py.import("numpy")?.call_method1("asarray", (value.call_method1("convert", ("RGBA",))?,))?
    } else {
        py.import("numpy")?
            .call_method1("asarray", (value,))
            .map_err(|_| invalid(name, "a path, a PIL image or an array"))?
    };
    let shape: Vec<usize> = array.getattr("shape")?.extract()?;
    let kind: String = array.getattr("dtype")?.getattr("kind")?.extract()?;
    let channels = match shape.as_slice() {
        [h, w, c @ (3 | 4)] if *h > 0 && *w > 0 => *c,
        _ => return Err(invalid(name, format!("an (H, W, 3) or (H, W, 4) image, got shape {shape:?}"))),
    };
    let scaled = match kind.as_str() {
        "u" if array.getattr("dtype")?.getattr("itemsize")?.extract::<usize>()? == 1 => {
            array.call_method1("astype", ("float32",))?.call_method1("__truediv__", (255.0f32,))?
        }
        "f" => array,
        _ => return Err(invalid(name, format!("a uint8 or float image, got dtype {}", array.getattr("dtype")?))),
    };
    crate::arrays::image(&scaled, name, channels)
}

/// An image prepared for the model (`prepare_image`).
#[pyclass(name = "PreparedImage", module = "wonder3d", frozen)]
pub struct PyPrepared {
    inner: wonder3d::Prepared,
}

#[pymethods]
impl PyPrepared {
    /// (S, S, 4) float32 RGBA with straight alpha, the object framed as the model expects.
    #[getter]
    fn rgba<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        image_to_array(py, &self.inner.rgba, false)
    }

    /// (H, W) float32 mask of the object at the input's resolution.
    #[getter]
    fn mask<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        image_to_array(py, &self.inner.mask, true)
    }

    /// "alpha" (the image's own) or "segmented" (background removed here).
    #[getter]
    fn source(&self) -> &'static str {
        self.inner.source.name()
    }

    /// How far to trust the mask, in [0, 1] (1 for the image's own alpha).
    #[getter]
    fn confidence(&self) -> f32 {
        self.inner.confidence.score
    }

    fn __repr__(&self) -> String {
        format!(
            "PreparedImage({}×{}, source={:?}, confidence={:.3})",
            self.inner.rgba.width(),
            self.inner.rgba.height(),
            self.inner.source.name(),
            self.inner.confidence.score
        )
    }
}

/// A photo (path, PIL image or array) made ready for the model, as `wonder3d prepare` does:
/// its own alpha when it has a meaningful one, else automatic background removal (refused
/// with the reasons below min_confidence: InvalidInputError), then cropped and centred.
#[pyfunction]
#[pyo3(signature = (image, min_confidence=None, crop=true))]
pub fn prepare_image(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    min_confidence: Option<f32>,
    crop: bool,
) -> PyResult<PyPrepared> {
    let mut options = PrepareOptions::default();
    options.crop = crop;
    if let Some(min) = min_confidence {
        options.min_confidence = min;
    }
    let pixels = input_image(image, "image")?;
    let prepared = py.detach(|| wonder3d::photo::prepare(&pixels, &options)).py_err()?;
    Ok(PyPrepared { inner: prepared })
}

/// The result of `refine`.
#[pyclass(name = "Refined", module = "wonder3d", frozen)]
pub struct PyRefined {
    inner: wonder3d::refine::Refined,
}

#[pymethods]
impl PyRefined {
    /// The refined, textured mesh.
    #[getter]
    fn mesh(&self) -> PyMesh {
        PyMesh::new(self.inner.mesh.clone())
    }

    /// The refined closed mesh without texture.
    #[getter]
    fn geometry(&self) -> PyMesh {
        PyMesh::new(self.inner.geometry.clone())
    }

    /// The refinement report (per iteration: mesh fit, bake, texture refinement, seconds).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py_objects(py, &self.inner.report, "report")
    }
}

/// Wonder3D++'s refinement (`wonder3d refine`): render the textured mesh, enhance the
/// renders, refit the mesh to them and project the enhanced colours into the texture,
/// `iterations` times. enhancer: None or "identity", a Mesh (the oracle: renders of a known
/// mesh), or the diffusion enhancer's weights (a folder or a Hugging Face id,
/// docs/weights.md). views must carry colours.
#[pyfunction]
#[pyo3(signature = (geometry, views, enhancer=None, iterations=2, size=512, texture_size=None, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn refine(
    py: Python<'_>,
    geometry: &PyMesh,
    views: &PyViewSet,
    enhancer: Option<Py<PyAny>>,
    iterations: usize,
    size: u32,
    texture_size: Option<u32>,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyRefined> {
    let mut options = RefineOptions::default().with_iterations(iterations).with_size(size);
    if let Some(texture_size) = texture_size {
        options = options.with_texture(TextureOptions::default().with_size(texture_size));
    }
    options.texture.validate().py_err()?;
    enum Choice {
        Identity,
        Oracle(wonder3d::Mesh),
        Diffusion(String),
    }
    let choice = match enhancer.as_ref().map(|e| e.bind(py)) {
        None => Choice::Identity,
        Some(e) if e.is_instance_of::<PyMesh>() => {
            let mut truth = e.cast::<PyMesh>()?.get().inner.clone();
            truth.orient_outward();
            Choice::Oracle(truth)
        }
        Some(e) => match e.extract::<String>() {
            Ok(name) if name == "identity" => Choice::Identity,
            Ok(name) if !name.is_empty() => Choice::Diffusion(name),
            _ => {
                return Err(invalid(
                    "enhancer",
                    "\"identity\", a Mesh (the oracle) or the enhancer's weights (a folder or a Hub id)",
                ));
            }
        },
    };
    let refined = run(py, progress, |reporter: &Reporter<'_>| {
        let enhancer: Box<dyn Enhancer> = match choice {
            Choice::Identity => Box::new(IdentityEnhancer),
            Choice::Oracle(truth) => Box::new(OracleEnhancer::new(truth)),
            Choice::Diffusion(weights) => {
                Box::new(DiffusionEnhancer::from_pretrained(&weights, &mut reporter.facade())?)
            }
        };
        wonder3d::refine::refine(&geometry.inner, &views.inner, enhancer.as_ref(), &options, &mut |p| {
            let (stage, done, total, loss) = match p.step {
                RefineStep::Enhancing => ("enhance", 0, 1, None),
                RefineStep::Fitting { done, total, loss } => ("fit", done, total, Some(loss)),
                RefineStep::Texturing => ("texture", 0, 1, None),
                _ => ("refine", 0, 1, None),
            };
            reporter.report(ProgressEvent { stage: stage.into(), done, total, loss, iteration: Some(p.iteration) })
        })
    })?;
    Ok(PyRefined { inner: refined })
}
