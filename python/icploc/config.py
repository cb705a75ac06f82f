"""Typed configuration of the localizer, loadable from and dumpable to YAML.

One dataclass per section::

    icp:       the ICP core's settings (metric, thresholds, iterations, robust weights)
    scan:      scan preparation (range limits, decimation, laser mounting offset)
    gating:    how a correction is checked against the odometry prediction
    localizer: the outer loop (odometry noise model, lost detection, initial pose)
    map:       how the map is sampled for the ICP index (spacing, visibility culling)

``LocalizerConfig.from_yaml(path)`` reads a (possibly partial) YAML file over the
defaults; an unknown section or key, or a value of the wrong type, raises
:class:`ConfigError` naming the file, the section and the key.
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


Metric = Literal["point_to_point", "point_to_line"]
Robust = Literal["none", "huber", "cauchy"]
Relocalization = Literal["global", "local"]
LostCheck = Literal["inline", "background"]


def _core_default(name: str) -> Any:
    """The Rust core's default of one ICP setting (``IcpConfig::default()``: the one source)."""
    from icploc._core import IcpConfig

    return getattr(IcpConfig(), name)


@dataclass
class IcpSection:
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

    def to_icp_config(self) -> IcpConfig:
        """The ``icploc.IcpConfig`` for the Rust core."""
        from icploc._core import IcpConfig

        kw = dataclasses.asdict(self)
        for k in ("adaptive_correspondence", "correspondence_sigmas", "max_correspondence_cap"):
            del kw[k]
        return IcpConfig(**kw)


@dataclass
class ScanSection:
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
class GatingSection:
    """The paper's "referring to the past value": a correction the odometry cannot
    explain is rejected, and the odometry prediction is kept instead."""

    #: largest accepted position correction (m) right after an accepted scan ...
    max_translation_jump: float = 0.25
    #: ... growing by this much per metre driven since the last accepted correction
    translation_jump_per_metre: float = 0.10
    #: largest accepted heading correction (degrees) ...
    max_rotation_jump_deg: float = 8.0
    #: ... growing by this much per radian turned and per metre driven since then
    rotation_jump_per_radian_deg: float = 6.0
    rotation_jump_per_metre_deg: float = 3.0
    #: the gate never opens wider than this (m, degrees)
    max_translation_jump_cap: float = 1.5
    max_rotation_jump_cap_deg: float = 45.0
    #: a fit with a smaller inlier ratio is rejected
    min_inlier_ratio: float = 0.12
    #: translational degeneracy (lambda_min / lambda_max) below which the fit is treated as
    #: a corridor: along the degenerate direction the odometry prediction is kept
    degeneracy_threshold: float = 0.02
    #: reject a fit that did not converge (hit the iteration limit / too few inliers)
    require_convergence: bool = False

    def validate(self) -> None:
        _positive(
            self,
            "max_translation_jump",
            "max_rotation_jump_deg",
            "max_translation_jump_cap",
            "max_rotation_jump_cap_deg",
        )
        for name in (
            "translation_jump_per_metre",
            "rotation_jump_per_radian_deg",
            "rotation_jump_per_metre_deg",
        ):
            if getattr(self, name) < 0.0:
                raise ConfigError(f"gating.{name} must be >= 0")
        if not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise ConfigError("gating.min_inlier_ratio must be in [0, 1]")
        if not 0.0 <= self.degeneracy_threshold < 1.0:
            raise ConfigError("gating.degeneracy_threshold must be in [0, 1)")


