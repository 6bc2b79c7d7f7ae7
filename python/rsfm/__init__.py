"""rsfm: camera motion, focal length and planar structure from tracked features.

Python bindings of the rsfm C++ library (python/README.md). The entry points:

* ``rsfm.estimate(tracks, **options)``: the pipeline of ``rsfm estimate`` on a tracks file or an
  array of observations;
* ``rsfm.estimate_patches(patches, **options)``: the patch pipeline (``rsfm estimate --patches``);
* ``rsfm.run(video, **options)``: tracking, then the same pipeline (``rsfm run``; ``model="patches"``
  tracks affine patches);
* ``rsfm.PlaneFilter``: the plane filter step by step (one frame's observations at a time).

Options are the command line's, with dashes as underscores (``focal_px=612`` is
``--focal-px 612``; a flag takes ``True``/``False``); ``rsfm.options("estimate")`` lists them with
their defaults. Errors raise ``rsfm.InputError`` (bad input: a file, an option) or ``RuntimeError``
with the command line's messages.
"""
from ._rsfm import (  # noqa: F401
    InputError,
    PlaneFilter,
    __version__,
    estimate,
    estimate_patches,
    options,
    read_tracks,
    run,
)

__all__ = ["InputError", "PlaneFilter", "__version__", "estimate", "estimate_patches", "options", "read_tracks", "run"]
