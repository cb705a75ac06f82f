"""Typed configuration of the localizer: one pydantic model per section, the one source of
every setting's type, range, default, unit and description.

Sections (the keys of a YAML config file)::

    icp:        the ICP core's settings (metric, thresholds, iterations, robust weights)
    scan:       scan preparation (range limits, decimation, laser mounting offset)
    gating:     how a correction is checked against the odometry prediction (chi-square)
    localizer:  the outer loop (motion model, calibration, verification, lost, recovery)
    map:        how the map is sampled for the ICP index (spacing, visibility culling)
    relocalize: the global relocalization's hypothesis tracker and kidnap check
    global_search: the global search both run (icploc.GlobalLocalizer; the core's defaults)
    recovery:   the local recovery around the dead-reckoned pose
    kidnap:     when a global kidnap check runs while tracking
    outside:    the outside-the-map state (icploc.outside; on by default)

``LocalizerConfig.from_yaml(path)`` reads a (possibly partial) YAML file over the defaults.
Every section validates at construction (and on assignment, and in :meth:`Section.replace`):
an unknown or duplicated section or key, a value of the wrong type, a non-finite number or
one out of range raises :class:`icploc.errors.ConfigError` naming the file and the field,
e.g. ``config.yaml: localizer.lost_sigma_xy: must be > 0, got -1``. The ICP defaults are
the Rust core's own (``IcpConfig::default()``) and the ``icp`` section is also checked by
the core's ``IcpConfig``. ``icploc config defaults`` prints :meth:`LocalizerConfig.to_yaml`
of the defaults (every key with its description and unit), ``icploc config check`` the
configuration a file gives.
"""

from __future__ import annotations

import math
import textwrap
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal, get_args

from icploc.errors import ConfigError
from icploc.lazy_model import LazyModel, field_validator, model_validator
from icploc.lazy_model import field as _field

if TYPE_CHECKING:
    from pydantic import ValidationError, ValidationInfo
    from typing_extensions import Self

    from icploc._core import IcpConfig

__all__ = [
    "ConfigError",
    "GatingSection",
    "GlobalSearchSection",
    "IcpSection",
    "KidnapSection",
    "LocalizerConfig",
    "LocalizerSection",
    "MapSection",
    "OutsideSection",
    "RecoverySection",
    "RelocalizeSection",
    "ScanSection",
    "Section",
    "default_yaml",
]

Metric = Literal["point_to_point", "point_to_line"]
Robust = Literal["none", "huber", "cauchy"]
Relocalization = Literal["global", "local"]
LostCheck = Literal["inline", "background"]

#: the finest map sampling accepted (m): finer multiplies the index size for no accuracy
MIN_MAP_SPACING = 0.001
#: a config file larger than this is not one (a wrong path): refused before parsing
MAX_CONFIG_BYTES = 1 << 20


def _core_default(name: str) -> Any:
    """The Rust core's default of one ICP setting (``IcpConfig::default()``: the one source)."""
    from icploc._core import IcpConfig

    return getattr(IcpConfig(), name)


def _f(default: Any, doc: str, unit: str = "", **limits: Any) -> Any:
    """A field: its default, its description, its unit (m, rad, deg, s, Hz, scans, ...)
    and its range (``gt`` / ``ge`` / ``lt`` / ``le``)."""
    return _field(default, doc, unit, **limits)


class Section(LazyModel):
    """Base of the config sections: strict types (an int is an int, a bool is no number),
    finite floats, no unknown keys, validated at construction, on assignment and in
    :meth:`replace`; a :class:`ConfigError` names the section and the field.

    The sections are :class:`icploc.lazy_model.LazyModel` classes: written as pydantic
    models and validated by one (their twin, built on first use); the defaults take no
    validator, so a process that only uses them never imports pydantic (~70 ms)."""

    model_settings: ClassVar[dict[str, Any]] = {
        "extra": "forbid",
        "strict": True,
        "allow_inf_nan": False,
        "validate_assignment": True,
    }
    #: the section's key in a config file
    section: ClassVar[str] = ""

    @classmethod
    def validation_error(cls, e: ValidationError) -> Exception:
        return _config_error(e, cls)

    def replace(self, **changes: Any) -> Self:
        """A validated copy with some values changed (``dataclasses.replace`` for a section)."""
        return type(self)(**{**self.__dict__, **changes})

    def validate(self) -> Self:  # type: ignore[override]
        """Every section is valid from construction on: returns self (kept for callers)."""
        return self

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.__dict__.items()}


def _tuple(v: Any) -> Any:
    return tuple(v) if isinstance(v, list) else v