@dataclass
class LocalizerSection:
    """The outer loop: odometry noise model, lost detection, start pose."""

    #: start pose (x, y, theta) of the robot in the map frame; null = must be given in code
    initial_pose: tuple[float, float, float] | None = None
    #: initial standard deviations (m, m, rad)
    initial_sigma_xy: float = 0.1
    initial_sigma_theta: float = 0.05
    #: odometry noise: position sigma per metre driven, heading sigma per radian turned
    #: and per metre driven (added in quadrature to the predicted covariance)
    odom_sigma_per_metre: float = 0.05
    odom_sigma_theta_per_radian: float = 0.05
    odom_sigma_theta_per_metre: float = 0.02
    #: process noise added at every scan even without motion (slip, a push): keeps the
    #: filter responsive while standing still
    process_sigma_xy: float = 0.002
    process_sigma_theta: float = 0.002
    #: fuse the ICP pose with the odometry prediction (Kalman update, ICP covariance
    #: floored by min_sigma_*) instead of taking the ICP pose as it is
    fuse_odometry: bool = True
    #: floor on the ICP pose's standard deviation (its measurement noise) after a correction
    min_sigma_xy: float = 0.002
    min_sigma_theta: float = 0.001
    #: lost when the inlier ratio stays below ``lost_inlier_ratio`` for this many scans ...
    lost_inlier_ratio: float = 0.1
    lost_after_low_inlier_scans: int = 5
    #: ... or when this many scans in a row are rejected by the gate
    lost_after_rejections: int = 15
    #: while lost, a fit with at least this inlier ratio (and not degenerate) recovers tracking
    recover_inlier_ratio: float = 0.7
    #: consecutive good fits needed to recover
    recover_after: int = 3
    #: "global": kidnap detection and multi-hypothesis global relocalization anywhere on the
    #: map (:mod:`icploc.relocalize`; its grids are built the first time they are needed);
    #: "local": only the built-in recovery around the dead-reckoned pose (plus a
    #: ``global_search=`` hook). A ``global_search=`` or ``relocalization=`` given to the
    #: Localizer takes precedence.
    relocalization: Relocalization = "global"
    #: the global relocalization's lost checks (a global search each, 5 ms - 1 s with the
    #: map's size): "inline" inside ``update`` (deterministic: replays, benchmarks) or
    #: "background" on a worker thread, acted on a few scans later (``icploc run``: a live
    #: loop must not stall)
    lost_check: LostCheck = "inline"
    #: while lost, try to relocalize on every n-th scan (each try is a multi-start ICP)
    relocalize_every: int = 4
    #: while lost with a global search attached (no initial pose, a kidnapping): at most one
    #: global search per this many scans and per this many seconds of scan time (the first
    #: lost scan always searches; between searches the hypotheses are carried by odometry
    #: and re-scored on every scan)
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
            self, "initial_sigma_xy", "initial_sigma_theta", "min_sigma_xy", "min_sigma_theta"
        )
        for name in (
            "process_sigma_xy",
            "process_sigma_theta",
            "odom_sigma_per_metre",
            "odom_sigma_theta_per_radian",
            "odom_sigma_theta_per_metre",
        ):
            if getattr(self, name) < 0.0:
                raise ConfigError(f"localizer.{name} must be >= 0")
        if not 0.0 <= self.lost_inlier_ratio <= 1.0 or not 0.0 <= self.recover_inlier_ratio <= 1.0:
            raise ConfigError("localizer inlier ratios must be in [0, 1]")
        _positive(
            self,
            "lost_after_low_inlier_scans",
            "lost_after_rejections",
            "recover_after",
            "relocalize_every",
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
class MapSection:
    """How the map is turned into the ICP index."""

    #: uniform sampling interval along the fitted wall lines (m), the paper's §2.2
    spacing: float = 0.05
    #: match each scan only against map points the laser could see from the predicted pose
    visibility_culling: bool = False
    #: field of view (degrees) and range (m) used for the culling
    visibility_fov_deg: float = 360.0
    visibility_max_range: float = 30.0

    def validate(self) -> None:
        _positive(self, "spacing", "visibility_fov_deg", "visibility_max_range")


@dataclass
class LocalizerConfig:
    """Every setting of the localizer, by section."""

    icp: IcpSection = field(default_factory=IcpSection)
    scan: ScanSection = field(default_factory=ScanSection)
    gating: GatingSection = field(default_factory=GatingSection)
    localizer: LocalizerSection = field(default_factory=LocalizerSection)
    map: MapSection = field(default_factory=MapSection)

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
            setattr(cfg, key, _update_section(sec, value, f"{source}: {key}"))
        try:
            return cfg.validate()
        except ConfigError as e:
            raise ConfigError(f"{source}: {e}") from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> LocalizerConfig:
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as e:
            raise ConfigError(f"{p}: cannot read config file: {e.strerror or e}") from None
        try:
            data = yaml.safe_load(text)
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


def _positive(obj: Any, *names: str) -> None:
    sec = type(obj).__name__.replace("Section", "").lower()
    for n in names:
        v = getattr(obj, n)
        if not (v > 0) or (isinstance(v, float) and not math.isfinite(v)):
            raise ConfigError(f"{sec}.{n} must be a finite positive number, got {v!r}")


def _update_section(sec: Any, values: dict[str, Any], where: str) -> Any:
    hints = get_type_hints(type(sec))
    names = [f.name for f in dataclasses.fields(sec)]
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
        if math.isnan(v):
            raise ConfigError(f"{where}: NaN is not allowed")
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
    raise ConfigError(f"{where}: unsupported type {hint!r}")  # pragma: no cover


def default_yaml() -> str:
    """The defaults as YAML (what ``icploc config defaults`` prints)."""
    return LocalizerConfig().to_yaml()
