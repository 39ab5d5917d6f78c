"""Type stubs of photonkit: PHM photon maps as numpy arrays, and every stage as a call.

Keyword arguments are the command line's options in snake_case, with its defaults (see
`photonkit help STAGE`); docs/python.md is the guide.
"""

import os
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, Literal, Optional, Union, overload

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, "os.PathLike[str]"]
MapLike = Union["PhotonMap", PathLike]
Vec3 = Union[Sequence[float], str]

class PhotonkitError(RuntimeError):
    """A stage failed: a corrupt or unsuitable photon map, a scene file with an error, or a run
    that cannot go on. The message is the one the command line prints."""

class PhotonMap:
    """A photon map: a PHM file (memory-mapped) or a stage's result in memory.

    Columns are read-only numpy arrays that view the map's memory (no copy) and whose
    ``base`` is this object, which they keep alive: ``m["position"]`` is float32 (N, 3),
    ``m["emitter"]`` uint16 (N,), a column of one component has shape (N,).
    """

    def __len__(self) -> int:
        """The number of photons."""
    def __getitem__(self, column: str) -> npt.NDArray[Any]:
        """The column as a read-only array viewing the map; KeyError if absent."""
    def __contains__(self, column: str) -> bool: ...
    def __iter__(self) -> Iterator[str]:
        """The column names, in file order."""
    @overload
    def get(self, column: str) -> Optional[npt.NDArray[Any]]: ...
    @overload
    def get(self, column: str, default: Any) -> Any: ...
    def keys(self) -> list[str]:
        """The column names, in file order."""
    @property
    def columns(self) -> dict[str, npt.NDArray[Any]]:
        """Every column as a read-only array viewing the map, in file order."""
    @property
    def metadata(self) -> dict[str, Any]:
        """The JSON header (photon_count, columns, emitters, units, bounding_box, state,
        history, …) as the file holds it; a map in memory has no column offsets, checksums or
        bounding box until written."""
    @property
    def emitters(self) -> list[dict[str, Any]]:
        """The emitters: kind, parameterisation, param_dims, power_w, colour, …"""
    @property
    def state(self) -> Literal["traced", "detected", "collapsed", "unknown"]:
        """Where the map is in the pipeline."""
    @property
    def history(self) -> list[dict[str, Any]]:
        """The stages that made the map, oldest first (stage, version, time, parameters,
        report)."""
    @property
    def path(self) -> Optional[str]:
        """The file's path; None for a map in memory."""
    @property
    def name(self) -> str:
        """The name messages use: the path, or that of the map a chain in memory started from."""
    @property
    def version(self) -> Optional[tuple[int, int]]:
        """(major, minor) of the file as written; None for a map in memory."""
    @property
    def mapping(self) -> Optional[tuple[int, int]]:
        """The addresses [start, end) of the file's bytes in this process (its memory map),
        inside which every column array lies; None for a map in memory."""
    def write(self, path: PathLike) -> PhotonMap:
        """Writes the map as a PHM file (beside the target, then renamed into place; never over
        a map open in this process) and returns it opened from there."""

def open(path: PathLike) -> PhotonMap:
    """Opens a PHM file: checks its header and every column's checksum, and maps it into
    memory."""

def write(
    path: PathLike,
    columns: Mapping[str, npt.ArrayLike],
    *,
    emitters: Optional[Sequence[Mapping[str, Any]]] = None,
    state: Literal["traced", "detected", "collapsed"] = "traced",
    history: Optional[Sequence[Mapping[str, Any]]] = None,
    units: Optional[Mapping[str, Any]] = None,
) -> PhotonMap:
    """Writes a PHM file from arrays, one per column, and returns it opened.

    ``position`` and ``flux`` (float32, shape (N, 3), metres and watts per RGB channel) are
    required; the other columns of the format (normal, incident, emitter, params, path_length,
    bounces, emission_index, surface, …) must have its types; any other name is a column of
    your own, of any of (u)int8–64, float32, float64, shape (N,) or (N, components). Emitters
    are dicts as the header holds them (``id``, ``param_dims`` and ``colour`` may be left out);
    without them the photons get one emitter of kind "external" without parameters, and a
    ``params`` column needs them. A record of this write is added to ``history``. Arrays are
    read in place when C-contiguous and must not change during the call.
    """

