"""Typed configuration of the localizer, loadable from and dumpable to YAML.

One dataclass per section::

    icp:       the ICP core's settings (metric, thresholds, iterations, robust weights)
    scan:      scan preparation (range limits, decimation, laser mounting offset)
    gating:    how a correction is checked against the odometry prediction (chi-square)
    localizer: the outer loop (motion model, calibration, verification, lost, recovery)
    map:       how the map is sampled for the ICP index (spacing, visibility culling)

``LocalizerConfig.from_yaml(path)`` reads a (possibly partial) YAML file over the
defaults; an unknown or duplicated section or key, or a value of the wrong type, raises
:class:`ConfigError` naming the file, the section and the key.

Validation lives here, in one place, and runs when a section is constructed (also by
``dataclasses.replace``): every value is type-checked (ints are ints, floats finite) and
range-checked with its field named; the ``icp`` section is also checked by the Rust core's
own ``IcpConfig``. ``icploc config check``, ``replay`` and ``run`` all go through it.
``icploc config defaults`` prints :meth:`LocalizerConfig.to_yaml` of the defaults.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, get_args, get_type_hints

import yaml

if TYPE_CHECKING:
    from icploc._core import IcpConfig


class ConfigError(ValueError):
    """A configuration file or value is invalid (unknown key, wrong type, out of range)."""


class _Section:
    """Base of the config sections: type-check and validate at construction."""

    def __post_init__(self) -> None:
        sec = _section_name(self)
        d = self.__dict__
        for name, hint in _hints(type(self)).items():
            v = d[name]
            t = type(v)
            # the common cases inline (a section is built often), the rest by _coerce
            if hint is float and t is float and math.isfinite(v):
                continue
            if (hint is int and t is int) or (hint is bool and t is bool) or (hint is str and t is str):
                continue
            d[name] = _coerce(v, hint, f"{sec}.{name}")
        self.validate()

    def validate(self) -> None:  # pragma: no cover - every section overrides it
        pass


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    """The field types of a section class (cached: sections are built often)."""
    got = _HINTS.get(cls)
    if got is None:
        h = get_type_hints(cls)
        got = _HINTS[cls] = {f.name: h[f.name] for f in dataclasses.fields(cls)}
    return got


def _section_name(obj: Any) -> str:
    return type(obj).__name__.replace("Section", "").lower()


Metric = Literal["point_to_point", "point_to_line"]
Robust = Literal["none", "huber", "cauchy"]
Relocalization = Literal["global", "local"]
LostCheck = Literal["inline", "background"]


def _core_default(name: str) -> Any:
    """The Rust core's default of one ICP setting (``IcpConfig::default()``: the one source)."""
    from icploc._core import IcpConfig

    return getattr(IcpConfig(), name)