class IcpSection(Section):
    """Settings passed to the Rust ICP core (see ``icploc.IcpConfig``); every default is
    the core's own (``IcpConfig::default()`` in Rust), so an unset key means the same as in
    ``icploc.icp()``. The paper uses point-to-point ICP with a fixed rejection threshold;
    point-to-line converges in fewer iterations on wall maps and is the core's default."""

    section: ClassVar[str] = "icp"

    metric: Metric = _f(_core_default("metric"), "error metric: point_to_point or point_to_line")
    max_iterations: int = _f(_core_default("max_iterations"), "ICP iterations at most", gt=0)
    max_correspondence_distance: float = _f(
        _core_default("max_correspondence_distance"),
        "correspondence threshold at the first iteration; shrinks by threshold_decay",
        "m",
        gt=0,
    )
    min_correspondence_distance: float = _f(
        _core_default("min_correspondence_distance"),
        "... down to this floor: the paper's fixed level that rejects occluding objects",
        "m",
        gt=0,
    )
    threshold_decay: float = _f(
        _core_default("threshold_decay"), "factor on the threshold per iteration", gt=0, le=1
    )
    trim_fraction: float = _f(
        _core_default("trim_fraction"), "share of the best pairs kept (trimmed ICP)", gt=0, le=1
    )
    robust: Robust = _f(_core_default("robust"), "robust weight: none, huber or cauchy")
    robust_scale: float = _f(_core_default("robust_scale"), "scale of the robust weight", "m")
    mse_threshold: float = _f(
        _core_default("mse_threshold"), "converged below this mean squared error", "m^2"
    )
    mse_change: float = _f(
        _core_default("mse_change"), "converged when the MSE changes by less than this", "m^2"
    )
    step_tolerance: float = _f(
        _core_default("step_tolerance"),
        "converged when a step moves less than this (point-to-line: less than its square root, at most 1 mm / 1 mrad)",
        "m, rad",
    )
    min_inliers: int = _f(
        _core_default("min_inliers"), "a fit needs at least this many pairs", ge=0
    )
    min_inlier_ratio: float = _f(
        _core_default("min_inlier_ratio"), "a fit needs at least this share of pairs", ge=0, le=1
    )
    window_search: bool = _f(
        _core_default("window_search"),
        "the verified start: a fit that does not explain the scan triggers a local "
        "branch-and-bound search around the start",
    )
    window_position: float = _f(
        _core_default("window_position"), "the window search's half width in x and y", "m"
    )
    window_heading: float = _f(
        _core_default("window_heading"), "the window search's half width in heading", "rad"
    )
    window_angle_step: float = _f(
        _core_default("window_angle_step"), "the window search's heading step", "rad"
    )
    expected_noise: float = _f(
        _core_default("expected_noise"),
        "range noise a good fit shows (for the verified start)",
        "m",
    )
    accept_inlier_ratio: float = _f(
        _core_default("accept_inlier_ratio"),
        "the verified start accepts a fit with at least this inlier ratio",
    )
    accept_see_through: float = _f(
        _core_default("accept_see_through"),
        "... and at most this share of beams through mapped walls",
    )
    prior_sure_rms: float = _f(
        _core_default("prior_sure_rms"),
        "a loosely accepted fit from the heading prior within this RMS (x expected_noise) "
        "skips the comparison with the ICP from the initial pose (0: always compared)",
        ge=0,
    )
    vanished_object_size: float = _f(
        _core_default("vanished_object_size"),
        "the verified start does not count beams through mapped objects of at most this "
        "size (bounding-box diagonal) that the scan does not see (a parked car that left) "
        "as beams through walls (0: every crossing counts)",
        "m",
        ge=0,
    )
    adaptive_correspondence: bool = _f(
        True,
        "open the first correspondence threshold to cover the odometry prediction's "
        "uncertainty (correspondence_sigmas), up to max_correspondence_cap: sparse logs",
    )
    correspondence_sigmas: float = _f(3.0, "sigmas of the prediction covered", "sigma", gt=0)
    max_correspondence_cap: float = _f(2.0, "cap of the opened threshold", "m", gt=0)

    #: this section's keys that are the Python outer loop's, not the core's
    _OUTER: ClassVar[tuple[str, ...]] = (
        "adaptive_correspondence",
        "correspondence_sigmas",
        "max_correspondence_cap",
    )

    @model_validator(mode="after")
    def _check(self) -> IcpSection:
        if self.min_correspondence_distance > self.max_correspondence_distance:
            raise ValueError(
                "min_correspondence_distance: must not exceed max_correspondence_distance "
                f"({self.min_correspondence_distance} > {self.max_correspondence_distance})"
            )
        # everything the core checks, checked by the core itself
        try:
            self.to_icp_config()
        except (ValueError, OverflowError, TypeError) as e:
            raise ValueError(_core_message(str(e))) from None
        return self

    def to_icp_config(self, **changes: Any) -> IcpConfig:
        """The ``icploc.IcpConfig`` for the Rust core, with some of the core's settings
        changed (``replace(**changes).to_icp_config()`` without a section in between; the
        core checks the values, raising ``InvalidConfigError``)."""
        from icploc._core import IcpConfig

        kw = {k: v for k, v in self.__dict__.items() if k not in self._OUTER}
        unknown = sorted(set(changes) - set(kw))
        if unknown:
            raise TypeError(f"to_icp_config: not a setting of the core: {', '.join(unknown)}")
        return IcpConfig(**{**kw, **changes})


def _core_message(msg: str) -> str:
    """``invalid config: robust_scale = 0: must be positive`` -> ``robust_scale: must be
    positive, got 0`` (the core's InvalidConfigError, worded as the other fields' errors)."""
    msg = msg.removeprefix("invalid config: ")
    head, sep, reason = msg.partition(": ")
    name, eq, value = head.partition(" = ")
    if sep and eq and name.isidentifier():
        return f"{name}: {reason}, got {value}"
    return msg


class ScanSection(Section):
    """Which beams are used and where the laser sits on the robot."""

    section: ClassVar[str] = "scan"

    min_range: float = _f(0.05, "beams nearer than this are dropped (the robot, dust)", "m", ge=0)
    max_range: float = _f(
        0.0, "beams at or beyond this are dropped; 0: the scanner's own maximum", "m", ge=0
    )
    max_range_margin: float = _f(
        0.999, "share of the scanner's max range read as max-range / no return", gt=0, le=1
    )
    decimation: int = _f(1, "keep every n-th beam (1: all)", ge=1)
    laser_x: float = _f(0.0, "laser mounting in the robot base frame: x", "m")
    laser_y: float = _f(0.0, "laser mounting in the robot base frame: y", "m")
    laser_theta: float = _f(0.0, "laser mounting in the robot base frame: yaw", "rad")
    min_points: int = _f(20, "fewer usable beams than this and the scan is not matched", ge=3)
    lasers: Any = _f(
        (),
        "several lasers merged into one correction (icploc.multilaser): a list of {name, "
        "frame, x, y, yaw, upside_down, time_offset, port, baud}; empty: one laser at "
        "laser_x / laser_y / laser_theta",
    )

    @field_validator("lasers", mode="after")
    @classmethod
    def _lasers(cls, v: Any, info: ValidationInfo) -> Any:
        if v == () or v is None:
            return ()
        from icploc.laser_mounts import check_lasers

        d = info.data
        single = (d.get("laser_x", 0.0), d.get("laser_y", 0.0), d.get("laser_theta", 0.0))
        return check_lasers(v, single)

    @model_validator(mode="after")
    def _check(self) -> ScanSection:
        if self.max_range and self.max_range <= self.min_range:
            raise ValueError(
                f"max_range: must exceed min_range (or be 0), got {self.max_range} "
                f"<= {self.min_range}"
            )
        return self

    @property
    def mounting(self) -> tuple[float, float, float]:
        return (self.laser_x, self.laser_y, self.laser_theta)


