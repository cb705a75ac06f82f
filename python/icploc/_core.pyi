"""Type stubs for the private native module ``icploc._core`` (Rust, pyo3).

Use the public names re-exported by :mod:`icploc`; this module is private.
"""

from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from typing_extensions import Self, final

from icploc.errors import IcplocError

__version__: str

class IcpError(IcplocError):
    """Base class of every error raised by the ICP core."""

class InvalidInputError(IcpError, ValueError):
    """An input array has the wrong shape or dtype, holds NaN/inf, or has too few points."""

class EmptyMapError(InvalidInputError):
    """The map has no points."""

class GridTooLargeError(InvalidInputError):
    """A grid would need more cells than the core's memory bound (use a coarser resolution)."""

class InvalidConfigError(IcpError, ValueError):
    """A configuration value is out of range (e.g. a non-positive threshold)."""

Metric = Literal["point_to_point", "point_to_line"]
Robust = Literal["none", "huber", "cauchy"]

@final
class IcpConfig:
    """ICP settings. Every default is the Rust core's ``IcpConfig::default()``; keyword
    arguments override them, and every value is checked at construction and on
    assignment (:class:`InvalidConfigError` naming the field).

    Thresholds in metres. The correspondence threshold shrinks geometrically from
    ``max_correspondence_distance`` to ``min_correspondence_distance`` by
    ``threshold_decay`` per iteration (``threshold_decay=1``: the paper's fixed threshold).
    ``mse_threshold`` is the paper's tau; ``mse_change`` the relative change of the MSE
    below which it stops. ``heading_search`` (rad, 0 = off) tries start headings within
    +-heading_search every ``heading_step`` with a short coarse ICP each;
    ``position_search`` (m, 0 = off) adds start positions offset by +-position_search in x
    and y (at most 10,000 start candidates in all).

    The verified start (``window_search``, on by default): when the ICP result does not
    explain the scan -- fewer than ``accept_inlier_ratio`` of the points within
    3 x ``expected_noise`` of the map, their RMS above 2 x ``expected_noise``, or more than
    ``accept_see_through`` of the beams passing through mapped walls; or it lies outside
    the window below -- cheap local checks run first, and a branch-and-bound search over
    +-``window_position`` (m) and +-``window_heading`` (rad, every ``window_angle_step``)
    around the initial pose on the map's likelihood pyramid (10 cm cells, built once per
    MapIndex on first use; 20 or 40 cm on maps whose bounds need more than 2**23 cells, and
    no search beyond that) only when they find nothing that explains the scan; ICP from the
    best poses gives the result that explains the scan best. When the plain fit explains
    the scan nothing more runs. A fit with an RMS within 0.75 x ``expected_noise`` and no
    more see-through than ``accept_see_through`` explains it with 55 % inliers already (the
    rest: unmapped things in front of walls); one with an RMS within 0.6 x
    ``expected_noise`` with 50 % inliers and, outside corridors, up to 15 % of the beams
    through mapped walls (mapped glass). A corridor fit (degeneracy < 0.25) is compared
    with the other places along the corridor (a 1-D look along its free axis, ICP from the
    ones that score about as well). When the fit does not explain the scan, the window is
    searched first at +-4 degrees around the heading at which the scan's wall directions
    match the map's, and in full only when nothing there explains the scan. A fit from
    that heading that explains the scan only by the looser rules is compared with the ICP
    from the initial pose unless its RMS is within ``prior_sure_rms`` x ``expected_noise``
    (0: always compared). Beams through mapped objects of at most
    ``vanished_object_size`` m that the scan does not see (a parked car that left since
    mapping) do not count against a tight fit as beams through walls (0: they do)."""

    metric: Metric
    max_iterations: int
    max_correspondence_distance: float
    min_correspondence_distance: float
    threshold_decay: float
    trim_fraction: float
    robust: Robust
    robust_scale: float
    mse_threshold: float
    mse_change: float
    step_tolerance: float
    min_inliers: int
    min_inlier_ratio: float
    heading_search: float
    heading_step: float
    position_search: float
    window_search: bool
    window_position: float
    window_heading: float
    window_angle_step: float
    expected_noise: float
    accept_inlier_ratio: float
    accept_see_through: float
    prior_sure_rms: float
    vanished_object_size: float
    def __new__(
        cls,
        *,
        metric: Metric = ...,
        max_iterations: int = ...,
        max_correspondence_distance: float = ...,
        min_correspondence_distance: float = ...,
        threshold_decay: float = ...,
        trim_fraction: float = ...,
        robust: Robust = ...,
        robust_scale: float = ...,
        mse_threshold: float = ...,
        mse_change: float = ...,
        step_tolerance: float = ...,
        min_inliers: int = ...,
        min_inlier_ratio: float = ...,
        heading_search: float = ...,
        heading_step: float = ...,
        position_search: float = ...,
        window_search: bool = ...,
        window_position: float = ...,
        window_heading: float = ...,
        window_angle_step: float = ...,
        expected_noise: float = ...,
        accept_inlier_ratio: float = ...,
        accept_see_through: float = ...,
        prior_sure_rms: float = ...,
        vanished_object_size: float = ...,
    ) -> Self: ...
    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` if any value is out of range."""
    def to_dict(self) -> dict[str, object]: ...

@final
class IcpResult:
    """What one ICP alignment did."""

    @property
    def pose(self) -> tuple[float, float, float]:
        """Sensor pose (x, y, theta) in the map frame."""
    @property
    def converged(self) -> bool:
        """False when the iteration limit was hit or too few inliers remained."""
    @property
    def iterations(self) -> int: ...
    @property
    def mse(self) -> float:
        """Mean squared error over the inliers of the final iteration (m^2)."""
    @property
    def inliers(self) -> int: ...
    @property
    def num_points(self) -> int: ...
    @property
    def inlier_ratio(self) -> float: ...
    @property
    def covariance(self) -> NDArray[np.float64]:
        """3x3 covariance of (x, y, theta), sigma^2 * H^-1 of the final cost."""
    @property
    def information(self) -> NDArray[np.float64]:
        """3x3 information (Hessian) matrix of (x, y, theta), point-to-line form."""
    @property
    def degeneracy(self) -> float:
        """lambda_min / lambda_max of the translational information (0 = corridor, 1 = well constrained)."""
    @property
    def degenerate_direction(self) -> tuple[float, float]:
        """Unit vector (map frame) of the least constrained translation direction."""
    @property
    def termination(self) -> str:
        """Why it stopped: mse_below_threshold, mse_change_below_epsilon, step_below_tolerance,
        max_iterations or too_few_inliers."""
    @property
    def start(self) -> Literal["plain", "prior", "local", "window_kept_plain", "window"]:
        """Which start the result came from: ``plain`` (the ICP from the initial pose explained
        the scan), ``prior`` (the heading at which the scan's wall directions line up with the
        map's disagreed with the initial heading by more than a few degrees, and the ICP from the
        initial position at that heading explained the scan), ``local`` (the ICP from another place along the corridor the plain fit lay
        in explained it better), ``window_kept_plain`` (it did not; the window search ran but nothing it
        found explained the scan better -- or, with ``window_score`` None, it could not run: a
        map too large for its grid) or ``window`` (ICP from a window-search pose)."""
    @property
    def fit_inlier_ratio(self) -> float | None:
        """Share of the scan points within 3 x expected_noise of the map at the final pose
        (None with window_search off)."""
    @property
    def fit_rms(self) -> float | None:
        """RMS (m) of those points' distances to the map."""
    @property
    def see_through(self) -> float | None:
        """Share of the checked beams that pass through a mapped wall at the final pose."""
    @property
    def fit_score(self) -> float | None:
        """Mean Gaussian likelihood of the point distances times (1 - see_through)², in [0, 1]."""
    @property
    def window_score(self) -> float | None:
        """Coarse (pyramid) score in [0, 1] of the window's best pose; None when the window
        search did not run."""
    @property
    def window_second_score(self) -> float | None:
        """Coarse score of the best window pose distinct from the best (>= 0.3 m or 0.1 rad
        away), 0 when none reached 80 % of the best: close to ``window_score`` means the
        window was ambiguous. None when the window search did not run."""
    def to_dict(self) -> dict[str, object]: ...

@final
class MapIndex:
    """An immutable k-d tree over 2D map points with optional unit normals."""

    def __new__(
        cls,
        points: ArrayLike,
        normals: ArrayLike | None = None,
        cache_resolution: float | None = ...,
    ) -> Self:
        """Build the k-d tree. ``cache_resolution`` (m): cell size of the precomputed
        closest-point grid ICP uses for correspondences (O(1) whatever the map size; answers at
        most ``1.67·cache_resolution`` farther than the exact nearest point when that is within
        2 m, else a map point farther than 2 m; tiles exist only within 2 m of map points);
        ``None`` or 0 for exact k-d tree answers only. The resolution is never coarsened: when
        the grid would exceed its memory bound (2²³ cells, 32 MB) there is none and
        ``cache_fallback`` says why. Map coordinates must be within ±1e9 m."""
    def __len__(self) -> int: ...
    @property
    def cache_resolution(self) -> float | None:
        """Cell size of the closest-point grid (None: exact k-d tree answers)."""
    @property
    def cache_fallback(self) -> str | None:
        """Why the requested closest-point grid was not built (ICP then gets exact, slower,
        k-d tree answers); None when it was built or not asked for."""
    @property
    def cache_bytes(self) -> int:
        """Heap bytes held by the closest-point grid (0 without one)."""
    @property
    def spacing(self) -> float:
        """Median nearest-neighbour spacing of the map points (m)."""
    @property
    def points(self) -> NDArray[np.float64]:
        """(N, 2) copy of the map points."""
    @property
    def normals(self) -> NDArray[np.float64]:
        """(N, 2) unit normals: the given ones, or estimated from neighbours on first use."""
    @property
    def has_normals(self) -> bool:
        """True when normals were given at construction."""
    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax)."""
    def nearest(self, query: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Distance to and index of the closest map point for each row of an (M, 2) query."""
    def within(self, center: Sequence[float], radius: float) -> NDArray[np.int64]:
        """Indices of the map points within ``radius`` of ``center``, sorted."""
    def visible(
        self,
        pose: Sequence[float],
        fov: float = ...,
        max_range: float = 30.0,
        point_radius: float | None = None,
        tolerance: float = 0.05,
        angular_resolution: float = 0.0025,
    ) -> NDArray[np.int64]:
        """Indices of the map points a scanner at ``pose`` could see: within ``max_range``
        and the field of view ``fov`` (radians, centred on the heading), not hidden behind
        nearer points. Each point occludes an arc of half-width ``point_radius`` (default:
        the median spacing between neighbouring map points)."""

def icp(
    scan_xy: ArrayLike,
    index: MapIndex,
    initial_pose: Sequence[float],
    config: IcpConfig | None = None,
) -> IcpResult:
    """Align an (N, 2) scan in the sensor frame to the map, starting from ``initial_pose``."""

def icp_batch(
    scans: Sequence[ArrayLike],
    index: MapIndex,
    initial_poses: ArrayLike,
    config: IcpConfig | None = None,
    num_threads: int | None = None,
) -> list[IcpResult]:
    """Align many (scan, initial pose) pairs in parallel with the GIL released. ``initial_poses``
    is (M, 3); ``scans`` has M entries, or one entry used for every pose (multi-start).
    ``num_threads`` (>= 1; default: the global pool) is clamped to 4 per core and to M."""

def parse_floats(text: str) -> NDArray[np.float64]:
    """Every whitespace-separated token of ``text`` as float64 (decimal, exponent, nan, inf),
    in order, exact; :class:`InvalidInputError` naming the first token that is not a number."""

def fit_score(
    index: MapIndex,
    points: ArrayLike,
    pose: Sequence[float],
    max_beams: int,
    hit_distance: float,
) -> tuple[float, float, int]:
    """``(hit, rms, beams)``: the evidence of the (N, 2) scan ``points`` (robot frame) at
    ``pose``. At most ``max_beams`` beams spread evenly over the scan (first and last
    included) are moved into the map frame; a beam hits when its exact nearest map point is
    closer than ``hit_distance``. ``hit`` is the share of beams that hit, ``rms`` the RMS of
    their offsets from those points along the points' normals (inf when none hits)."""

def noise_factor(
    v: tuple[float, float, float],
    p: ArrayLike,
    r: ArrayLike,
    max_gain: float,
    median: float,
) -> float | None:
    """The factor ``g`` on the (3, 3) prediction covariance ``p`` that makes
    ``v' (g p + r)^-1 v`` equal to ``median`` (the chi-square median with 3 degrees of
    freedom, 2.366; ``v``: scan pose minus prediction, heading wrapped; ``r``: the scan
    pose's covariance). Bisection on ``log g`` within ``[1e-3, 4 max_gain]``, an end when the
    root lies beyond it; None when an input is not finite."""

def scan_covariance(
    information: ArrayLike,
    inliers: int,
    mse: float,
    sigma_floor: float,
    independent_beams: float,
    min_axis_beams: float,
) -> NDArray[np.float64] | None:
    """The (3, 3) covariance of an ICP pose: ``(f H_sym + 1e-6 I)^-1`` with
    ``f = min(independent_beams, n) / (n s2)``, ``H`` the fit's (3, 3) ``information``, ``n``
    its inliers (at least 1), ``s2`` its ``mse`` (0 when not finite) floored at
    ``sigma_floor**2``; ``1e6 I`` when that is not positive definite. None when the smallest
    eigenvalue of H's translational block may be below ``min_axis_beams`` (> 0): the caller
    (``icploc.fusion.scan_covariance``) decides that case."""

def prepare_points(
    ranges: NDArray[np.float64],
    flags: NDArray[np.uint8] | None,
    cos: NDArray[np.float64],
    sin: NDArray[np.float64],
    lo: float,
    hi: float,
    decimation: int,
    bad_flags: int,
    offset: tuple[float, float],
) -> NDArray[np.float64]:
    """The (M, 2) points ``(r cos + offset_x, r sin + offset_y)`` of the beams with
    ``lo < r < hi`` and no ``bad_flags`` bit set in ``flags``, every ``decimation``-th of
    them from the first (``cos``, ``sin``: of the beam angles plus the laser's heading; the
    offset added only when not zero). All arrays of one length."""

def raycast(
    segments: ArrayLike,
    pose: Sequence[float],
    angles: ArrayLike,
    max_range: float,
) -> NDArray[np.float64]:
    """Range along each beam (angles in the sensor frame) from ``pose`` to the nearest of the
    (K, 4) segments [x1, y1, x2, y2]; inf where nothing is hit within ``max_range``."""

@final
class GlobalCandidate:
    """One ranked pose hypothesis of a global search (ICP-refined, re-scored)."""

    @property
    def pose(self) -> tuple[float, float, float]:
        """Sensor pose (x, y, theta) in the map frame."""
    @property
    def score(self) -> float:
        """Mean Gaussian likelihood of the point distances times (1 - see_through)², in [0, 1]."""
    @property
    def inlier_ratio(self) -> float: ...
    @property
    def mse(self) -> float:
        """Mean-square distance of the inliers (m^2)."""
    @property
    def see_through(self) -> float:
        """Fraction of beams passing through a mapped wall before their return."""
    @property
    def coarse_score(self) -> float: ...
    def to_dict(self) -> dict[str, object]: ...

@final
class GlobalSearchResult:
    """Ranked candidates of a global search; ``ambiguous`` when the best two distinct
    candidates score within the ambiguity margin."""

    @property
    def candidates(self) -> list[GlobalCandidate]: ...
    @property
    def best(self) -> GlobalCandidate | None: ...
    @property
    def ambiguous(self) -> bool: ...
    @property
    def nodes(self) -> int: ...
    @property
    def dense_nodes(self) -> int: ...
    @property
    def leaves(self) -> int: ...
    @property
    def headings(self) -> int: ...
    @property
    def coarse_time(self) -> float: ...
    @property
    def refine_time(self) -> float: ...
    def __len__(self) -> int: ...

def global_defaults() -> dict[str, float | int]:
    """The core's defaults of the settings :class:`GlobalLocalizer` takes (m, rad)."""

@final
class GlobalLocalizer:
    """Global localization on one map: a likelihood pyramid built once at ``resolution``,
    then branch-and-bound searches over free positions and headings, the best seeds
    refined by point-to-line ICP (GIL released)."""

    def __new__(
        cls,
        index: MapIndex,
        resolution: float = 0.05,
        *,
        angle_step: float | None = None,
        max_points: int | None = None,
        sigma: float | None = None,
        min_clearance: float | None = None,
        accept_ratio: float | None = None,
        min_score: float | None = None,
        max_candidates: int | None = None,
        levels: int | None = None,
        score_sigma: float | None = None,
        inlier_distance: float | None = None,
        distinct_distance: float | None = None,
        distinct_angle: float | None = None,
        ambiguity_margin: float | None = None,
        icp_config: IcpConfig | None = None,
        distances: NDArray[np.float32] | None = None,
    ) -> Self:
        """Every setting left None is the core's default (:func:`global_defaults`);
        ``distances``: :meth:`distances` of a localizer built before on the same map and
        resolution (the likelihood field without its nearest-point queries)."""
    def search(
        self,
        scan_xy: ArrayLike,
        region: Sequence[float] | None = None,
        heading: tuple[float, float] | None = None,
        min_score: float | None = None,
    ) -> GlobalSearchResult:
        """Find the pose of an (N, 2) sensor-frame scan; ``region`` (xmin, ymin, xmax, ymax)
        bounds the position, ``heading`` (min, max) the heading in radians; ``min_score``
        this search's coarse floor (a share of a perfect score, in [0, 1)) in place of the
        configured one: the leaves at or above it are those of the plain search."""
    def distances(self) -> NDArray[np.float32]:
        """The likelihood field's distances (m, each cell centre to the map, row by row)."""
    def refine(self, scan_xy: ArrayLike, poses: ArrayLike) -> list[GlobalCandidate]:
        """ICP-refine each of the (M, 3) poses and score it."""
    def score(self, scan_xy: ArrayLike, poses: ArrayLike) -> list[GlobalCandidate]:
        """Score the scan at each of the (M, 3) poses, no refinement."""
    def distinct(
        self, a: tuple[float, float, float], b: tuple[float, float, float]
    ) -> bool: ...
    def distance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Grid distance (m) from each (N, 2) point to the map (nan outside the grid)."""
    @property
    def index(self) -> MapIndex: ...
    @property
    def resolution(self) -> float: ...
    @property
    def shape(self) -> tuple[int, int]: ...
    @property
    def free_cells(self) -> int: ...
    @property
    def angle_step(self) -> float: ...
    @property
    def ambiguity_margin(self) -> float: ...
    @property
    def distinct_distance(self) -> float: ...
    @property
    def distinct_angle(self) -> float: ...

# ----------------------------------------------------------------------------- maps
@final
class GridLines:
    """Result of :func:`extract_grid_lines` (cell-corner units)."""

    @property
    def lines(self) -> NDArray[np.float64]: ...
    @property
    def rms(self) -> NDArray[np.float64]: ...
    @property
    def support(self) -> NDArray[np.int64]: ...
    @property
    def sigma_angle(self) -> NDArray[np.float64]: ...
    @property
    def snapped(self) -> NDArray[np.bool_]: ...
    @property
    def points(self) -> NDArray[np.float64]: ...
    @property
    def normals(self) -> NDArray[np.float64]: ...
    @property
    def surface_cells(self) -> int: ...
    @property
    def explained_cells(self) -> int: ...
    @property
    def explained_fraction(self) -> float: ...
    @property
    def face_edges(self) -> int: ...
    @property
    def dominant_direction(self) -> float | None: ...

def grid_line_defaults() -> dict[str, float | bool | int]:
    """The defaults of :func:`extract_grid_lines` (lengths in cells)."""

def extract_grid_lines(
    cells: NDArray[np.uint8],
    *,
    split_tolerance: float | None = None,
    min_length: float | None = None,
    max_gap: float | None = None,
    join_angle_deg: float | None = None,
    join_offset: float | None = None,
    max_rms: float | None = None,
    snap: bool | None = None,
    snap_sigmas: float | None = None,
    surface_offset: float | None = None,
    unknown_rim: int | None = None,
) -> GridLines:
    """Wall lines of a class grid ``cells[iy, ix]`` (0 free, 1 occupied, else unknown)."""

def cast_rays(
    origins: ArrayLike,
    ends: ArrayLike,
    hit: NDArray[np.bool_],
    origin: tuple[float, float],
    resolution: float,
    width: int,
    height: int,
) -> tuple[NDArray[np.uint32], NDArray[np.uint32]]:
    """Ray casting into a grid: (hits, passes) per cell, (height, width)."""

def grid_visible(
    cells: NDArray[np.uint8],
    origin: tuple[float, float],
    resolution: float,
    sensor: tuple[float, float],
    targets: ArrayLike,
    tolerance: float,
) -> NDArray[np.bool_]:
    """Which targets a sensor sees through a class grid (non-free cells block)."""

# saving and restoring a MapIndex's closest-point grid (icploc.maps.cache)
DEFAULT_CACHE_RESOLUTION: float
"""Cell size (m) of the closest-point grid ``MapIndex(points, normals)`` builds by default."""
GRID_FILL_VERSION: int
"""Version of the grid cells' computation and order: saved cells are valid for it only."""
FIELD_VERSION: int
"""Version of the likelihood field's distances (GlobalLocalizer.distances(), cached)."""

def grid_runs(
    index: MapIndex,
) -> tuple[NDArray[np.uint32], NDArray[np.uint32], float] | None:
    """``(values, lengths, resolution)``: the closest-point grid's cells as runs (None
    without a grid)."""

def index_from_grid_runs(
    points: ArrayLike,
    normals: ArrayLike | None,
    resolution: float,
    values: NDArray[np.uint32],
    lengths: NDArray[np.uint32],
) -> MapIndex:
    """``MapIndex(points, normals, cache_resolution=resolution)`` with the grid cells that
    ``grid_runs`` returned, not computed again; ``InvalidInputError`` when they do not fit."""
