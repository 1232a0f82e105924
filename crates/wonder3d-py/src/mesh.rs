//! `wonder3d.Mesh`: a triangle mesh with optional normals, uvs, vertex colours and texture,
//! in and out as numpy arrays, from and to every mesh format the core reads and writes, and
//! to and from `trimesh`.

use std::path::PathBuf;

use pyo3::prelude::*;
use wonder3d::{Image, Mesh};

use crate::arrays::{float_rows, image, image_to_array, rows_to_array, triangles};
use crate::errors::{IntoPy, invalid};

/// A triangle mesh. Immutable: the array properties return copies.
///
/// Mesh(vertices, faces, *, normals=None, uvs=None, colours=None, texture=None):
/// vertices: (N, 3) float array (float64 is rounded to float32); faces: (M, 3) integer
/// array of vertex indices; normals: (N, 3) float; uvs: (N, 2) float, origin at the
/// bottom left; colours: (N, 3) sRGB floats in [0, 1]; texture: (H, W, 3) sRGB floats in
/// [0, 1] (needs uvs). Raises InvalidInputError naming the array at fault.
#[pyclass(name = "Mesh", module = "wonder3d", frozen)]
#[derive(Debug, Clone)]
pub struct PyMesh {
    /// The core mesh.
    pub inner: Mesh,
}

impl PyMesh {
    /// Wraps a core mesh.
    pub fn new(inner: Mesh) -> Self {
        PyMesh { inner }
    }
}

#[pymethods]
impl PyMesh {
    /// A mesh from arrays, each checked (shape, dtype, finite values, indices in range; see
    /// the class).
    #[new]
    #[pyo3(signature = (vertices, faces, *, normals=None, uvs=None, colours=None, texture=None))]
    fn py_new(
        vertices: &Bound<'_, PyAny>,
        faces: &Bound<'_, PyAny>,
        normals: Option<&Bound<'_, PyAny>>,
        uvs: Option<&Bound<'_, PyAny>>,
        colours: Option<&Bound<'_, PyAny>>,
        texture: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let positions = float_rows::<3>(vertices, "vertices")?;
        let tris = triangles(faces, "faces", positions.len())?;
        let mut mesh = Mesh::new(positions, tris).py_err()?;
        if let Some(normals) = normals {
            mesh = mesh.with_normals(float_rows::<3>(normals, "normals")?).py_err()?;
        }
        if let Some(uvs) = uvs {
            mesh = mesh.with_uvs(float_rows::<2>(uvs, "uvs")?).py_err()?;
        }
        if let Some(colours) = colours {
            mesh = mesh.with_colours(float_rows::<3>(colours, "colours")?).py_err()?;
        }
        if let Some(texture) = texture {
            mesh = mesh.with_texture(image(texture, "texture", 3)?).py_err()?;
        }
        Ok(PyMesh::new(mesh))
    }