class GatingSection(Section):
    """How a scan match is checked against the odometry prediction before it is fused: the
    chi-square test of prediction against scan pose (v' (P + R)^-1 v, 3 degrees of freedom)
    fuses it below the chi2_accept quantile, inflates its covariance up to chi2_reject and
    rejects it beyond (the paper's "referring to the past value")."""

    section: ClassVar[str] = "gating"

    chi2_accept: float = _f(
        0.99, "chi-square probability (3 dof) of the accept quantile", ge=0.5, lt=1
    )
    chi2_reject: float = _f(0.9999, "... of the reject quantile (>= chi2_accept)", ge=0.5, lt=1)
    heading_test: bool = _f(
        True,
        "test the heading on its own too: the tracking gate's statistic is the larger of the joint "
        "v' (P + R)^-1 v and the 3-dof value with the tail of the heading's own "
        "v_t^2 / (P + R)_tt (1 dof), so a position covariance grown by a turn does not "
        "loosen the heading a fit may take",
    )
    max_translation_jump: float = _f(1.5, "hard cap on one correction's translation", "m", gt=0)
    max_rotation_jump_deg: float = _f(45.0, "hard cap on one correction's rotation", "deg", gt=0)
    min_inlier_ratio: float = _f(0.12, "a fit with a smaller inlier ratio is rejected", ge=0, le=1)
    require_convergence: bool = _f(
        False, "reject a fit that did not converge (iteration limit, too few inliers)"
    )

    @model_validator(mode="after")
    def _check(self) -> GatingSection:
        if self.chi2_accept > self.chi2_reject:
            raise ValueError(
                f"chi2_accept: must not exceed chi2_reject ({self.chi2_accept} > {self.chi2_reject})"
            )
        return self


