//! The native part of the `wonder3d` Python package: a thin PyO3 face over the `wonder3d`
//! facade. Plain data in and out (numpy arrays, dicts); long calls release the GIL, report
//! progress to a callback and stop on Ctrl-C (module `job`); Rust errors become the exception
//! classes of `python/wonder3d/errors.py` (module `errors`). The Python package
//! (`python/wonder3d/__init__.py`) re-exports everything here with its type stubs;
//! `docs/python.md` is the user guide. Built by maturin (`pyproject.toml`):
//!
//! ```text
//! pip install maturin && maturin build --release -m crates/wonder3d-py/Cargo.toml
//! ```

// Layers, bottom-up: errors and arrays, then the long-call runner, then the types, then
// the functions over them.
mod arrays;
mod errors;
mod job;

mod mesh;
mod views;

mod generate;
mod stages;

use pyo3::prelude::*;

/// The `wonder3d._native` extension module.
#[pymodule]
#[pyo3(name = "_native")]
fn native(module: &Bound<'_, PyModule>) -> PyResult<()> {
    module.add("__version__", env!("CARGO_PKG_VERSION"))?;
    module.add_class::<mesh::PyMesh>()?;
    module.add_class::<views::PyViewSet>()?;
    module.add_class::<job::ProgressEvent>()?;
    module.add_class::<stages::PyPrepared>()?;
    module.add_class::<stages::PyRefined>()?;
    module.add_class::<generate::PyGenerator>()?;
    module.add_class::<generate::PyGenerated>()?;
    module.add_class::<generate::PyPipeline>()?;
    module.add_class::<generate::PyOutput>()?;
    module.add_function(wrap_pyfunction!(views::render_views, module)?)?;
    module.add_function(wrap_pyfunction!(stages::reconstruct, module)?)?;
    module.add_function(wrap_pyfunction!(stages::texture, module)?)?;
    module.add_function(wrap_pyfunction!(stages::evaluate, module)?)?;
    module.add_function(wrap_pyfunction!(stages::prepare_image, module)?)?;
    module.add_function(wrap_pyfunction!(stages::refine, module)?)?;
    Ok(())
}