@dataclass
class IcpSection(_Section):
    """Settings passed to the Rust ICP core (see ``icploc.IcpConfig``); every default is
    the core's own (``IcpConfig::default()`` in Rust), so an unset key means the same as
    in ``icploc.icp()``.

    The paper uses point-to-point ICP with a fixed rejection threshold; point-to-line
    converges in fewer iterations on wall maps and is the core's default.
    """

    metric: Metric = _core_default("metric")
    max_iterations: int = _core_default("max_iterations")
    #: correspondence threshold at the first iteration (m); shrinks by ``threshold_decay``
    max_correspondence_distance: float = _core_default("max_correspondence_distance")
    #: ... down to this floor (m): the paper's "fixed level" that rejects occluding objects
    min_correspondence_distance: float = _core_default("min_correspondence_distance")
    threshold_decay: float = _core_default("threshold_decay")
    trim_fraction: float = _core_default("trim_fraction")
    robust: Robust = _core_default("robust")
    robust_scale: float = _core_default("robust_scale")
    mse_threshold: float = _core_default("mse_threshold")
    mse_change: float = _core_default("mse_change")
    step_tolerance: float = _core_default("step_tolerance")
    min_inliers: int = _core_default("min_inliers")
    min_inlier_ratio: float = _core_default("min_inlier_ratio")
    #: the verified start: a fit that does not explain the scan triggers a local
    #: branch-and-bound search (+-window_position m, +-window_heading rad) around the start
    window_search: bool = _core_default("window_search")
    window_position: float = _core_default("window_position")
    window_heading: float = _core_default("window_heading")
    window_angle_step: float = _core_default("window_angle_step")
    expected_noise: float = _core_default("expected_noise")
    accept_inlier_ratio: float = _core_default("accept_inlier_ratio")
    accept_see_through: float = _core_default("accept_see_through")

    #: open the first correspondence threshold to cover the odometry prediction's
    #: uncertainty (this many sigmas), up to the cap (m); for sparse logs with big steps
    adaptive_correspondence: bool = True
    correspondence_sigmas: float = 3.0
    max_correspondence_cap: float = 2.0

    def validate(self) -> None:
        _positive(
            self, "max_iterations", "max_correspondence_distance", "min_correspondence_distance"
        )
        if self.min_correspondence_distance > self.max_correspondence_distance:
            raise ConfigError(
                "icp.min_correspondence_distance must not exceed icp.max_correspondence_distance"
            )
        if not 0.0 < self.threshold_decay <= 1.0:
            raise ConfigError("icp.threshold_decay must be in (0, 1]")
        if not 0.0 < self.trim_fraction <= 1.0:
            raise ConfigError("icp.trim_fraction must be in (0, 1]")
        if not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise ConfigError("icp.min_inlier_ratio must be in [0, 1]")
        _positive(self, "correspondence_sigmas", "max_correspondence_cap")
        _at_least(self, 0, "min_inliers")
        # everything the core checks, checked by the core itself
        try:
            self.to_icp_config()
        except (ValueError, OverflowError, TypeError) as e:
            msg = str(e).removeprefix("invalid config: ")
            raise ConfigError(f"icp.{msg}" if " = " in msg else f"icp: {msg}") from None

    def to_icp_config(self) -> IcpConfig:
        """The ``icploc.IcpConfig`` for the Rust core."""
        from icploc._core import IcpConfig

        kw = dataclasses.asdict(self)
        for k in ("adaptive_correspondence", "correspondence_sigmas", "max_correspondence_cap"):
            del kw[k]
        return IcpConfig(**kw)


@dataclass
class ScanSection(_Section):
    """Which beams are used and where the laser sits on the robot."""

    #: beams nearer than this are dropped (m): the robot's own body, dust
    min_range: float = 0.05
    #: beams at or beyond this are dropped (m); 0 = use the scanner's own maximum range
    max_range: float = 0.0
    #: fraction of the scanner's max range treated as "max-range / no return"
    max_range_margin: float = 0.999
    #: keep every n-th beam (1 = all)
    decimation: int = 1
    #: laser mounting offset in the robot base frame: x, y (m) and yaw (rad)
    laser_x: float = 0.0
    laser_y: float = 0.0
    laser_theta: float = 0.0
    #: fewer usable beams than this and the scan is not matched at all
    min_points: int = 20

    def validate(self) -> None:
        if self.min_range < 0.0 or self.max_range < 0.0:
            raise ConfigError("scan.min_range and scan.max_range must be >= 0")
        if self.max_range and self.max_range <= self.min_range:
            raise ConfigError("scan.max_range must exceed scan.min_range (or be 0)")
        if self.decimation < 1:
            raise ConfigError("scan.decimation must be >= 1")
        if not 0.0 < self.max_range_margin <= 1.0:
            raise ConfigError("scan.max_range_margin must be in (0, 1]")
        if self.min_points < 3:
            raise ConfigError("scan.min_points must be >= 3")

    @property
    def mounting(self) -> tuple[float, float, float]:
        return (self.laser_x, self.laser_y, self.laser_theta)