class LocalizerSection(Section):
    """The outer loop: odometry noise model and calibration, the scan covariance,
    verification and status, lost detection and recovery, start pose."""

    section: ClassVar[str] = "localizer"

    initial_pose: tuple[float, float, float] | None = _f(
        None, "start pose [x, y, theta] in the map frame; null: given in code", "m, m, rad"
    )
    initial_sigma_xy: float = _f(0.1, "initial standard deviation of x and y", "m", gt=0)
    initial_sigma_theta: float = _f(0.05, "initial standard deviation of the heading", "rad", gt=0)
    # the odometry motion model (icploc.motion), AMCL-style variances; defaults fitted
    # (maximum likelihood) to the 2,000 real motions of the Freiburg course data in 0.5 m
    # steps (benches/loc_check.py --fit-motion): 1.3 % of a turn, 0.36 deg/m, 3.2 % of the
    # distance along and across
    alpha1: float = _f(1.6e-4, "heading variance per squared turn", "rad^2/rad^2", ge=0)
    alpha2: float = _f(3.9e-5, "heading variance per squared distance", "rad^2/m^2", ge=0)
    alpha3: float = _f(1.0e-3, "along-track variance per squared distance", "m^2/m^2", ge=0)
    alpha4: float = _f(
        1.0e-4, "along- and cross-track variance per squared turn", "m^2/rad^2", ge=0
    )
    alpha5: float = _f(1.0e-3, "cross-track variance per squared distance", "m^2/m^2", ge=0)
    turn_walk_variance: float = _f(
        2.0e-3,
        "along- and cross-track variance per radian turned, growing linearly with the turn (a "
        "random walk: the wheels' slip over a turn on the spot adds up per radian); the real "
        "paired motions hold no step turning 0.3 rad, so alpha4's fit says nothing about it",
        "m^2/rad",
        ge=0,
    )
    turn_walk_max_travel: float = _f(
        0.5,
        "a step that travelled farther than this adds no turn walk: the walk is a turn on "
        "the spot's, the alphas cover a step as long as the 0.5 m motions they were fitted "
        "to; 0: every step",
        "m",
        ge=0,
    )
    learn_noise: bool = _f(
        True,
        "learn the odometry noise online (icploc.motion.NoiseGain): the alphas scale up (to "
        "noise_gain_max) until the prediction is consistent with the fits the map backs",
    )
    noise_gain_max: float = _f(10.0, "largest factor on the alphas", gt=0)
    grow_on_rejected_fit: bool = _f(
        False,
        "grow the prediction's covariance (by at most noise_gain_max over rejected scans in a "
        "row) when a rejected fit explains clearly more of the scan than the prediction; off "
        "by default: it helped the tuned real-data cells (intel 5 cm bad p95 30 -> 24 cm) but "
        "sent infinite-corridor 5 cm bad 55 m off while lost (3.1 m without)",
    )
    noise_gain_window: int = _f(
        31, "the learned factor is the median over the last this many trusted fits", "scans", ge=1
    )
    noise_gain_min_samples: int = _f(
        5, "... once at least this many are in (until then: 1, the configured alphas)", "scans", ge=1
    )
    process_sigma_xy: float = _f(
        0.002, "process noise per scan even without motion (slip, a push)", "m", ge=0
    )
    process_sigma_theta: float = _f(0.002, "... in heading", "rad", ge=0)
    calibrate_odometry: bool = _f(
        True,
        "online odometry calibration (icploc.calibration): distance scale, turn scale, "
        "heading drift and sideways skew from verified scan matches",
    )
    calibration_memory: float = _f(50.0, "the calibration's memory, in distance driven (and radians turned for the turn scale)", "m", gt=0)
    calibration_baseline: float = _f(2.0, "verified matches this far apart are compared", "m", gt=0)
    calibration_max_sigma: float = _f(
        0.05, "... whose position is known to this standard deviation", "m", gt=0
    )
    calibration_max_scale: float = _f(0.05, "bound of the distance scale error (0.05: 5 %)", ge=0)
    calibration_max_turn_scale: float = _f(0.1, "bound of the turn scale error", ge=0)
    calibration_max_drift_deg: float = _f(2.0, "bound of the heading drift", "deg/m", ge=0)
    calibration_max_skew: float = _f(
        0.05, "bound of the sideways skew (0.05: 5 cm sideways per metre forward)", "m/m", ge=0
    )
    calibration_uncertainty: bool = _f(
        True,
        "the prediction's covariance also holds what the calibration has not learned yet "
        "(each factor's spread: half its bound, shrinking with evidence)",
    )
    calibrate_from_consistent: bool = _f(
        True,
        "the calibration also learns from fits the odometry agrees with (chi-square accepted, "
        "at least verify_min_hit_ratio of the beams on walls) that verification turned down",
    )
    scan_independent_beams: float = _f(
        6.0,
        "the scan match's covariance: the information of this many independent beams, "
        "whatever the map's resolution (the beams on one wall share its error)",
        "beams",
        gt=0,
    )
    min_axis_beams: float = _f(
        8.0,
        "a direction the scan match constrains with fewer beams than this (the smallest "
        "eigenvalue of its translational information, unit normals) is left unconstrained: "
        "an aisle's length held by the odd shelf end is no measurement; 0: off",
        "beams",
        ge=0,
    )
    covariance_min_axis_independent: float = _f(
        0.0,
        "... and so is a direction along which it gives fewer than this many independent "
        "measurements (scan_independent_beams times that direction's share of the fit's "
        "beams: a corridor's length); 0: off (at 0.5 infinite-corridor 5 cm bad's max fell "
        "55 m -> 1.0 m, but seattle bad's max rose 21 -> 38 and 20 -> 50 cm: such fits "
        "usually do pin the pose)",
        "measurements",
        ge=0,
    )
    min_axis_independent: float = _f(
        0.5,
        "the promise (tracking): a direction a fit gives fewer than this many independent "
        "measurements along (see covariance_min_axis_independent) counts as left to the "
        "odometry: after a stretch not tracking such fits do not make the pose tracking, and "
        "while dead-reckoned along it the odometry's scale error over the travel counts",
        "measurements",
        ge=0,
    )
    verify_min_hit_ratio: float = _f(
        0.5, "verification: at least this share of beams end on walls", ge=0, le=1
    )
    verify_hit_fraction: float = _f(
        0.8, "... and at least this fraction of the share this map's verified fits show", ge=0, le=1
    )
    verify_unmeasured_hit_ratio: float = _f(
        0.56,
        "... and until that share is measured, at least this share (and only fits showing it "
        "teach the share): a wrong start pose half fitting the scan (55 % of beams on walls) "
        "would otherwise verify and teach its own share as the usual one",
        ge=0,
        le=1,
    )
    quality_window: int = _f(
        51,
        "the map's learned residual and usual hit share are medians over this many recent fits",
        "fits",
        gt=0,
    )
    quality_learn_after: int = _f(
        10,
        "the residual counts as measured (the expected residual becomes the fits' median, "
        "not the map resolution's prior) after this many fits ...",
        "fits",
        gt=0,
    )
    quality_loosen_after: int = _f(
        3,
        "... and already after this many when their median is above twice the prior (walls "
        "from another pass: acapulco 5 cm was lost on its 14th scan with the prior's hit "
        "distance; a median nearer the prior taken this early widened aces 10 cm's fits)",
        "fits",
        gt=0,
    )
    quality_sigma_cap: float = _f(
        0.5,
        "the learned residual may grow up to this fraction of icp.min_correspondence_distance "
        "(at least twice the prior)",
        gt=0,
        le=1,
    )
    quality_rms_min_hit: float = _f(
        0.0,
        "a fit the odometry agrees with that did not verify teaches the residual only when "
        "at least this fraction of verify_min_hit_ratio of its beams end on walls (a looser "
        "residual learned from a wrong place loosens every later verification); 0: every "
        "such fit (at 0.5 freiburg-campus 5 cm, biased odometry, went 5.7 -> 26.6 m max)",
        ge=0,
        le=1,
    )
    verify_max_residual: float = _f(
        2.0,
        "... their RMS residual at most this many expected residuals",
        "expected residuals",
        gt=0,
    )
    verify_see_through: bool = _f(False, "verification also counts beams through mapped walls")
    verify_max_see_through: float = _f(0.15, "... at most this share of beams", ge=0)
    arbitration_margin: float = _f(
        0.1,
        "a scan pose failing the chi-square test is taken when it verifies and its hit share "
        "beats the prediction's by this",
        ge=0,
        le=1,
    )
    step_retry_scales: tuple[float, ...] = _f(
        (0.0, 0.5, 1.5),
        "a fit that does not verify is retried (as from the heading-turned predictions) "
        "from the last pose moved on by this scan's odometry step times each of these "
        "(odometry off by a share of one step: a slip, a stop); the retry that verifies "
        "and explains clearly more of the scan replaces the fit; each >= 0; empty: off",
        "x step",
    )
    step_retry_min_turn_deg: float = _f(
        20.0,
        "... only for a step that turned at least this much (wheels slip in a turn; on a "
        "straight step a seed moved along the travel finds the corridor's next alike "
        "place: aces and csail 10 cm, fits 0.7-0.8 m off explaining more than the right "
        "pose)",
        "deg",
        ge=0,
        le=180,
    )
    step_retry_max_offset: float = _f(
        0.6,
        "... only seeds at most this far from the prediction (a seed a metre off on a 2 m "
        "step found a wrong place explaining more than the right one: intel 5 cm, bad base)",
        "m",
        ge=0,
    )
    step_retry_margin: float = _f(
        0.02,
        "... a step seed's fit replaces the fit when it verifies and its hit share beats "
        "the fit's by this",
        ge=0,
        le=1,
    )
    unverified_worse_margin: float = _f(
        0.05,
        "a fit the chi-square test admits that does not verify and whose hit share is more "
        "than this below the prediction's is not fused (the prediction stands, "
        "inconsistent); 0: off",
        ge=0,
        le=1,
    )
    arbitration_max_inflation: float = _f(
        16.0,
        "... and the disagreement is at most this many times the accept quantile",
        "x quantile",
        gt=0,
    )
    arbitration_hit_ratio: float = _f(
        2.0,
        "... or, short of the usual share, when at least verify_min_hit_ratio of its beams "
        "end on walls at the usual residual and this many times the prediction's share (plus "
        "arbitration_margin): a place the map covers by half, the prediction tens of "
        "centimetres off; 0: off",
        "x prediction's share",
        ge=0,
    )
    arbitration_ratio_max_jump: float = _f(
        0.6,
        "... and that share-ratio arbitration (a fit that does not verify) only for a fit at "
        "most this far from the prediction: on the real cells the right ones moved the pose "
        "0.14-0.54 m (a prediction tens of centimetres off), while wrong ones 0.7-0.9 m off, "
        "at 0.55-0.63 hit share, turned it by 5-9 degrees as well (freiburg-079 on its "
        "partial map, csail 10 cm bad)",
        "m",
        ge=0,
    )
    consistent_rejections: int = _f(
        3, "... or when this many rejected scan poses in a row agree with each other", "scans", gt=0
    )
    dispute_scans: int = _f(
        5,
        "after a fit taken against the odometry (odometry_off) the prediction it overruled is "
        "followed too; the pose is not tracking until that rival failed to verify (or "
        "explained clearly less of the scan than the pose) on this many scans in a row",
        "scans",
        gt=0,
    )
    settle_scans: int = _f(
        3,
        "a pose a fit took against the odometry (odometry_off, or inflated fits moving it "
        "apart) is not tracking until this many verified scans explained the scan at least "
        "as well as the map's usual hit share, with no unverified scan between (unsettled)",
        "scans",
        gt=0,
    )
    settle_correction: float = _f(
        0.15,
        "a fit that moved the pose farther than this from its prediction (a correction "
        "beyond what a tracking pose promises) leaves it unsettled too, whatever the "
        "chi-square test said; 0: off",
        "m",
        ge=0,
    )
    tracking_max_sigma: float = _f(
        0.15, "tracking promises the pose: verified, and its sigma at most this", "m", gt=0
    )
    tracking_max_sigma_theta_deg: float = _f(
        3.0, "... and its heading sigma at most this", "deg", gt=0
    )
    tracking_min_axis_independent: float = _f(
        1.0,
        "... and once a fit left the pose to the odometry along a direction (fewer than this "
        "many independent measurements along it, see min_axis_independent), a fit that "
        "moves the pose along it farther than the map can tell apart is unsettled, and after "
        "a stretch not tracking no fit weaker than this makes it tracking (unconstrained)",
        "measurements",
        ge=0,
    )
    lost_after_bad_scans: int = _f(
        5,
        "lost when this many scans in a row contradict the pose (no usable fit, a rejected "
        "one, or one no better than the prediction with few hits)",
        "scans",
        gt=0,
    )
    lost_hit_fraction: float = _f(
        0.35, "few hits: fewer than this x the usual share of beams end on walls", ge=0, le=1
    )
    crowd_residual: float = _f(
        1.2,
        "... unless the hits fit within this many expected residuals (a crowd hides walls)",
        "expected residuals",
        gt=0,
    )
    lost_sigma_xy: float = _f(2.0, "lost when the position is this uncertain", "m", gt=0)
    lost_coasting: bool = _f(
        True,
        "while lost: the dead reckoning is corrected by scan fits consistent with it (the "
        "chi-square gate, explaining the scan at least as well); the status stays lost",
    )
    coast_min_hit_ratio: float = _f(
        0.3,
        "a coasting fit needs at least this share of beams on walls (and lost_hit_fraction "
        "of the usual); under verify_min_hit_ratio its hits must fit within "
        "verify_max_residual and it must beat the dead reckoning's share by "
        "arbitration_margin, and such a weak fit is no step towards tracking (at 0.25 one "
        "in a wing the map does not hold moved the dead reckoning farther off and a "
        "relocalization 8 m off followed: tests/partial_world.py's sudden exit)",
        ge=0,
        le=1,
    )
    coast_heading_seeds: int = _f(
        2,
        "while coasting, a fit from the dead reckoning that does not pass is retried from it "
        "turned by 1..this many times max(2 heading sigmas, 3 deg) either way (while a "
        "stretch outside the map is open, a turned seed's fit must pass on the usual share, "
        "not as a weak fit); 0: off",
        "seeds a side",
        ge=0,
    )
    coast_sigma_xy: float = _f(
        8.0,
        "lost_coasting goes on while the dead-reckoned position's sigma is at most this (past "
        "lost_sigma_xy: a long stretch the map barely shows, bad odometry drifting metres)",
        "m",
        gt=0,
    )
    coast_jump_sigmas: float = _f(
        3.0,
        "... and a coasting fit may move the pose by up to this many of those sigmas (at least "
        "gating.max_translation_jump; beyond that jump only a fit that verifies and that a strict "
        "check clears, no rival within the dominance margin): a fit from a dead reckoning 2 m "
        "off lies 2 m away",
        "sigmas",
        ge=0,
    )
    lost_noise_gain: float = _f(
        4.0, "while lost the odometry noise variances are this many times the learned ones", gt=0
    )
    recover_inlier_ratio: float = _f(
        0.6, "a recovery candidate needs this inlier ratio (then verification)", ge=0, le=1
    )
    recover_after: int = _f(
        3, "consecutive verified, consistent scans before a recovery locks", "scans", gt=0
    )
    relocalization: Relocalization = _f(
        "global",
        "recovery while lost: global (icploc.relocalize.GlobalRelocalization: near the "
        "dead-reckoned pose, then the whole map) or local (icploc.recovery.LocalRecovery: "
        "near it only); a recovery= given to the Localizer takes precedence",
    )
    lost_check: LostCheck = _f(
        "inline",
        "the global searches: inline in update (deterministic: replays, benchmarks) or "
        "background on a worker thread (icploc run: a live loop must not stall)",
    )
    local_recovery_scans: int = _f(
        3,
        "while lost, scans searching near the dead-reckoned pose before the global search",
        "scans",
        gt=0,
    )
    global_search_every: int = _f(
        10, "while lost: at most one global search per this many scans ...", "scans", gt=0
    )
    global_search_interval: float = _f(1.0, "... and per this much scan time", "s", ge=0)
    max_odometry_gap: float = _f(
        1.0,
        "a scan newer than the newest odometry is extrapolated at the last velocity for at "
        "most min(0.25 s, this), then the pose is held",
        "s",
        gt=0,
    )

    _pose = field_validator("initial_pose", mode="before")(_tuple)
    _step_scales = field_validator("step_retry_scales", mode="before")(_tuple)

    @model_validator(mode="after")
    def _check(self) -> LocalizerSection:
        bad = [f for f in self.step_retry_scales if f < 0]
        if bad:
            raise ValueError(
                "step_retry_scales: every scale must be >= 0 (a share of the odometry "
                f"step's travel; empty: off), got {list(self.step_retry_scales)}"
            )
        if self.noise_gain_min_samples > self.noise_gain_window:
            raise ValueError(
                "noise_gain_min_samples: must not exceed noise_gain_window "
                f"({self.noise_gain_min_samples} > {self.noise_gain_window})"
            )
        return self


