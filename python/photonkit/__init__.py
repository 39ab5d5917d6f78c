"""photonkit: caustic photon maps with robust relaxation constraints.

Photon maps (PHM files) open as :class:`PhotonMap` objects whose columns are read-only numpy
arrays viewing the file's memory map; :func:`write` makes a PHM file from numpy arrays (a
Python tracer's photons); and every stage of the pipeline is a call with the command line's
options as keyword arguments:

    trace -> detect -> relax -> collapse -> relax -> render

>>> import photonkit
>>> traced = photonkit.trace(photons=100_000)          # the embedded glass sphere
>>> relaxed = photonkit.pipeline(traced)                 # detect, relax, collapse, relax
>>> image = photonkit.render(relaxed, width=300)         # (height, width, 3) float32
>>> relaxed["position"].shape
(…, 3)

Stages release the interpreter while they run. A bad argument raises ``ValueError``, a file
that cannot be read or written ``OSError``, anything else :class:`PhotonkitError` (a
``RuntimeError``), with the message ``photonkit`` prints on the command line. What the
command line prints as notes goes to the ``logging`` logger ``"photonkit"`` at level INFO.
docs/python.md has the whole story.
"""

from ._photonkit import (
    PhotonkitError,
    PhotonMap,
    __version__,
    collapse,
    compare,
    detect,
    open,
    pipeline,
    relax,
    render,
    trace,
    write,
)

__all__ = [
    "PhotonkitError",
    "PhotonMap",
    "__version__",
    "collapse",
    "compare",
    "detect",
    "open",
    "pipeline",
    "relax",
    "render",
    "trace",
    "write",
]
