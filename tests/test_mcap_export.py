"""--mcap: a Foxglove MCAP of a replay, read back with the ``mcap`` package."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from icploc import sim as worlds
from icploc.live import tum_row
from icploc.logs import write_carmen
from icploc.maps import Map
from icploc.replay import replay

pytest.importorskip("foxglove")
pytest.importorskip("mcap")

from foxglove import messages as fm  # noqa: E402
from icploc import foxglove_pb as pb  # noqa: E402
from icploc.mcap_export import TOPICS, McapError, McapRecorder, attach  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

N_SCANS = 150


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> dict:
    d = tmp_path_factory.mktemp("mcap")
    w = worlds.lab(people=1)
    frames = list(
        worlds.simulate(w, worlds.lab_random_walk(8.0, seed=5), seed=6, max_frames=N_SCANS)
    )
    log = d / "run.log"
    write_carmen(
        log,
        [f.scan for f in frames],
        [f.odometry for f in frames],
        poses=np.array([f.truth for f in frames]),
        scan_odometry=np.array([f.odometry.pose for f in frames]),
    )
    truth = d / "truth.tum"
    truth.write_text("".join(tum_row(f.scan.stamp, f.truth) for f in frames))
    return {
        "dir": d,
        "log": log,
        "truth": truth,
        "map": Map.from_lines(w.lines).to_ros(d / "lab.yaml", 0.05),
    }


def _read(path: Path) -> tuple[dict[str, int], dict[str, str], dict[str, list[bytes]]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        stats = summary.statistics.channel_message_counts
        counts = {summary.channels[cid].topic: n for cid, n in stats.items()}
        schemas = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        data: dict[str, list[bytes]] = {}
        for _schema, channel, message in reader.iter_messages():
            data.setdefault(channel.topic, []).append(message.data)
    return counts, schemas, data


@pytest.fixture(scope="module")
def tracked(sim: dict) -> dict:
    """``icploc replay --mcap`` from the true start pose: tracking throughout."""
    from icploc.cli import app
    from typer.testing import CliRunner

    out = sim["dir"] / "tracked.mcap"
    r = CliRunner().invoke(
        app,
        ["replay", str(sim["log"]), "--map", str(sim["map"]), "--truth", str(sim["truth"]),
         "--mcap", str(out), "--no-progress"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    counts, schemas, data = _read(out)
    return {"counts": counts, "schemas": schemas, "data": data, "output": r.output}


def test_replay_mcap_has_one_message_per_scan_on_each_stream(tracked: dict) -> None:
    c = tracked["counts"]
    per_scan = ("scan", "pose", "covariance", "odometry", "tf")
    assert [c[TOPICS[t]] for t in per_scan] == [N_SCANS] * len(per_scan)


def test_replay_mcap_has_the_map_once(tracked: dict) -> None:
    assert (tracked["counts"][TOPICS["map"]], tracked["counts"][TOPICS["map_points"]]) == (1, 1)


def test_replay_mcap_uses_the_foxglove_schemas(tracked: dict) -> None:
    s = tracked["schemas"]
    assert [s[TOPICS[t]] for t in ("map", "map_points", "scan", "pose", "odometry", "tf")] == [
        "foxglove.Grid",
        "foxglove.PointCloud",
        "foxglove.LaserScan",
        "foxglove.PoseInFrame",
        "foxglove.PoseInFrame",
        "foxglove.FrameTransforms",
    ]


def test_no_hypotheses_while_tracking(tracked: dict) -> None:
    assert tracked["counts"].get(TOPICS["hypotheses"], 0) == 0


def test_covariance_companion_is_json_with_the_estimate(tracked: dict, sim: dict) -> None:
    ref = replay(sim["log"], sim["map"], truth=sim["truth"])
    docs = [json.loads(b) for b in tracked["data"][TOPICS["covariance"]]]
    got = np.array([d["covariance"] for d in docs]).reshape(-1, 3, 3)
    want = np.array([e.covariance for e in ref.estimates])
    assert np.allclose(got, want, rtol=1e-12, atol=0)


def test_pose_messages_decode_to_the_estimates(tracked: dict, sim: dict) -> None:
    ref = replay(sim["log"], sim["map"], truth=sim["truth"])
    first = tracked["data"][TOPICS["pose"]][0]
    e = ref.estimates[0]
    ns = int(round(e.stamp * 1e9))
    assert first == pb.pose_in_frame(ns, "map", e.pose)


def test_replay_reports_the_mcap_file(tracked: dict) -> None:
    assert "mcap:" in tracked["output"]


def test_hypotheses_logged_on_every_lost_scan(sim: dict, tmp_path: Path) -> None:
    out = tmp_path / "global.mcap"
    rec = McapRecorder(out)
    res = replay(sim["log"], sim["map"], global_localize=True,
                 on_localizer=lambda loc: attach(loc, rec))  # fmt: skip
    rec.close()
    lost = res.status_counts.get("lost", 0)
    counts, _, data = _read(out)
    assert lost > 0
    assert counts[TOPICS["hypotheses"]] == lost
    assert all(len(m) > 0 for m in data[TOPICS["hypotheses"]])


def test_log_times_increase_when_stamps_do_not(tmp_path: Path) -> None:
    from icploc.localizer import Estimate, Status
    from icploc.messages import Scan

    out = tmp_path / "zero.mcap"
    rec = McapRecorder(out)
    scan = Scan(0.0, np.ones(5), np.linspace(-1, 1, 5))
    for _ in range(3):
        e = Estimate(0.0, (1.0, 2.0, 0.5), np.eye(3), Status.TRACKING, 1.0, 3, 0.0)
        rec.record(scan, e)
    rec.close()
    with open(out, "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(topics=[TOPICS["scan"]])]
    assert times == [0, 1, 2]


def test_unwritable_path_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(McapError, match="cannot write"):
        McapRecorder(tmp_path / "no" / "such" / "dir" / "x.mcap")


def test_cli_refuses_to_overwrite_the_input_log(sim: dict) -> None:
    from icploc.cli import app
    from typer.testing import CliRunner

    before = sim["log"].read_bytes()
    r = CliRunner().invoke(
        app, ["replay", str(sim["log"]), "--map", str(sim["map"]), "--mcap", str(sim["log"])]
    )
    assert (r.exit_code, sim["log"].read_bytes() == before) == (1, True)


# -- the fast encoders give the SDK's own bytes ---------------------------------------------
finite = st.floats(-1e4, 1e4, allow_nan=False) | st.just(0.0)
poses = st.tuples(finite, finite, st.floats(-math.pi, math.pi) | st.just(0.0))
stamps = st.integers(0, (2**32 - 1) * 10**9)  # the SDK's Timestamp: u32 seconds


def _pose(p: tuple[float, float, float]) -> fm.Pose:
    h = 0.5 * p[2]
    return fm.Pose(
        position=fm.Vector3(x=p[0], y=p[1], z=0.0),
        orientation=fm.Quaternion(x=0.0, y=0.0, z=math.sin(h), w=math.cos(h)),
    )


def _ts(ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=ns // 10**9, nsec=ns % 10**9)


@settings(max_examples=200, deadline=None)
@given(ns=stamps, p=poses, frame=st.sampled_from(["map", "odom"]))
def test_pose_in_frame_bytes_match_the_sdk(ns: int, p: tuple, frame: str) -> None:
    sdk = fm.PoseInFrame(timestamp=_ts(ns), frame_id=frame, pose=_pose(p)).encode()
    assert pb.pose_in_frame(ns, frame, p) == sdk


@settings(max_examples=100, deadline=None)
@given(ns=stamps, ps=st.lists(poses, max_size=5))
def test_poses_in_frame_bytes_match_the_sdk(ns: int, ps: list) -> None:
    sdk = fm.PosesInFrame(timestamp=_ts(ns), frame_id="map", poses=[_pose(p) for p in ps]).encode()
    assert pb.poses_in_frame(ns, "map", ps) == sdk


@settings(max_examples=100, deadline=None)
@given(ns=stamps, a=poses, b=poses)
def test_frame_transforms_bytes_match_the_sdk(ns: int, a: tuple, b: tuple) -> None:
    tfs = [("map", "odom", a), ("odom", "base_link", b), ("base_link", "laser", (0.1, 0.0, 0.0))]
    sdk = fm.FrameTransforms(
        transforms=[
            fm.FrameTransform(
                timestamp=_ts(ns),
                parent_frame_id=p,
                child_frame_id=c,
                translation=fm.Vector3(x=q[0], y=q[1], z=0.0),
                rotation=fm.Quaternion(
                    x=0.0, y=0.0, z=math.sin(0.5 * q[2]), w=math.cos(0.5 * q[2])
                ),
            )
            for p, c, q in tfs
        ]
    ).encode()
    assert pb.frame_transforms(ns, tfs) == sdk


@settings(max_examples=100, deadline=None)
@given(
    ns=stamps,
    ranges=st.lists(st.floats(0.0, 80.0) | st.just(math.inf), max_size=400),
    a0=st.floats(-math.pi, 0.0),
)
def test_laser_scan_bytes_match_the_sdk(ns: int, ranges: list, a0: float) -> None:
    sdk = fm.LaserScan(timestamp=_ts(ns), frame_id="laser", pose=_pose((0.0, 0.0, 0.0)),
                       start_angle=a0, end_angle=-a0, ranges=ranges).encode()  # fmt: skip
    assert pb.laser_scan(ns, "laser", a0, -a0, np.array(ranges, dtype=np.float64)) == sdk


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_full_disk_is_a_clear_error_without_a_flood_of_warnings(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from icploc.localizer import Estimate, Status
    from icploc.messages import Scan

    rec = McapRecorder("/dev/full")
    scan = Scan(1.0, np.ones(361), np.linspace(-1.5, 1.5, 361))
    e = Estimate(1.0, (1.0, 2.0, 0.3), np.eye(3), Status.TRACKING, 1.0, 3, 0.0)
    with pytest.raises(McapError, match=r"/dev/full: .*(No space left|StorageFull)"):
        for _ in range(600):
            rec.record(scan, e)
        rec.close()
    assert capsys.readouterr().err == ""
