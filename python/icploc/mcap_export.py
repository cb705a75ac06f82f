"""``--mcap FILE.mcap``: a localization run as a Foxglove MCAP file (``icploc replay`` and
``icploc run``), written with the ``foxglove-sdk`` package (its built-in Foxglove schemas,
protobuf-encoded — the per-scan messages by :mod:`icploc.foxglove_pb`, byte for byte
what the SDK's own encoders give, only faster — zstd chunks) — ``pip install 'icploc[mcap]'``, imported only here.

Topics (frames ``map`` -> ``odom`` -> ``base_link`` -> ``laser``):

============================  ========================  ==========================================
topic                         schema                    what
============================  ========================  ==========================================
``/map``                      ``foxglove.Grid``         the occupancy grid (grid maps only), once
``/map/points``               ``foxglove.PointCloud``   the map points the ICP matches against
                                                        (any map: the sampled lines), once
``/scan``                     ``foxglove.LaserScan``    every scan, in the ``laser`` frame
``/localization/pose``        ``foxglove.PoseInFrame``  the estimate (base in ``map``), every scan
``/localization/covariance``  JSON (``icploc.PoseCovariance``)  its 3x3 (x, y, theta) covariance,
                                                        status, reason and inlier ratio
``/odom``                     ``foxglove.PoseInFrame``  the odometry pose (base in ``odom``)
``/localization/hypotheses``  ``foxglove.PosesInFrame`` the pose hypotheses, on every lost scan
``/tf``                       ``foxglove.FrameTransforms``  map->odom, odom->base_link,
                                                        base_link->laser at every scan
============================  ========================  ==========================================

Message log times are the scan stamps (nanoseconds), made strictly increasing (a log whose
stamps are all zero still plays back in order); the map messages carry the first scan's.
:func:`attach` records every :meth:`Localizer.update` of a localizer into an
:class:`McapRecorder`; a failed write is reported (at the latest by :meth:`McapRecorder.close`)
and the localization goes on.

Speed: the SDK's message objects cost ~10-25 us each to build in Python, five messages a
scan; the per-scan messages are therefore encoded by :mod:`icploc.foxglove_pb` (the same
bytes, tested) and logged through the channels' raw loggers, ~40 us a scan in all
(``benches/mcap_bench.py``).
"""

from __future__ import annotations

import json
import logging
import math
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from icploc import foxglove_pb as pb
from icploc.errors import IcplocError
from icploc.localizer import Estimate, Localizer, Status
from icploc.messages import Scan
from icploc.se2 import Pose, compose, inverse

__all__ = ["McapError", "McapFileWriter", "McapRecorder", "TOPICS", "attach", "hypotheses_of"]

TOPICS = {
    "map": "/map",
    "map_points": "/map/points",
    "scan": "/scan",
    "pose": "/localization/pose",
    "covariance": "/localization/covariance",
    "odometry": "/odom",
    "hypotheses": "/localization/hypotheses",
    "tf": "/tf",
}

_COVARIANCE_SCHEMA = {
    "title": "icploc.PoseCovariance",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame_id": {"type": "string"},
        "covariance": {
            "type": "array",
            "items": {"type": "number"},
            "description": "3x3 covariance of (x, y, theta), row-major (m^2, m rad, rad^2)",
        },
        "status": {"type": "string"},
        "reason": {"type": "string"},
        "inlier_ratio": {"type": "number"},
    },
}


class McapError(IcplocError, RuntimeError):
    """The MCAP file cannot be written (package missing, bad path)."""


def _check_foxglove() -> None:
    """A clear error now if foxglove-sdk is missing (it is imported when the file opens)."""
    import importlib.util

    if importlib.util.find_spec("foxglove") is None:
        raise McapError(
            "--mcap needs the foxglove-sdk package, which is not installed: "
            "pip install 'icploc[mcap]'"
        )


def _import_foxglove() -> Any:
    try:
        import foxglove
        from foxglove import messages
    except ImportError:
        raise McapError(
            "--mcap needs the foxglove-sdk package, which is not installed: "
            "pip install 'icploc[mcap]'"
        ) from None
    return foxglove, messages


_COV_FMT = (
    b'{"timestamp":{"sec":%d,"nsec":%d},"frame_id":"map","covariance":'
    b'[%r,%r,%r,%r,%r,%r,%r,%r,%r],"status":"%s","reason":%s,"inlier_ratio":%r}'
)


#: one scan as the writer needs it: stamp, ranges, first and last beam angle, pose,
#: covariance (9 floats, row-major), status, reason, inlier ratio, odometry pose or None,
#: hypotheses (poses) or None
Row = tuple[Any, ...]


