"""wonder3d: one photo of an object in, a textured, watertight 3D mesh out.

A thin Python face over the Rust core (wonder3d-rs, a reimplementation of Wonder3D++):
numpy arrays in and out, every stage callable on its own.

>>> import wonder3d
>>> spot = wonder3d.Mesh.load("assets/spot.obj")                    # doctest: +SKIP
>>> views = wonder3d.render_views(spot, size=128)                   # doctest: +SKIP
>>> mesh = wonder3d.reconstruct(views, preset="fast")               # doctest: +SKIP
>>> wonder3d.evaluate(mesh, spot)["chamfer"]                        # doctest: +SKIP

Long calls (reconstruct, texture, refine, Generator, Pipeline) release the GIL, take a
``progress`` callback receiving :class:`ProgressEvent` objects (see :func:`tqdm_progress`),
and stop promptly on Ctrl-C with ``KeyboardInterrupt``, leaving no file half-written.
Errors are :class:`Error` subclasses (:mod:`wonder3d.errors`). The guide: docs/python.md.
"""

from . import errors
from ._native import (
    Generated,
    Generator,
    Mesh,
    Output,
    Pipeline,
    PreparedImage,
    ProgressEvent,
    Refined,
    ViewSet,
    __version__,
    evaluate,
    prepare_image,
    reconstruct,
    refine,
    render_views,
    texture,
)
from .errors import Error, FileError, FormatError, InternalError, InvalidInputError


class tqdm_progress:
    """A progress callback that draws one tqdm bar per stage.

    >>> with wonder3d.tqdm_progress() as progress:                  # doctest: +SKIP
    ...     mesh = wonder3d.reconstruct(views, progress=progress)

    Needs ``tqdm`` (``pip install tqdm``); keyword arguments go to each ``tqdm`` bar.
    """

    def __init__(self, **tqdm_kwargs):
        from tqdm.auto import tqdm  # imported here: tqdm is optional

        self._tqdm = tqdm
        self._kwargs = tqdm_kwargs
        self._bar = None
        self._stage = None

    def __call__(self, event: ProgressEvent) -> None:
        if event.stage != self._stage or self._bar is None:
            self.close()
            self._stage = event.stage
            self._bar = self._tqdm(total=event.total, desc=event.stage, **self._kwargs)
        if self._bar.total != event.total:
            self._bar.total = event.total
        self._bar.n = event.done
        if event.loss is not None:
            self._bar.set_postfix(loss=f"{event.loss:.5f}", refresh=False)
        self._bar.refresh()

    def close(self) -> None:
        """Closes the current bar."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


__all__ = [
    "Error",
    "FileError",
    "FormatError",
    "Generated",
    "Generator",
    "InternalError",
    "InvalidInputError",
    "Mesh",
    "Output",
    "Pipeline",
    "PreparedImage",
    "ProgressEvent",
    "Refined",
    "ViewSet",
    "__version__",
    "errors",
    "evaluate",
    "prepare_image",
    "reconstruct",
    "refine",
    "render_views",
    "texture",
    "tqdm_progress",
]