def trace(
    scene: Optional[PathLike] = None,
    output: Optional[PathLike] = None,
    *,
    photons: Optional[float] = None,
    stored: Optional[float] = None,
    seed: int = 1,
    shard: Optional[Union[str, tuple[int, int]]] = None,
    store: Literal["caustic", "direct"] = "caustic",
    threads: Optional[int] = None,
    max_bounces: int = 64,
    memory: Optional[Union[int, str]] = None,
) -> PhotonMap:
    """Traces photons from a scene file (TOML; the embedded glass sphere without one) and
    keeps the caustic ones with their trajectory parameters (``photonkit trace``).

    ``photons`` emitted (default 1e6), or until ``stored`` are stored; ``shard`` "i/n" traces
    one slice of the emission numbers. With ``output`` the map is written there, photons
    beyond ``memory`` (default "256MiB") waiting on its disk, and returned opened; without, it
    is kept in memory.
    """

def detect(
    map: MapLike,
    output: Optional[PathLike] = None,
    *,
    method: Optional[Literal["param-pca", "world-pca", "gradient", "none"]] = None,
    kc: int = 50,
    beta: float = 3.0,
    growths: int = 2,
    spectral_scale: float = 0.03,
    k_density: Optional[int] = None,
    gain: float = 0.6,
    mu_sigma: Literal["simulated", "paper"] = "simulated",
    memory: Optional[Union[int, str]] = None,
) -> PhotonMap:
    """Feature detection (Eq. 1–7): a constraint basis per photon (columns basis_u, basis_v,
    lambda2, r_param) for ``relax`` (``photonkit detect``). ``method`` None: param-pca, or
    world-pca for a map without trajectory parameters. ``memory`` ("8G"): detect in spatial
    tiles when the whole map would not fit, with the same result (``--memory``)."""

def relax(
    map: MapLike,
    output: Optional[PathLike] = None,
    *,
    iterations: int = 7,
    kf: int = 16,
    epsilon: float = 1e-3,
    step_limit: float = 0.5,
    scene: Optional[PathLike] = None,
    flux_diffusion: float = 0.0,
    spectral_window: float = 35.0,
    memory: Optional[Union[int, str]] = None,
) -> PhotonMap:
    """Relaxation (Eq. 8–9): ``iterations`` of repulsion from the ``kf`` nearest photons along
    each constraint basis (``photonkit relax``). After the collapse, photons that carry their
    wavelength take as neighbours only those within ``spectral_window`` nm of their own
    (``--spectral-window``; 0: every wavelength). Photons return to their surfaces in ``scene``,
    or in the scene the map's trace record names when it is found. ``memory`` ("8G"): relax
    in spatial tiles when the whole map would not fit, with the same result (``--memory``)."""

def collapse(map: MapLike, output: Optional[PathLike] = None) -> PhotonMap:
    """Drops the parameter dimensions from the neighbour search: the next ``relax`` works in
    world space (``photonkit collapse``)."""

def pipeline(
    map: MapLike,
    out_dir: Optional[PathLike] = None,
    *,
    scene: Optional[PathLike] = None,
    method: Optional[Literal["param-pca", "world-pca", "gradient", "none"]] = None,
    kc: int = 50,
    beta: float = 3.0,
    growths: int = 2,
    spectral_scale: float = 0.03,
    k_density: Optional[int] = None,
    iterations: int = 7,
    kf: int = 16,
    spectral_window: float = 35.0,
) -> PhotonMap:
    """Detect → relax (parameter space) → collapse → relax (world space) on a traced map, in
    memory, with ``photonkit pipeline``'s settings; returns the relaxed map. With ``out_dir``
    each stage's map is written there as ``pipeline`` names it (detected.phm,
    relaxed-params.phm, collapsed.phm, relaxed.phm)."""