def map_data(map_: Any, spacing: float = 0.05) -> dict[str, Any]:
    """What the writer draws of a map: the occupancy grid (uint8 cells, 255 unknown; grid
    maps only) and the points the ICP matches against (float32 (N, 2))."""
    if isinstance(map_, (str, Path)):
        from icploc.maps import Map

        map_ = Map.load(map_)
    out: dict[str, Any] = {"grid": None}
    grid = getattr(map_, "grid", None)
    if grid is not None and getattr(map_, "resolution", None):
        occ = getattr(map_, "occupancy", None)
        if occ is not None and occ.shape == grid.shape:
            cells = np.where(occ < 0, 255, occ).astype(np.uint8)
        else:
            cells = np.where(grid, 100, 0).astype(np.uint8)
        out["grid"] = np.ascontiguousarray(cells)
        out["resolution"] = float(map_.resolution)
        out["origin"] = tuple(float(v) for v in map_.origin)
    if hasattr(map_, "sample") and callable(map_.sample):
        pts = map_.sample(spacing)[0]
    elif hasattr(map_, "points"):
        pts = map_.points
    else:
        pts = map_
    out["points"] = np.ascontiguousarray(np.asarray(pts, dtype=np.float32).reshape(-1, 2))
    return out


class _FirstError(logging.Handler):
    """Keeps the SDK's first warning (a failed write) in ``writer.write_error``."""

    def __init__(self, writer: McapFileWriter) -> None:
        super().__init__(logging.WARNING)
        self.writer = writer

    def emit(self, record: logging.LogRecord) -> None:
        if not self.writer.write_error:
            self.writer.write_error = record.getMessage()