@dataclass
class GatingSection(_Section):
    """How a scan match is checked against the odometry prediction before it is fused.

    The chi-square test of prediction against scan pose (``v' (P + R)^-1 v``, 3 degrees of
    freedom) decides: below the ``chi2_accept`` quantile the match is fused as it is, up to
    the ``chi2_reject`` quantile its covariance is inflated until consistent, beyond it is
    rejected and the prediction kept (the paper's "referring to the past value")."""

    #: chi-square probabilities (3 dof) of the accept and reject quantiles
    chi2_accept: float = 0.99
    chi2_reject: float = 0.9999
    #: hard caps on one correction, whatever the covariances say (m, degrees)
    max_translation_jump: float = 1.5
    max_rotation_jump_deg: float = 45.0
    #: a fit with a smaller inlier ratio is rejected
    min_inlier_ratio: float = 0.12
    #: reject a fit that did not converge (hit the iteration limit / too few inliers)
    require_convergence: bool = False

    def validate(self) -> None:
        _positive(self, "max_translation_jump", "max_rotation_jump_deg")
        if not 0.5 <= self.chi2_accept <= self.chi2_reject < 1.0:
            raise ConfigError(
                "gating: need 0.5 <= chi2_accept <= chi2_reject < 1, got "
                f"{self.chi2_accept}, {self.chi2_reject}"
            )
        if not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise ConfigError("gating.min_inlier_ratio must be in [0, 1]")