def render(
    map: MapLike,
    output: Optional[PathLike] = None,
    *,
    scene: Optional[PathLike] = None,
    mode: Optional[Literal["full", "caustic", "direct", "irradiance"]] = None,
    estimator: Literal["knn", "diffusion", "variable"] = "knn",
    kernel: Literal["epanechnikov", "disc", "cone"] = "epanechnikov",
    k: Optional[int] = None,
    max_radius: Optional[float] = None,
    diffusion_k: int = 500,
    diffusion_q: float = 0.02,
    diagnostic: Optional[Literal["params", "path-length", "constrained", "splat"]] = None,
    threshold: float = 0.5,
    dot_radius: Optional[float] = None,
    plane: Optional[str] = None,
    rect: Optional[tuple[float, float, float, float]] = None,
    plane_tolerance: float = 1e-3,
    png: Optional[PathLike] = None,
    no_png: bool = False,
    exposure: float = 0.0,
    fixed_exposure: bool = False,
    width: Optional[int] = None,
    height: Optional[int] = None,
    spp: int = 4,
    specular: Literal["split", "sample"] = "split",
    max_depth: int = 16,
    eye: Optional[Vec3] = None,
    look_at: Optional[Vec3] = None,
    up: Optional[Vec3] = None,
    fov: Optional[float] = None,
    ortho: Optional[float] = None,
    seed: int = 0,
    threads: Optional[int] = None,
    memory: Optional[Union[int, str]] = None,
) -> npt.NDArray[np.float32]:
    """Renders a photon map (``photonkit render``) and returns the image, float32 of shape
    (height, width, 3), top row first: radiance in W/(m²·sr) per RGB channel, or irradiance in
    W/m² with ``mode="irradiance"`` or a ``plane`` ("z=0": a scene-less top view). The scene is
    ``scene``, else the one the map's trace record names, else the embedded default. With
    ``output`` (an .exr) the EXR and its PNG preview are written as ``photonkit render -o``
    writes them. ``k`` defaults to 15 (the k-NN estimate); on a map grown by refinement, when
    ``k`` is not given, each estimate gathers within the distance of the 15th nearest of the
    map's first photons, narrowed where detection held them, as ``photonkit render`` does. ``memory`` ("8G"): the estimate streams
    the map one spatial tile at a time when the whole would not fit, with the same image
    (``--memory``; not with ``plane`` or ``diagnostic``)."""

def compare(
    scene: Optional[PathLike] = None,
    out_dir: Optional[PathLike] = None,
    *,
    photons: Optional[float] = None,
    seed: int = 1,
    methods: Optional[Sequence[Literal["pm", "relax2009", "diffusion", "ours", "ppm", "ours-progressive"]]] = None,
    k: int = 15,
    pm_k: Optional[Sequence[int]] = None,
    estimator: Literal["knn", "variable"] = "knn",
    kc: int = 50,
    beta: float = 3.0,
    growths: int = 2,
    spectral_scale: float = 0.03,
    k_density: Optional[int] = None,
    iterations: int = 7,
    kf: int = 16,
    spectral_window: float = 35.0,
    iterations_2009: int = 14,
    diffusion_k: int = 500,
    diffusion_q: float = 0.02,
    ppm_passes: Optional[Sequence[int]] = None,
    ppm_photons: Optional[float] = None,
    ppm_k: int = 30,
    spp: int = 16,
    feature_spp: int = 4096,
    seeds: int = 4,
    cells: int = 128,
    reference_passes: int = 64,
    fast_truth: bool = False,
    threads: Optional[int] = None,
) -> dict[str, Any]:
    """Every method on the same traced photons, timed and measured against the truth
    (``photonkit compare``; defaults: photons 1e6, every method, pm_k [15, 50, 200],
    ppm_passes [1, 4, 16], out_dir "photonkit-compare"). Writes report.md, report.csv and the
    images to ``out_dir``; returns {"rows": one dict per method, setting and region with
    report.csv's columns, "table": Table I in Markdown, "report": the path of report.md}.
    For a sweep, call it in a loop."""