class McapFileWriter:
    """Writes the topics of the module doc to ``path`` with foxglove-sdk, in this process:
    :meth:`set_map` (written with the first row's log time), :meth:`write_rows`,
    :meth:`close` (returns the message count per topic)."""

    def __init__(self, path: str | Path, laser_mounting: Sequence[float] = (0.0, 0.0, 0.0)):
        fg, msg = _import_foxglove()
        from foxglove import channels as ch

        self._m = msg
        self.path = Path(path)
        self._ctx = c = fg.Context()
        try:
            self._writer = fg.open_mcap(self.path, allow_overwrite=True, context=c)
        except Exception as e:  # the SDK raises its own error types
            raise McapError(f"{self.path}: cannot write the MCAP file ({e})") from None
        self._grid = ch.GridChannel(TOPICS["map"], context=c)
        self._points = ch.PointCloudChannel(TOPICS["map_points"], context=c)

        def pb_channel(topic: str, message: Any) -> Any:
            # the SDK's own schema; the messages encoded by icploc.foxglove_pb (same bytes)
            return fg.Channel(
                topic, schema=message.get_schema(), message_encoding="protobuf", context=c
            )

        self._scan = pb_channel(TOPICS["scan"], msg.LaserScan)
        self._pose = pb_channel(TOPICS["pose"], msg.PoseInFrame)
        self._odom = pb_channel(TOPICS["odometry"], msg.PoseInFrame)
        self._hyp = pb_channel(TOPICS["hypotheses"], msg.PosesInFrame)
        self._tf = pb_channel(TOPICS["tf"], msg.FrameTransforms)
        self._cov = fg.Channel(
            TOPICS["covariance"],
            message_encoding="json",
            schema=fg.Schema(
                name="icploc.PoseCovariance",
                encoding="jsonschema",
                data=json.dumps(_COVARIANCE_SCHEMA).encode(),
            ),
            context=c,
        )
        lm = tuple(float(v) for v in laser_mounting)
        self.laser_mounting: Pose = (lm[0], lm[1], lm[2])
        self._last_ns = -1
        self._map: dict[str, Any] | None = None
        # the SDK reports a failed write (a full disk) as a warning per message logged, not
        # as an exception: keep the first one, silence the rest, stop at the next batch
        self.write_error = ""
        self._sdk_log = logging.getLogger("foxglove")
        self._handler = _FirstError(self)
        self._sdk_log.addHandler(self._handler)
        self._propagate = self._sdk_log.propagate
        self._sdk_log.propagate = False
        self.counts: dict[str, int] = dict.fromkeys(TOPICS.values(), 0)
        self.closed = False

    def _log_time(self, stamp: float) -> int:
        ns = int(round(stamp * 1e9)) if math.isfinite(stamp) and stamp > 0 else 0
        if ns <= self._last_ns:
            ns = self._last_ns + 1
        self._last_ns = ns
        return ns

    # -- the map ---------------------------------------------------------------------------
    def set_map(self, data: dict[str, Any]) -> None:
        """:func:`map_data` of the map, written with the first row's log time."""
        self._map = data

    def _flush_map(self, ns: int) -> None:
        data, self._map = self._map, None
        if data is None:
            return
        m = self._m
        ts = m.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)
        origin = m.Pose(
            position=m.Vector3(x=0.0, y=0.0, z=0.0),
            orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        )
        cells = data.get("grid")
        if cells is not None:
            h, w = cells.shape
            res = data["resolution"]
            ox, oy, oth = data["origin"]
            self._grid.log(
                m.Grid(
                    timestamp=ts,
                    frame_id="map",
                    pose=m.Pose(
                        position=m.Vector3(x=ox, y=oy, z=0.0),
                        orientation=m.Quaternion(
                            x=0.0, y=0.0, z=math.sin(0.5 * oth), w=math.cos(0.5 * oth)
                        ),
                    ),
                    column_count=int(w),
                    cell_size=m.Vector2(x=res, y=res),
                    row_stride=int(w),
                    cell_stride=1,
                    fields=[
                        m.PackedElementField(
                            name="occupancy", offset=0, type=m.PackedElementFieldNumericType.Uint8
                        )
                    ],
                    data=cells.tobytes(),
                ),
                log_time=ns,
            )
            self.counts[TOPICS["map"]] += 1
        f32 = m.PackedElementFieldNumericType.Float32
        self._points.log(
            m.PointCloud(
                timestamp=ts,
                frame_id="map",
                pose=origin,
                point_stride=8,
                fields=[
                    m.PackedElementField(name="x", offset=0, type=f32),
                    m.PackedElementField(name="y", offset=4, type=f32),
                ],
                data=data["points"].tobytes(),
            ),
            log_time=ns,
        )
        self.counts[TOPICS["map_points"]] += 1

    # -- per scan --------------------------------------------------------------------------
    @staticmethod
    def _covariance_json(
        ns: int, cov: Sequence[float], status: str, reason: str, ir: float
    ) -> bytes:
        if all(math.isfinite(v) for v in cov) and math.isfinite(ir):
            return _COV_FMT % (
                ns // 1_000_000_000,
                ns % 1_000_000_000,
                *cov,
                status.encode(),
                json.dumps(reason).encode(),
                ir,
            )
        doc = {
            "timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000},
            "frame_id": "map",
            "covariance": [v if math.isfinite(v) else None for v in cov],
            "status": status,
            "reason": reason,
            "inlier_ratio": ir if math.isfinite(ir) else None,
        }
        return json.dumps(doc).encode()

    def write_rows(self, rows: Sequence[Row]) -> None:
        if self.write_error:
            raise McapError(f"{self.path}: {self.write_error}")
        cnt = self.counts
        # the channels' raw loggers (bytes, log time): the SDK's Channel.log minus its checks
        log_scan, log_pose = self._scan.base.log, self._pose.base.log
        log_cov, log_odom = self._cov.base.log, self._odom.base.log
        log_tf, log_hyp = self._tf.base.log, self._hyp.base.log
        laser = ("base_link", "laser", self.laser_mounting)
        for stamp, ranges, a0, a1, pose, cov, status, reason, ir, odo, hyps in rows:
            ns = self._log_time(stamp)
            if self._map is not None:
                self._flush_map(ns)
            log_scan(pb.laser_scan(ns, "laser", a0, a1, ranges), ns)
            log_pose(pb.pose_in_frame(ns, "map", pose), ns)
            log_cov(self._covariance_json(ns, cov, status, reason, ir), ns)
            if odo is not None:
                log_odom(pb.pose_in_frame(ns, "odom", odo), ns)
                cnt[TOPICS["odometry"]] += 1
                map_odom, base = compose(pose, inverse(odo)), odo
            else:
                map_odom, base = (0.0, 0.0, 0.0), pose
            log_tf(
                pb.frame_transforms(
                    ns, (("map", "odom", map_odom), ("odom", "base_link", base), laser)
                ),
                ns,
            )
            if hyps is not None:
                log_hyp(pb.poses_in_frame(ns, "map", hyps), ns)
                cnt[TOPICS["hypotheses"]] += 1
        n = len(rows)
        for t in ("scan", "pose", "covariance", "tf"):
            cnt[TOPICS[t]] += n

    def close(self) -> dict[str, int]:
        """Finish the file; :class:`McapError` (the first failure) if it was not written."""
        if not self.closed:
            self.closed = True
            try:
                if self._map is not None and not self.write_error:
                    self._flush_map(max(self._last_ns, 0))
                self._writer.close()
            except Exception as e:  # the SDK raises its own error types
                self.write_error = self.write_error or str(e)
            finally:
                self._sdk_log.removeHandler(self._handler)
                self._sdk_log.propagate = self._propagate
            if self.write_error:
                raise McapError(f"{self.path}: {self.write_error}")
        return dict(self.counts)