class MapSection(Section):
    """How the map is turned into the ICP index."""

    section: ClassVar[str] = "map"

    spacing: float = _f(
        0.05,
        "sampling interval along the fitted wall lines (the paper's 2.2)",
        "m",
        ge=MIN_MAP_SPACING,
    )
    resolution: float = _f(
        0.0,
        "the map's resolution the thresholds scale with; 0: a grid's cell size, else the "
        "median spacing of the map's points",
        "m",
        ge=0,
    )
    visibility_culling: bool = _f(
        False, "match each scan only against map points visible from the predicted pose"
    )
    visibility_fov_deg: float = _f(360.0, "field of view of the culling", "deg", gt=0)
    visibility_max_range: float = _f(30.0, "range of the culling", "m", gt=0)
    patch_lead_in_scans: int = _f(
        200,
        "map patch (--map-patch): at most this many scans between a stretch's last tracking "
        "pose and its first scan outside the map kept for the patch's pose graph",
        "scans",
        ge=0,
    )
    patch_lead_out_scans: int = _f(
        20, "map patch: scans recorded after a stretch's re-entry lock", "scans", ge=0
    )


class RelocalizeSection(Section):
    """The global relocalization (icploc.relocalize): the multi-hypothesis tracker over
    the global search's candidates, the grid it builds, and the kidnap check while
    tracking. Scores are the global search's (a likelihood in [0, 1])."""

    section: ClassVar[str] = "relocalize"

    resolution: float = _f(0.05, "grid resolution of the global search", "m", gt=0)
    max_cells: float = _f(
        4e6,
        "the localizer's deferred build picks the finest resolution (>= 5 cm) with at most "
        "this many cells",
        "cells",
        gt=0,
    )
    max_hypotheses: int = _f(12, "hypotheses kept at most", ge=1)
    keep_ratio: float = _f(
        0.6, "hypotheses scoring below this fraction of the best are dropped", ge=0, lt=1
    )
    min_score: float = _f(0.45, "a confirming scan needs at least this score", ge=0, lt=1)
    min_inlier_ratio: float = _f(0.6, "... and this inlier ratio", ge=0, lt=1)
    dominance: float = _f(
        0.03, "every other distinct hypothesis must score below (1 - this) x the best", ge=0, lt=1
    )
    dominance_slope: float = _f(
        0.5, "the margin grows by this x (clean_score - the leader's score)", ge=0, lt=1
    )
    clean_score: float = _f(
        0.9, "a leader scoring this needs only the dominance margin", ge=0, lt=1
    )
    confirm_scans: int = _f(
        3,
        "consecutive dominating, good scans (the search scan included) before a lock",
        "scans",
        ge=1,
    )
    search_every: int = _f(
        1, "a fresh global search every n-th scan while not locked (1: every scan)", "scans", ge=1
    )
    max_points: int = _f(360, "scan points per hypothesis refinement (0: all)", "points", ge=0)
    see_through_weight: float = _f(
        0.5,
        "weight of the see-through penalty in the tracker's score (glass and map errors let "
        "real beams through mapped lines)",
        ge=0,
        le=1,
    )
    inlier_margin: float = _f(
        0.02, "a rival beating the best's inlier ratio by more than this blocks a lock", ge=0, lt=1
    )
    max_see_through: float = _f(
        0.6, "a confirming scan sees through mapped walls with at most this share of beams", ge=0
    )
    min_clearance: float = _f(
        0.1, "hypotheses nearer than this to the map (inside a wall) are dropped", "m", ge=0
    )
    lost_margin: float = _f(
        0.3,
        "kidnap check: elsewhere when the tracked pose scores below (1 - this) x the best",
        ge=0,
        le=1,
    )
    clean_inlier_ratio: float = _f(
        0.95, "... or, for a best fit this clean (inlier ratio) ...", ge=0, le=1
    )
    clean_margin: float = _f(0.1, "... below the best's score minus this", ge=0, le=1)
    window_sigmas: float = _f(
        3.0,
        "while lost, a global search covers the dead-reckoned pose +- this many sigmas of its "
        "covariance (plus window_margin) ...",
        "sigmas",
        gt=0,
    )
    window_margin: float = _f(1.0, "... plus this much on every side", "m", ge=0)
    window_heading_margin: float = _f(0.35, "... and this much heading either way", "rad", ge=0)
    prior_confirm_scans: int = _f(
        2,
        "while lost, a leader within the dead-reckoned pose's window (window_sigmas) locks "
        "after this many consecutive dominating, good scans (at most confirm_scans)",
        "scans",
        ge=1,
    )
    full_search_every: int = _f(
        4,
        "while lost with a meaningful dead-reckoned pose, every n-th global search covers the "
        "whole map (the others its window; 1: always the whole map)",
        "searches",
        ge=1,
    )


