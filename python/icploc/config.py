"""Typed configuration of the localizer, loadable from and dumpable to YAML.

One dataclass per section::

    icp:       the ICP core's settings (metric, thresholds, iterations, robust weights)
    scan:      scan preparation (range limits, decimation, laser mounting offset)
    gating:    how a correction is checked against the odometry prediction
    localizer: the outer loop (odometry noise model, lost detection, initial pose)
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


@dataclass
class IcpSection(_Section):
    """Settings passed to the Rust ICP core (see ``icploc.IcpConfig``).

    The paper uses point-to-point ICP with a fixed rejection threshold; point-to-line
    converges in fewer iterations on wall maps and is the default here.
    """

    metric: Metric = "point_to_line"
    max_iterations: int = 30
    #: correspondence threshold at the first iteration (m); shrinks by ``threshold_decay``
    max_correspondence_distance: float = 0.5
    #: ... down to this floor (m): the paper's "fixed level" that rejects occluding objects
    min_correspondence_distance: float = 0.12
    threshold_decay: float = 0.6
    trim_fraction: float = 1.0
    robust: Robust = "huber"
    robust_scale: float = 0.05
    mse_threshold: float = 1e-8
    mse_change: float = 1e-7
    step_tolerance: float = 1e-5
    min_inliers: int = 10
    min_inlier_ratio: float = 0.0

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
class LocalizerSection(_Section):
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
class MapSection(_Section):
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
        if self.spacing < MIN_MAP_SPACING:
            raise ConfigError(
                f"map.spacing must be at least {MIN_MAP_SPACING} m (1 mm), got {self.spacing!r}"
            )


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