class McapRecorder:
    """Records a localization run into ``path`` (see the module doc): :meth:`write_map`
    once, :meth:`record` per scan, :meth:`close` at the end (or use it as a context
    manager). A failed write raises :class:`McapError` (from :meth:`record` at the next
    batch, or from :meth:`close`). ``laser_mounting``: the laser pose in the base frame
    (``config.scan.mounting``; :func:`attach` sets it). Scans are written ``chunk`` at a
    time."""

    def __init__(
        self,
        path: str | Path,
        laser_mounting: Sequence[float] = (0.0, 0.0, 0.0),
        *,
        chunk: int = 256,
    ) -> None:
        _check_foxglove()
        self.path = Path(path)
        if self.path.is_dir():
            raise McapError(f"{self.path}: is a directory, not an MCAP file name")
        try:  # a bad path fails now, not after the run
            with open(self.path, "ab"):
                pass
        except OSError as e:
            raise McapError(f"{self.path}: cannot write the MCAP file ({e.strerror})") from None
        lm = tuple(float(v) for v in laser_mounting)
        self.laser_mounting: Pose = (lm[0], lm[1], lm[2])
        self.chunk = max(1, int(chunk))
        self.counts: dict[str, int] = {}
        self.closed = False
        self._rows: list[Row] = []
        self._map: dict[str, Any] | None = None
        self._writer: McapFileWriter | None = None

    def _open(self) -> McapFileWriter:
        """The file is opened at the first message: the laser mounting is known by then."""
        if self._writer is None:
            self._writer = McapFileWriter(self.path, self.laser_mounting)
        return self._writer

    def write_map(self, map_: Any, spacing: float = 0.05) -> None:
        """The map (an icploc Map, a path, a MapIndex or (N, 2) points), drawn once."""
        self._map = map_data(map_, spacing)

    def record(self, scan: Scan, e: Estimate, hypotheses: Sequence[Pose] | None = None) -> None:
        """One scan and its estimate (``hypotheses``: the pose hypotheses while lost)."""
        a = scan.angles
        n = len(a)
        self._rows.append(
            (
                e.stamp,
                scan.ranges.astype("<f8", copy=False).tobytes(),
                float(a[0]) if n else 0.0,
                float(a[-1]) if n else 0.0,
                e.pose,
                e.covariance.ravel().tolist(),
                e.status.value,
                e.reason,
                float(e.inlier_ratio),
                e.odometry,
                (list(hypotheses or ()) if e.status is Status.LOST else None),
            )
        )
        if len(self._rows) >= self.chunk:
            self.flush()

    def flush(self) -> None:
        w = self._open()
        if self._map is not None:
            data, self._map = self._map, None
            w.set_map(data)
        if self._rows:
            rows, self._rows = self._rows, []
            w.write_rows(rows)

    def close(self) -> None:
        """Write what is left and finish the file; :class:`McapError` if it failed."""
        if self.closed:
            return
        self.closed = True
        try:
            self.flush()
        finally:
            if self._writer is not None:
                self.counts = self._writer.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def hypotheses_of(estimate: Estimate) -> list[Pose]:
    """The pose hypotheses a lost estimate carries (``Estimate.hypotheses``, ranked by the
    recovery strategy); with none, the dead-reckoned pose."""
    hyps = getattr(estimate, "hypotheses", ()) or ()
    if hyps:
        return [tuple(h.pose) for h in hyps]  # type: ignore[misc]
    return [estimate.pose]


def attach(localizer: Localizer, recorder: McapRecorder) -> Callable[[], None]:
    """Record every ``localizer.update`` (the scan, its estimate, the hypotheses while
    lost) into ``recorder``, and queue the localizer's map. Returns a function that
    detaches. A recorder error is warned about once; the localizer carries on."""
    orig = localizer.update
    sm = localizer.config.scan.mounting
    recorder.laser_mounting = (float(sm[0]), float(sm[1]), float(sm[2]))
    recorder.write_map(localizer.map, localizer.config.map.spacing)
    failed = [False]

    def update(scan: Scan, odometry: Any = None) -> Estimate:
        est = orig(scan, odometry)
        if not failed[0]:
            try:
                hyp = hypotheses_of(est) if est.status is Status.LOST else None
                recorder.record(scan, est, hyp)
            except Exception as e:  # a dead writer must not stop the localization
                failed[0] = True
                warnings.warn(
                    f"{recorder.path}: MCAP recording stopped ({type(e).__name__}: {e})",
                    RuntimeWarning,
                    stacklevel=2,
                )
        return est

    setattr(localizer, "update", update)  # noqa: B010  (an instance attribute over the method)

    def detach() -> None:
        if localizer.__dict__.get("update") is update:
            del localizer.__dict__["update"]

    return detach