def _global_default(name: str) -> Any:
    """The Rust core's default of one global search setting (``GlobalConfig::default()``)."""
    from icploc._core import global_defaults

    return global_defaults()[name]


class GlobalSearchSection(Section):
    """The global search (icploc.GlobalLocalizer: branch-and-bound over positions and
    headings on a likelihood pyramid, the best seeds refined by ICP) the relocalization and
    the kidnap check run; every default is the Rust core's own (GlobalConfig::default())."""

    section: ClassVar[str] = "global_search"

    angle_step: float = _f(
        _global_default("angle_step"), "heading lattice step", "rad", gt=0, le=math.pi
    )
    max_points: int = _f(
        _global_default("max_points"),
        "scan points of the coarse search (above 257 a large region's search starts from its "
        "top level: the dense start sums in 16 bits)",
        ge=3,
    )
    sigma: float = _f(_global_default("sigma"), "sigma of the coarse likelihood grid", "m", gt=0)
    min_clearance: float = _f(
        _global_default("min_clearance"),
        "candidate positions at least this far from the map",
        "m",
        ge=0,
    )
    accept_ratio: float = _f(
        _global_default("accept_ratio"),
        "keep coarse leaves scoring this fraction of the best",
        gt=0,
        le=1,
    )
    min_score: float = _f(
        _global_default("min_score"),
        "never keep a coarse leaf below this share of a perfect score",
        ge=0,
        lt=1,
    )
    max_candidates: int = _f(
        _global_default("max_candidates"), "seeds refined by ICP at most", ge=1
    )
    levels: int = _f(
        _global_default("levels"), "pyramid depth: the top node covers 2^levels cells", ge=0, le=12
    )
    score_sigma: float = _f(
        _global_default("score_sigma"), "sigma of the fine likelihood", "m", gt=0
    )
    inlier_distance: float = _f(
        _global_default("inlier_distance"), "a scan point this near the map is an inlier", "m", gt=0
    )
    distinct_distance: float = _f(
        _global_default("distinct_distance"),
        "two candidates farther apart than this are distinct",
        "m",
        ge=0,
    )
    distinct_angle: float = _f(
        _global_default("distinct_angle"), "... or turned more than this", "rad", ge=0
    )
    ambiguity_margin: float = _f(
        _global_default("ambiguity_margin"),
        "the best two distinct candidates within this relative score are ambiguous",
        ge=0,
        lt=1,
    )