@dataclass
class LocalizerSection(_Section):
    """The outer loop: odometry noise model and calibration, the scan covariance,
    verification and status, lost detection and recovery, start pose."""

    #: start pose (x, y, theta) of the robot in the map frame; null = must be given in code
    initial_pose: tuple[float, float, float] | None = None
    #: initial standard deviations (m, m, rad)
    initial_sigma_xy: float = 0.1
    initial_sigma_theta: float = 0.05
    #: odometry motion model (:mod:`icploc.motion`), AMCL-style variances:
    #: heading alpha1 turn^2 + alpha2 dist^2; along alpha3 dist^2 + alpha4 turn^2;
    #: sideways alpha5 dist^2 + alpha4 turn^2. Defaults fitted (maximum likelihood) to the
    #: 2,000 real motions of the Freiburg course data in 0.5 m steps (benches/loc_check.py
    #: --fit-motion): 1.3 % of a turn, 0.36 deg/m, 3.2 % of the distance along and across
    alpha1: float = 1.6e-4
    alpha2: float = 3.9e-5
    alpha3: float = 1.0e-3
    alpha4: float = 1.0e-4
    alpha5: float = 1.0e-3
    #: learn the odometry noise online: the alphas are scaled up (up to ``noise_gain_max``
    #: times) while the accepted fits' chi-square statistic averages above 3
    learn_noise: bool = True
    noise_gain_max: float = 10.0
    #: process noise added at every scan even without motion (slip, a push): keeps the
    #: filter responsive while standing still
    process_sigma_xy: float = 0.002
    process_sigma_theta: float = 0.002
    #: online odometry calibration (:mod:`icploc.calibration`): distance scale, turn scale
    #: and heading drift learned from verified scan matches ``calibration_baseline`` m apart
    #: whose position is known to ``calibration_max_sigma`` m; memory in metres driven;
    #: the factors stay within the bounds
    calibrate_odometry: bool = True
    calibration_memory: float = 50.0
    calibration_baseline: float = 2.0
    calibration_max_sigma: float = 0.05
    calibration_max_scale: float = 0.05
    calibration_max_turn_scale: float = 0.1
    calibration_max_drift_deg: float = 2.0
    #: the prediction's covariance also holds what the calibration has not learned yet
    #: (each factor's spread: half its bound, shrinking with evidence)
    calibration_uncertainty: bool = True
    #: the calibration also learns from fits the odometry agrees with (chi-square accepted,
    #: at least ``verify_min_hit_ratio`` of the beams on walls) that verification turned down
    calibrate_from_consistent: bool = True
    #: the scan match's covariance (:func:`icploc.fusion.scan_covariance`): the information
    #: of this many independent beams on a 10 cm map, inversely proportional to the map's
    #: resolution (a scan's beams share their walls' quantisation); 6 makes the NEES
    #: against the reference ~3 on real logs at 10 cm (benches/loc_check.py)
    scan_independent_beams: float = 6.0
    #: verification of a pose (:mod:`icploc.fitcheck`): at least this share of beams end on
    #: walls, and at least this fraction of the share this map's verified fits show; the
    #: RMS residual of those at most this many expected residuals (the map's resolution and
    #: measured fit quality); optionally few beams through mapped walls
    verify_min_hit_ratio: float = 0.5
    verify_hit_fraction: float = 0.8
    verify_max_residual: float = 2.0
    verify_see_through: bool = False
    verify_max_see_through: float = 0.15
    #: when prediction and scan pose fail the chi-square test, the scan pose is taken (the
    #: prediction's covariance inflated) if it verifies and its hit share beats the
    #: prediction's by at least this
    arbitration_margin: float = 0.1
    #: ... and the disagreement is at most this many times the accept quantile (a jump the
    #: odometry cannot have made stays rejected: the paper's "referring to the past value")
    arbitration_max_inflation: float = 16.0
    #: ... or when this many rejected scan poses in a row agree with each other (moved on by
    #: odometry, within their covariances): the prediction is what is off
    consistent_rejections: int = 3
    #: ``tracking`` promises the pose: verified, and its standard deviation at most this
    #: (m along its worst axis, degrees)
    tracking_max_sigma: float = 0.15
    tracking_max_sigma_theta_deg: float = 3.0
    #: lost when this many scans in a row contradict the pose (no usable fit, a rejected
    #: one, or one no better than the prediction while fewer than ``lost_hit_fraction`` x
    #: the usual share of beams end on walls), or when the position is this uncertain (m)
    lost_after_bad_scans: int = 5
    lost_hit_fraction: float = 0.35
    #: ... unless the beams that do end on walls fit within this many expected residuals
    #: (a crowd hides walls; at a wrong place chance hits scatter)
    crowd_residual: float = 1.2
    lost_sigma_xy: float = 2.0
    #: while lost: the dead reckoning is corrected by scan fits consistent with it (the
    #: chi-square gate, explaining the scan at least as well); the status stays ``lost``
    lost_coasting: bool = True
    #: while lost the odometry noise variances are this many times the learned ones
    lost_noise_gain: float = 4.0
    #: a recovery candidate needs at least this inlier ratio (then verification)
    recover_inlier_ratio: float = 0.6
    #: consecutive verified, consistent scans before a recovery locks
    recover_after: int = 3
    #: the recovery strategy while lost: "global" (:class:`icploc.relocalize.GlobalRelocalization`:
    #: around the dead-reckoned pose first, then anywhere on the map, its grids built the
    #: first time they are needed) or "local" (:class:`icploc.recovery.LocalRecovery`: only
    #: around the dead-reckoned pose). A ``recovery=`` given to the Localizer takes precedence.
    relocalization: Relocalization = "global"
    #: the global recovery's searches (5 ms - 1 s with the map's size): "inline" inside
    #: ``update`` (deterministic: replays, benchmarks) or "background" on a worker thread,
    #: used a scan or more later (``icploc run``: a live loop must not stall)
    lost_check: LostCheck = "inline"
    #: while lost, scans spent searching only around the dead-reckoned pose before the
    #: global search joins in
    local_recovery_scans: int = 3
    #: while lost and searching globally: at most one global search per this many scans and
    #: per this many seconds of scan time (between searches the hypotheses are carried by
    #: odometry and re-scored on every scan)
    global_search_every: int = 10
    global_search_interval: float = 1.0
    #: a scan newer than the newest odometry sample is predicted by extrapolating at the last
    #: odometry velocity for at most min(0.25 s, this) seconds, then the pose is held
    max_odometry_gap: float = 1.0

    def validate(self) -> None:
        if self.initial_pose is not None:
            if len(self.initial_pose) != 3 or not all(math.isfinite(v) for v in self.initial_pose):
                raise ConfigError(
                    "localizer.initial_pose must be three finite numbers [x, y, theta]"
                )
        _positive(
            self,
            "initial_sigma_xy",
            "initial_sigma_theta",
            "calibration_memory",
            "calibration_baseline",
            "calibration_max_sigma",
            "scan_independent_beams",
            "verify_max_residual",
            "crowd_residual",
            "tracking_max_sigma",
            "tracking_max_sigma_theta_deg",
            "lost_sigma_xy",
            "arbitration_max_inflation",
            "noise_gain_max",
            "lost_noise_gain",
        )
        for name in (
            "process_sigma_xy",
            "process_sigma_theta",
            "alpha1",
            "alpha2",
            "alpha3",
            "alpha4",
            "alpha5",
            "calibration_max_scale",
            "calibration_max_turn_scale",
            "calibration_max_drift_deg",
            "verify_max_see_through",
        ):
            v = getattr(self, name)
            if not (v >= 0.0 and math.isfinite(v)):
                raise ConfigError(f"localizer.{name} must be a finite number >= 0, got {v!r}")
        for name in (
            "recover_inlier_ratio",
            "verify_min_hit_ratio",
            "verify_hit_fraction",
            "arbitration_margin",
            "lost_hit_fraction",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"localizer.{name} must be in [0, 1]")
        _positive(
            self,
            "lost_after_bad_scans",
            "consistent_rejections",
            "recover_after",
            "local_recovery_scans",
            "global_search_every",
            "max_odometry_gap",
        )
        if not (self.global_search_interval >= 0.0 and math.isfinite(self.global_search_interval)):
            raise ConfigError("localizer.global_search_interval must be a finite number >= 0")
        if self.relocalization not in ("global", "local"):
            raise ConfigError(
                f"localizer.relocalization must be 'global' or 'local', got {self.relocalization!r}"
            )