    /// Reads an .obj, .ply, .glb or .gltf file (the format from the extension). Raises
    /// FileError when it cannot be read, FormatError when its contents are wrong.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        py.detach(|| wonder3d::load_mesh(&path)).py_err().map(PyMesh::new)
    }

    /// Writes an .obj (+ .mtl and .png when textured), .ply or .glb file, all at once
    /// (a failure leaves no partial file).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| wonder3d::save_mesh(&path, &self.inner)).py_err()
    }

    /// (N, 3) float32 vertex positions.
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_to_array(py, self.inner.positions())
    }

    /// (M, 3) uint32 vertex indices, counter-clockwise seen from outside.
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_to_array(py, self.inner.triangles())
    }

    /// (N, 3) float32 vertex normals, or None.
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.inner.normals().map(|n| rows_to_array(py, n)).transpose()
    }

    /// (N, 2) float32 texture coordinates (origin bottom left), or None.
    #[getter]
    fn uvs<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.inner.uvs().map(|n| rows_to_array(py, n)).transpose()
    }

    /// (N, 3) float32 sRGB vertex colours in [0, 1], or None.
    #[getter]
    fn colours<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.inner.colours().map(|n| rows_to_array(py, n)).transpose()
    }

    /// (H, W, 3) float32 sRGB texture in [0, 1] (row 0 at the top), or None.
    #[getter]
    fn texture<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.inner.texture().map(|t| image_to_array(py, t, false)).transpose()
    }

    /// Number of vertices.
    #[getter]
    fn vertex_count(&self) -> usize {
        self.inner.vertex_count()
    }

    /// Number of triangles.
    #[getter]
    fn triangle_count(&self) -> usize {
        self.inner.triangle_count()
    }

    /// True when every edge joins exactly two triangles (after welding equal positions).
    #[getter]
    fn is_watertight(&self) -> bool {
        self.inner.topology().is_watertight()
    }

    /// Total triangle area.
    #[getter]
    fn surface_area(&self) -> f64 {
        self.inner.surface_area()
    }

    /// ((min x, y, z), (max x, y, z)) of the vertices.
    #[getter]
    fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let (lo, hi) = self.inner.bbox();
        (lo.to_array(), hi.to_array())
    }

    /// The same vertices and faces (process=False: nothing merged or reordered), with the
    /// normals, the vertex colours or the texture (a PIL image, when Pillow is installed).
    fn to_trimesh<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let trimesh = py.import("trimesh").map_err(|e| {
            pyo3::exceptions::PyImportError::new_err(format!(
                "Mesh.to_trimesh needs trimesh (pip install trimesh): {e}"
            ))
        })?;
        let kwargs = pyo3::types::PyDict::new(py);
        kwargs.set_item("vertices", self.vertices(py)?)?;
        kwargs.set_item("faces", self.faces(py)?)?;
        kwargs.set_item("process", false)?;
        if let Some(normals) = self.normals(py)? {
            kwargs.set_item("vertex_normals", normals)?;
        }
        let visual = pyo3::types::PyModule::import(py, "trimesh.visual")?;
        if let (Some(uvs), Some(texture)) = (self.inner.uvs(), self.inner.texture()) {
            let image = py.import("PIL.Image")?.call_method1("fromarray", (srgb_bytes(py, texture)?,))?;
            let visuals = visual.getattr("TextureVisuals")?.call((rows_to_array(py, uvs)?,), None)?;
            visuals.getattr("material")?.setattr("image", image)?;
            kwargs.set_item("visual", visuals)?;
        } else if let Some(colours) = self.inner.colours() {
            let bytes: Vec<[u8; 4]> = colours.iter().map(|c| [byte(c[0]), byte(c[1]), byte(c[2]), 255]).collect();
            kwargs.set_item("vertex_colors", rows_to_array(py, &bytes)?)?;
        }
        trimesh.getattr("Trimesh")?.call((), Some(&kwargs))
    }

    /// The vertices and faces of a trimesh.Trimesh (float64 positions rounded to float32).
    #[staticmethod]
    fn from_trimesh(mesh: &Bound<'_, PyAny>) -> PyResult<Self> {
        let vertices = mesh.getattr("vertices").map_err(|_| invalid("mesh", "a trimesh.Trimesh (no .vertices)"))?;
        let faces = mesh.getattr("faces").map_err(|_| invalid("mesh", "a trimesh.Trimesh (no .faces)"))?;
        PyMesh::py_new(&vertices, &faces, None, None, None, None)
    }

    pub fn __repr__(&self) -> String {
        let mut extras = Vec::new();
        if self.inner.normals().is_some() {
            extras.push("normals");
        }
        if self.inner.uvs().is_some() {
            extras.push("uvs");
        }
        if self.inner.colours().is_some() {
            extras.push("colours");
        }
        if self.inner.texture().is_some() {
            extras.push("texture");
        }
        let extras = if extras.is_empty() { String::new() } else { format!(", with {}", extras.join(", ")) };
        format!("Mesh({} vertices, {} triangles{extras})", self.inner.vertex_count(), self.inner.triangle_count())
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other.cast::<PyMesh>().map(|o| o.get().inner == self.inner).unwrap_or(false)
    }
}

/// An sRGB float in [0, 1] as a byte.
fn byte(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// An image as an (H, W, C) uint8 array.
fn srgb_bytes<'py>(py: Python<'py>, image: &Image) -> PyResult<Bound<'py, PyAny>> {
    let bytes: Vec<u8> = image.data().iter().map(|&v| byte(v)).collect();
    let (h, w, c) = (image.height() as usize, image.width() as usize, image.channels() as usize);
    use numpy::PyArrayMethods;
    Ok(numpy::PyArray1::from_vec(py, bytes).reshape([h, w, c])?.into_any())
}