class RecoverySection(Section):
    """The local recovery (icploc.recovery.LocalRecovery): multi-start ICP around the
    dead-reckoned pose within its uncertainty (3 sigma, min_radius .. max_radius); the
    scans it needs to lock are localizer.recover_after."""

    section: ClassVar[str] = "recovery"

    min_radius: float = _f(0.25, "smallest search radius", "m", gt=0)
    max_radius: float = _f(2.0, "largest search radius (and: beyond it no local search)", "m", gt=0)
    headings: tuple[float, ...] = _f((-0.3, 0.0, 0.3), "heading offsets tried at each start", "rad")
    keep: int = _f(5, "candidates kept as hypotheses", ge=1)

    _headings = field_validator("headings", mode="before")(_tuple)

    @model_validator(mode="after")
    def _check(self) -> RecoverySection:
        if self.min_radius > self.max_radius:
            raise ValueError(
                f"min_radius: must not exceed max_radius ({self.min_radius} > {self.max_radius})"
            )
        if not self.headings:
            raise ValueError("headings: need at least one heading")
        return self


class KidnapSection(Section):
    """When a global kidnap check runs while tracking (icploc.kidnap.KidnapTrigger)."""

    section: ClassVar[str] = "kidnap"

    doubt: float = _f(0.8, "doubtful: a hit share below this x the usual share", ge=0, le=1)
    doubt_scans: int = _f(8, "... for this many scans in a row: check", "scans", ge=1)
    doubt_jump: float = _f(
        0.9,
        "a fit taken far against the odometry is checked when its hit share is below this "
        "fraction of the map's usual share",
        ge=0,
        le=1,
    )
    recheck_scans: int = _f(
        3, "a better pose elsewhere is re-checked this many scans later", "scans", ge=1
    )
    recheck_distance: float = _f(
        0.5, "... and must be found again this near where the odometry carried it", "m", gt=0
    )
    recheck_angle: float = _f(0.175, "... and within this heading", "rad", gt=0)
    history: int = _f(
        25, "the usual share averages about this many recent ordinary scans", "scans", ge=1
    )
    backoff_max: int = _f(
        64, "after a check the trigger keeps quiet at most this long", "scans", ge=1
    )


class OutsideSection(Section):
    """The outside-the-map state (icploc.outside): a scan whose beams mostly end where the
    map knows nothing, seen from a pose still believed, is coasted on the odometry (never
    tracking, reason outside_map, mapped 0) instead of matched against whatever walls are
    near; its other settings: icploc.outside.OutsideConfig."""

    section: ClassVar[str] = "outside"

    enabled: bool = _f(
        True,
        "every Localizer on a map that marks unknown space (a map_server grid with at least "
        "one unknown cell) gets the "
        "outside-the-map monitor (icploc replay --no-partial-map, "
        "replay(partial_map=False) turn it off); without it a run that leaves the map matches "
        "the unmapped part against wrong walls and a global lock there can be reported tracking",
    )


_SECTIONS: tuple[type[Section], ...] = (
    IcpSection,
    ScanSection,
    GatingSection,
    LocalizerSection,
    MapSection,
    RelocalizeSection,
    GlobalSearchSection,
    RecoverySection,
    KidnapSection,
    OutsideSection,
)


class LocalizerConfig(LazyModel):
    """Every setting of the localizer, by section (see the module docstring)."""

    model_settings: ClassVar[dict[str, Any]] = {
        "extra": "forbid",
        "strict": True,
        "validate_assignment": True,
        "arbitrary_types_allowed": True,  # a section is checked by _a_section
    }

    icp: IcpSection = _field(default_factory=IcpSection)
    scan: ScanSection = _field(default_factory=ScanSection)
    gating: GatingSection = _field(default_factory=GatingSection)
    localizer: LocalizerSection = _field(default_factory=LocalizerSection)
    map: MapSection = _field(default_factory=MapSection)
    relocalize: RelocalizeSection = _field(default_factory=RelocalizeSection)
    global_search: GlobalSearchSection = _field(default_factory=GlobalSearchSection)
    recovery: RecoverySection = _field(default_factory=RecoverySection)
    kidnap: KidnapSection = _field(default_factory=KidnapSection)
    outside: OutsideSection = _field(default_factory=OutsideSection)

    @field_validator("*", mode="before")
    @classmethod
    def _a_section(cls, v: Any, info: ValidationInfo) -> Any:
        want = cls.model_fields[str(info.field_name)].annotation
        if isinstance(want, type) and not isinstance(v, want):
            raise ValueError(f"expected a {want.__name__}, got {type(v).__name__}")
        return v

    @classmethod
    def validation_error(cls, e: ValidationError) -> Exception:
        return _config_error(e, None)

    def validate(self) -> LocalizerConfig:  # type: ignore[override]
        """Every section is valid from construction on: returns self (kept for callers)."""
        return self

    # -- dict / YAML -----------------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        return {name: sec.to_dict() for name, sec in self.__dict__.items()}

    def to_yaml(self) -> str:
        """The configuration as YAML, every section and key with its description, unit and
        range as comments (what ``icploc config defaults`` / ``config check`` print)."""
        from yaml import safe_dump  # only when YAML is written (~15 ms to import)

        out = ["# icploc localizer configuration (every key optional; unknown keys are errors)"]
        for name, sec in self.__dict__.items():
            doc = " ".join((type(sec).__doc__ or "").split())
            out.append("")
            out.extend("# " + ln for ln in textwrap.wrap(f"{name}: {doc}", 88))
            out.append(f"{name}:")
            for key, value in sec.to_dict().items():
                out.extend("  # " + ln for ln in textwrap.wrap(_describe(type(sec), key), 86))
                dumped = safe_dump({key: value}, default_flow_style=True, width=1000)
                out.append("  " + dumped.strip().removeprefix("{").removesuffix("}"))
        return "\n".join(out) + "\n"

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_yaml())

    @classmethod
    def from_dict(cls, data: Any, source: str = "<dict>") -> LocalizerConfig:
        """Build a config from nested mappings over the defaults (partial input is fine);
        errors name ``source`` and the field."""
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ConfigError(
                f"{source}: the top level must be a mapping of sections, got {type(data).__name__}",
                path=source,
            )
        sections = {s.section: s for s in _SECTIONS}
        built: dict[str, Section] = {}
        for key, value in data.items():
            if key not in sections:
                raise ConfigError(
                    f"{source}: unknown section {key!r}; valid sections: {', '.join(sections)}",
                    path=source,
                    field=str(key),
                )
            if value is None:
                continue
            if not isinstance(value, dict):
                raise ConfigError(
                    f"{source}: section {key!r} must be a mapping, got {type(value).__name__}",
                    path=source,
                    field=key,
                )
            try:
                built[key] = sections[key](**{str(k): v for k, v in value.items()})
            except ConfigError as e:
                raise ConfigError(f"{source}: {e}", path=source, field=e.field) from None
        return cls(**built)

    @classmethod
    def from_yaml(cls, path: str | Path) -> LocalizerConfig:
        p = Path(path)
        try:
            if p.stat().st_size > MAX_CONFIG_BYTES:
                raise ConfigError(
                    f"{p}: not a config file (more than {MAX_CONFIG_BYTES:,} bytes)", path=str(p)
                )
            raw = p.read_bytes()
        except OSError as e:
            raise ConfigError(
                f"{p}: cannot read config file: {e.strerror or e}", path=str(p)
            ) from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            line = raw[: e.start].count(b"\n") + 1
            raise ConfigError(
                f"{p}:{line}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start}); "
                "save the config file as UTF-8",
                path=str(p),
            ) from None
        import yaml  # only when a file is read (~15 ms to import)

        loader, duplicate = _yaml_loader()
        try:
            data = yaml.load(text, Loader=loader)  # noqa: S506 - a SafeLoader
        except duplicate as e:
            raise ConfigError(f"{p}:{e.line}: {e}", path=str(p), field=str(e.key)) from None
        except yaml.YAMLError as e:
            raise ConfigError(f"{p}: invalid YAML: {e}", path=str(p)) from None
        return cls.from_dict(data, str(p))

    def replace(self, **sections: Any) -> LocalizerConfig:
        """A copy with some sections replaced (or updated from mappings)."""
        new = dict(self.__dict__)
        for name, value in sections.items():
            cur = new.get(name)
            if isinstance(value, dict) and isinstance(cur, Section):
                value = cur.replace(**value)
            new[name] = value
        return LocalizerConfig(**new)


