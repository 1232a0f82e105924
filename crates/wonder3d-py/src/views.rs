//! `wonder3d.ViewSet` (a rig and the normal, mask and colour images of each view, the input
//! of reconstruction and texturing) and `render_views` (oracle views of a known mesh).

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::PyList;
use wonder3d::raster::MAX_VIEW_SIZE;
use wonder3d::{ViewImages, ViewRig, ViewSet};

use crate::arrays::{image, image_to_array};
use crate::errors::{IntoPy, invalid};
use crate::mesh::PyMesh;

/// The views of one object: a rig (named cameras) and, per view, a unit-normal image, a
/// mask and optionally a colour image, all the same size. Immutable.
#[pyclass(name = "ViewSet", module = "wonder3d", frozen)]
#[derive(Debug, Clone)]
pub struct PyViewSet {
    /// The core view set.
    pub inner: ViewSet,
}

impl PyViewSet {
    /// Wraps a core view set.
    pub fn new(inner: ViewSet) -> Self {
        PyViewSet { inner }
    }

    /// One array per view, stacked into a (V, …) array.
    fn stacked<'py>(
        &self,
        py: Python<'py>,
        pick: impl Fn(&ViewImages) -> Option<&wonder3d::Image>,
        squeeze: bool,
    ) -> PyResult<Option<Bound<'py, PyAny>>> {
        let mut arrays = Vec::new();
        for view in self.inner.views() {
            match pick(view) {
                Some(image) => arrays.push(image_to_array(py, image, squeeze)?),
                None => return Ok(None),
            }
        }
        Ok(Some(py.import("numpy")?.call_method1("stack", (PyList::new(py, arrays)?,))?))
    }
}

/// The items of a per-view argument: a (V, …) array or a sequence of V arrays.
fn per_view<'py>(value: &Bound<'py, PyAny>, name: &str, views: usize) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let items: Vec<Bound<'py, PyAny>> = value
        .try_iter()
        .map_err(|_| invalid(name, format!("one array per view ({views} views)")))?
        .collect::<PyResult<_>>()?;
    if items.len() != views {
        return Err(invalid(name, format!("one array per view of the rig ({views}), got {}", items.len())));
    }
    Ok(items)
}

#[pymethods]
impl PyViewSet {
    /// Reads a view-set folder as `wonder3d render` or `wonder3d generate` writes it
    /// (cameras.json, normal_<view>.png|exr, mask_<view>.png, colour_<view>.png).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        py.detach(|| ViewSet::load(&path)).py_err().map(PyViewSet::new)
    }

    /// normals: (V, H, W, 3) float array or V arrays of (H, W, 3), unit normals in the
    /// canonical frame (zero on the background); masks: (V, H, W) or V arrays of (H, W), in
    /// [0, 1]; colours: (V, H, W, 3) sRGB in [0, 1], or None; rig: "wonder3d-ortho",
    /// "wonder3d-persp" or "syncdreamer16" (V must match it).
    #[staticmethod]
    #[pyo3(signature = (normals, masks, colours=None, rig="wonder3d-ortho"))]
    fn from_arrays(
        normals: &Bound<'_, PyAny>,
        masks: &Bound<'_, PyAny>,
        colours: Option<&Bound<'_, PyAny>>,
        rig: &str,
    ) -> PyResult<Self> {
        let rig = ViewRig::by_name(rig).py_err()?;
        let n = rig.len();
        let normals = per_view(normals, "normals", n)?;
        let masks = per_view(masks, "masks", n)?;
        let colours = colours.map(|c| per_view(c, "colours", n)).transpose()?;
        let mut views = Vec::with_capacity(n);
        for (i, view) in rig.views.iter().enumerate() {
            views.push(ViewImages {
                name: view.name.clone(),
                normal: image(&normals[i], &format!("normals[{i}]"), 3)?,
                mask: image(&masks[i], &format!("masks[{i}]"), 1)?,
                colour: colours.as_ref().map(|c| image(&c[i], &format!("colours[{i}]"), 3)).transpose()?,
                depth: None,
            });
        }
        ViewSet::new(rig, views).py_err().map(PyViewSet::new)
    }

    /// Writes the folder layout of `wonder3d render`, all at once: a failure leaves the
    /// folder as it was. The folder must be new or empty, or a view set itself.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| self.inner.save(&path)).py_err()
    }

    /// The rig's name (e.g. "wonder3d_ortho").
    #[getter]
    fn rig(&self) -> String {
        self.inner.rig().name.clone()
    }

    /// The view names, in rig order.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.inner.rig().views.iter().map(|v| v.name.clone()).collect()
    }

    /// Image width in pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.inner.width()
    }

    /// Image height in pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height()
    }

    /// (V, H, W, 3) float32 unit normals in the canonical frame (zero on the background).
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        Ok(self.stacked(py, |v| Some(&v.normal), false)?.expect("every view has a normal"))
    }

    /// (V, H, W) float32 foreground masks in [0, 1].
    #[getter]
    fn masks<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        Ok(self.stacked(py, |v| Some(&v.mask), true)?.expect("every view has a mask"))
    }

    /// (V, H, W, 3) float32 sRGB colours in [0, 1], or None when the views have none.
    #[getter]
    fn colours<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.stacked(py, |v| v.colour.as_ref(), false)
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    pub fn __repr__(&self) -> String {
        let colours = if self.inner.views().iter().all(|v| v.colour.is_some()) { ", with colours" } else { "" };
        format!(
            "ViewSet(rig={:?}, {} views of {}×{}{colours})",
            self.inner.rig().name,
            self.inner.len(),
            self.inner.width(),
            self.inner.height()
        )
    }
}

/// Oracle views of a known mesh, as `wonder3d render` makes them: a closed mesh wound
/// inward is flipped outward, the mesh is normalised into the unit cube (unless
/// normalize=False), and the rig's cameras render normals, masks and depth (and colours
/// where the mesh has them) at size × size pixels.
#[pyfunction]
#[pyo3(signature = (mesh, rig="wonder3d-ortho", size=256, normalize=true))]
pub fn render_views(py: Python<'_>, mesh: &PyMesh, rig: &str, size: u32, normalize: bool) -> PyResult<PyViewSet> {
    let rig = ViewRig::by_name(rig).py_err()?;
    if size == 0 || size > MAX_VIEW_SIZE {
        return Err(invalid("size", format!("1 to {MAX_VIEW_SIZE} pixels, got {size}")));
    }
    let mut mesh = mesh.inner.clone();
    mesh.orient_outward();
    if normalize {
        mesh.normalize_unit_cube();
    }
    py.detach(|| wonder3d::raster::render_oracle_views(&mesh, &rig, size)).py_err().map(PyViewSet::new)
}