@dataclass
class MapSection(_Section):
    """How the map is turned into the ICP index."""

    #: uniform sampling interval along the fitted wall lines (m), the paper's §2.2
    spacing: float = 0.05
    #: the map's resolution (m) the thresholds scale with; 0: a grid's cell size, else the
    #: median spacing of the map's sample points
    resolution: float = 0.0
    #: match each scan only against map points the laser could see from the predicted pose
    visibility_culling: bool = False
    #: field of view (degrees) and range (m) used for the culling
    visibility_fov_deg: float = 360.0
    visibility_max_range: float = 30.0

    def validate(self) -> None:
        _positive(self, "spacing", "visibility_fov_deg", "visibility_max_range")
        if self.spacing < MIN_MAP_SPACING:
            raise ConfigError(
                f"map.spacing must be at least {MIN_MAP_SPACING} m (1 mm), got {self.spacing!r}"
            )
        if not (self.resolution >= 0.0 and math.isfinite(self.resolution)):
            raise ConfigError(f"map.resolution must be a finite number >= 0, got {self.resolution!r}")


#: the finest map sampling accepted (m): finer multiplies the index size for no accuracy
MIN_MAP_SPACING = 0.001


@dataclass
class LocalizerConfig:
    """Every setting of the localizer, by section."""

    icp: IcpSection = field(default_factory=IcpSection)
    scan: ScanSection = field(default_factory=ScanSection)
    gating: GatingSection = field(default_factory=GatingSection)
    localizer: LocalizerSection = field(default_factory=LocalizerSection)
    map: MapSection = field(default_factory=MapSection)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            want = f.default_factory  # type: ignore[misc]
            got = getattr(self, f.name)
            if not isinstance(got, want):  # type: ignore[arg-type]
                raise ConfigError(
                    f"{f.name}: expected a {want.__name__}, got {type(got).__name__}"  # type: ignore[union-attr]
                )

    # -- validation ----------------------------------------------------------------------
    def validate(self) -> LocalizerConfig:
        """Raise :class:`ConfigError` when a value is out of range; return self."""
        for f in dataclasses.fields(self):
            getattr(self, f.name).validate()
        return self

    # -- dict / YAML -----------------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for f in dataclasses.fields(self):
            sec = getattr(self, f.name)
            d: dict[str, Any] = {}
            for sf in dataclasses.fields(sec):
                v = getattr(sec, sf.name)
                d[sf.name] = list(v) if isinstance(v, tuple) else v
            out[f.name] = d
        return out

    def to_yaml(self) -> str:
        header = "# icploc localizer configuration (every key optional; unknown keys are errors)\n"
        return header + yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=False)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_yaml())

    @classmethod
    def from_dict(cls, data: Any, source: str = "<dict>") -> LocalizerConfig:
        """Build a config from nested mappings over the defaults (partial input is fine)."""
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ConfigError(
                f"{source}: the top level must be a mapping of sections, got {type(data).__name__}"
            )
        cfg = cls()
        sections = {f.name: f for f in dataclasses.fields(cls)}
        for key, value in data.items():
            if key not in sections:
                raise ConfigError(
                    f"{source}: unknown section {key!r}; valid sections: {', '.join(sections)}"
                )
            if value is None:
                continue
            if not isinstance(value, dict):
                raise ConfigError(
                    f"{source}: section {key!r} must be a mapping, got {type(value).__name__}"
                )
            sec = getattr(cfg, key)
            try:
                setattr(cfg, key, _update_section(sec, value, key))
            except ConfigError as e:
                raise ConfigError(f"{source}: {e}") from None
        try:
            return cfg.validate()
        except ConfigError as e:
            raise ConfigError(f"{source}: {e}") from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> LocalizerConfig:
        p = Path(path)
        try:
            if p.stat().st_size > MAX_CONFIG_BYTES:
                raise ConfigError(f"{p}: not a config file (more than {MAX_CONFIG_BYTES:,} bytes)")
            raw = p.read_bytes()
        except OSError as e:
            raise ConfigError(f"{p}: cannot read config file: {e.strerror or e}") from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            line = raw[: e.start].count(b"\n") + 1
            raise ConfigError(
                f"{p}:{line}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start}); "
                "save the config file as UTF-8"
            ) from None
        try:
            data = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader
        except _DuplicateKey as e:
            raise ConfigError(f"{p}:{e.line}: {e}") from None
        except yaml.YAMLError as e:
            raise ConfigError(f"{p}: invalid YAML: {e}") from None
        return cls.from_dict(data, str(p))

    def replace(self, **sections: Any) -> LocalizerConfig:
        """A copy with some sections replaced (or updated from mappings)."""
        new = dataclasses.replace(self)
        for name, value in sections.items():
            cur = getattr(new, name)
            if isinstance(value, dict):
                value = _update_section(cur, value, name)
            setattr(new, name, value)
        return new.validate()


