//! The one error type of wonder3d-rs.

use std::path::{Path, PathBuf};

/// Result alias used by every fallible function in the workspace.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Every way an operation on user data can fail.
///
/// Each variant names *where* the problem is (a file and/or a field such as
/// `positions[12].y` or `views[3].mask`) and *what was expected*, so the message
/// alone tells the user what to fix.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The operating system refused to read or write a file.
    #[error("{path}: {source}")]
    Io {
        /// The file that could not be read or written.
        path: PathBuf,
        /// The underlying OS error.
        #[source]
        source: std::io::Error,
    },
    /// A file was read but its contents are not what the format requires.
    #[error("{path}: {field}: expected {expected}")]
    Format {
        /// The offending file.
        path: PathBuf,
        /// Where in the file (line, element, key ...).
        field: String,
        /// What the format requires there, and what was found when useful.
        expected: String,
    },
    /// In-memory data (a mesh, an image, an option) is invalid.
    #[error("{field}: expected {expected}")]
    Invalid {
        /// The offending field, e.g. `positions[12].y`.
        field: String,
        /// What is required, and what was found when useful.
        expected: String,
    },
}

impl Error {
    /// An [`Error::Io`] for `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io { path: path.as_ref().to_path_buf(), source }
    }

    /// An [`Error::Format`] for `path`.
    pub fn format(path: impl AsRef<Path>, field: impl Into<String>, expected: impl Into<String>) -> Self {
        Error::Format { path: path.as_ref().to_path_buf(), field: field.into(), expected: expected.into() }
    }

    /// An [`Error::Invalid`] for an in-memory `field`.
    pub fn invalid(field: impl Into<String>, expected: impl Into<String>) -> Self {
        Error::Invalid { field: field.into(), expected: expected.into() }
    }

    /// Attach a file path to an in-memory validation error (turning it into
    /// [`Error::Format`]); other variants pass through unchanged.
    pub fn in_file(self, path: impl AsRef<Path>) -> Self {
        match self {
            Error::Invalid { field, expected } => Error::format(path, field, expected),
            other => other,
        }
    }
}
