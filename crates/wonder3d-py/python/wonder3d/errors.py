"""The exceptions of wonder3d.

Every error raised by the Rust core is one of these, carrying the core's message, which names
the file, array or option at fault and what was expected. Each also subclasses the built-in
exception callers already catch: bad data is a ``ValueError``, a file the system refused is
an ``OSError`` (with ``errno`` and ``filename``).
"""


class Error(Exception):
    """Base class of every wonder3d error."""


class InvalidInputError(Error, ValueError):
    """In-memory data or an option is invalid: a wrong array shape or dtype, NaN vertices,
    an out-of-range face index, an unknown rig or preset name."""


class FormatError(Error, ValueError):
    """A file was read but its contents are not what its format requires."""


class FileError(Error, OSError):
    """The operating system refused to read or write a file (missing, unreadable, a
    folder that cannot be written)."""


class InternalError(Error, RuntimeError):
    """A bug in wonder3d (the Rust code panicked). Please report it."""


__all__ = ["Error", "InvalidInputError", "FormatError", "FileError", "InternalError"]