#: a config file larger than this is not one (a wrong path): refused before parsing
MAX_CONFIG_BYTES = 1 << 20


class _DuplicateKey(yaml.YAMLError):
    def __init__(self, key: Any, first: int, line: int) -> None:
        super().__init__(f"duplicate key {key!r} (first at line {first})")
        self.line = line


class _UniqueKeyLoader(yaml.SafeLoader):
    """The safe loader, with a duplicated mapping key an error (not a silent override)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, Any] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            try:
                dup = key in seen
            except TypeError:
                continue  # an unhashable key: the base class reports it
            if dup:
                raise _DuplicateKey(key, seen[key].line + 1, key_node.start_mark.line + 1)
            seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _positive(obj: Any, *names: str) -> None:
    sec = _section_name(obj)
    for n in names:
        v = getattr(obj, n)
        if not (v > 0) or (isinstance(v, float) and not math.isfinite(v)):
            raise ConfigError(f"{sec}.{n} must be a finite positive number, got {v!r}")


def _at_least(obj: Any, low: int, *names: str) -> None:
    sec = _section_name(obj)
    for n in names:
        v = getattr(obj, n)
        if v < low:
            raise ConfigError(f"{sec}.{n} must be >= {low}, got {v!r}")


def _update_section(sec: Any, values: dict[str, Any], where: str) -> Any:
    hints = _hints(type(sec))
    names = list(hints)
    changes: dict[str, Any] = {}
    for key, raw in values.items():
        if key not in names:
            raise ConfigError(f"{where}: unknown key {key!r}; valid keys: {', '.join(names)}")
        changes[key] = _coerce(raw, hints[key], f"{where}.{key}")
    return dataclasses.replace(sec, **changes)


def _coerce(value: Any, hint: Any, where: str) -> Any:
    args = get_args(hint)
    origin = getattr(hint, "__origin__", None)
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected true/false, got {value!r}")
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ConfigError(f"{where}: must be a finite number, got {v!r}")
        return v
    if origin is Literal:
        if value not in args:
            raise ConfigError(
                f"{where}: expected one of {', '.join(map(repr, args))}, got {value!r}"
            )
        return value
    if args and type(None) in args:  # Optional[...]
        if value is None:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(value, inner[0], where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise ConfigError(f"{where}: expected a list of {len(args)} numbers, got {value!r}")
        return tuple(_coerce(v, a, where) for v, a in zip(value, args, strict=True))
    return value  # a type this checker does not know: the section's validate() checks it


def default_yaml() -> str:
    """The defaults as YAML (what ``icploc config defaults`` prints)."""
    return LocalizerConfig().to_yaml()