def _describe(cls: type[Section], key: str) -> str:
    """A key's comment in the YAML: description, unit and range from the model."""
    info = cls.model_fields[key]
    extra = info.json_schema_extra
    unit = extra.get("unit", "") if isinstance(extra, dict) else ""
    limits = []
    for m in info.metadata:
        for attr, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            v = getattr(m, attr, None)
            if v is not None:
                limits.append(f"{op} {v:g}")
    args = get_args(info.annotation)
    if args and all(isinstance(a, str) for a in args):
        limits.append(" | ".join(args))
    tail = ", ".join([str(unit), *limits] if unit else limits)
    return f"{info.description or key}" + (f" [{tail}]" if tail else "")


def _num(v: Any) -> str:
    return f"{v:g}" if isinstance(v, (int, float)) else str(v)


def _config_error(e: ValidationError, cls: type[Section] | None) -> ConfigError:
    """The first problem of a pydantic ValidationError as a ConfigError naming the field
    (``section.key: what is wrong, got value``)."""
    err = e.errors(include_url=False)[0]
    loc = [str(x) for x in err["loc"]]
    if cls is not None:
        loc.insert(0, cls.section)
    section_cls = cls
    if cls is None and loc:
        section_cls = next((s for s in _SECTIONS if s.section == loc[0]), None)
    t, v, ctx = err["type"], err.get("input"), err.get("ctx") or {}
    where = ".".join(loc[:2])
    if t == "extra_forbidden":
        valid = ", ".join(section_cls.model_fields) if section_cls else ""
        return ConfigError(
            f"{loc[0]}: unknown key {loc[-1]!r}; valid keys: {valid}", field=".".join(loc)
        )
    if t == "value_error":  # a model validator's "key: problem"
        msg = str(ctx.get("error", err["msg"]))
        key, sep, problem = msg.partition(": ")
        if sep and key.startswith(f"{loc[0]}."):  # the message names its field already
            return ConfigError(msg, field=key)
        if sep and key.isidentifier():
            return ConfigError(f"{loc[0]}.{key}: {problem}", field=f"{loc[0]}.{key}")
        return ConfigError(f"{where}: {msg}", field=where)
    what = {
        "int_type": "expected an integer",
        "float_type": "expected a number",
        "bool_type": "expected true/false",
        "string_type": "expected a string",
        "finite_number": "must be a finite number",
        "tuple_type": "expected a list of numbers",
        "too_short": "expected a list of 3 numbers",
        "too_long": "expected a list of 3 numbers",
        "missing": "expected a list of 3 numbers",
        "greater_than": f"must be > {_num(ctx.get('gt'))}",
        "greater_than_equal": f"must be >= {_num(ctx.get('ge'))}",
        "less_than": f"must be < {_num(ctx.get('lt'))}",
        "less_than_equal": f"must be <= {_num(ctx.get('le'))}",
        "is_instance_of": f"expected a {ctx.get('class')}",
        "model_type": f"expected a {ctx.get('class_name')}",
    }.get(t)
    if t == "literal_error" and section_cls is not None and len(loc) >= 2:
        choices = get_args(section_cls.model_fields[loc[1]].annotation)
        what = f"expected one of {', '.join(map(repr, choices))}"
    if what is None:
        what = err["msg"]
    if t == "model_type" and isinstance(v, dict):
        return ConfigError(f"{where}: {what}, got a dict", field=where)
    if t in ("too_short", "too_long", "missing") and isinstance(v, tuple):
        v = list(v)
    return ConfigError(f"{where}: {what}, got {v!r}", field=where)


@cache
def _yaml_loader() -> tuple[Any, Any]:
    """``(loader, duplicate)``: the safe YAML loader with a duplicated mapping key an error
    (``duplicate``, a YAMLError with ``key`` and ``line``) rather than a silent override;
    built on first use so that importing the config does not import yaml."""
    import yaml

    class _DuplicateKey(yaml.YAMLError):
        def __init__(self, key: Any, first: int, line: int) -> None:
            super().__init__(f"duplicate key {key!r} (first at line {first})")
            self.key = key
            self.line = line

    class _UniqueKeyLoader(yaml.SafeLoader):
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

    return _UniqueKeyLoader, _DuplicateKey


def default_yaml() -> str:
    """The defaults as YAML with comments (what ``icploc config defaults`` prints)."""
    return LocalizerConfig().to_yaml()
