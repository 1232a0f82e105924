//! Rust errors as Python exceptions: every [`wonder3d::Error`] becomes one of the classes of
//! `wonder3d/errors.py`, all subclasses of `wonder3d.Error`, with the Rust message.

use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

/// The Python module that defines the exception classes (plain Python, so that each can
/// subclass both `wonder3d.Error` and the built-in a caller already catches).
const ERRORS_MODULE: &str = "wonder3d.errors";

/// The exception classes a Rust error maps to.
#[derive(Debug, Clone, Copy)]
pub enum Kind {
    /// In-memory data or an option is invalid (`InvalidInputError`, a `ValueError`).
    Invalid,
    /// A file was read but is not what its format requires (`FormatError`, a `ValueError`).
    Format,
    /// The operating system refused a file (`FileError`, an `OSError`).
    File,
    /// A bug: Rust code panicked (`InternalError`).
    Internal,
}

impl Kind {
    fn class_name(self) -> &'static str {
        match self {
            Kind::Invalid => "InvalidInputError",
            Kind::Format => "FormatError",
            Kind::File => "FileError",
            Kind::Internal => "InternalError",
        }
    }
}

/// The class of `kind`, imported once.
fn class(py: Python<'_>, kind: Kind) -> PyResult<Bound<'_, PyType>> {
    static CLASSES: PyOnceLock<[Py<PyType>; 4]> = PyOnceLock::new();
    let classes = CLASSES.get_or_try_init(py, || -> PyResult<_> {
        let module = py.import(ERRORS_MODULE)?;
        let get = |kind: Kind| -> PyResult<Py<PyType>> {
            Ok(module.getattr(kind.class_name())?.cast_into::<PyType>()?.unbind())
        };
        Ok([get(Kind::Invalid)?, get(Kind::Format)?, get(Kind::File)?, get(Kind::Internal)?])
    })?;
    let index = kind as usize;
    Ok(classes[index].bind(py).clone())
}

/// A Python exception of `kind` with `message`.
pub fn new_error(kind: Kind, message: String) -> PyErr {
    Python::attach(|py| match class(py, kind) {
        Ok(class) => PyErr::from_type(class, message),
        Err(import_failed) => import_failed,
    })
}

/// `InvalidInputError("{field}: expected {expected}")`, the wording of the Rust errors.
pub fn invalid(field: impl std::fmt::Display, expected: impl std::fmt::Display) -> PyErr {
    new_error(Kind::Invalid, format!("{field}: expected {expected}"))
}

/// The Python exception of a Rust error. An I/O error keeps its errno and file name, so
/// `FileError` (an `OSError`) reads like the built-in one (`e.errno`, `e.filename`).
pub fn to_py(error: wonder3d::Error) -> PyErr {
    match &error {
        wonder3d::Error::Io { path, source } => Python::attach(|py| {
            let class = match class(py, Kind::File) {
                Ok(class) => class,
                Err(import_failed) => return import_failed,
            };
            let errno = source.raw_os_error().unwrap_or(0);
            let filename = path.display().to_string();
            match class.call1((errno, error.to_string(), filename)) {
                Ok(instance) => PyErr::from_value(instance),
                Err(failed) => failed,
            }
        }),
        wonder3d::Error::Format { .. } => new_error(Kind::Format, error.to_string()),
        wonder3d::Error::Invalid { .. } => new_error(Kind::Invalid, error.to_string()),
    }
}

/// Turns a Rust result into a Python one.
pub trait IntoPy<T> {
    /// The value, or the error as a Python exception ([`to_py`]).
    fn py_err(self) -> PyResult<T>;
}

impl<T> IntoPy<T> for wonder3d::Result<T> {
    fn py_err(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}
