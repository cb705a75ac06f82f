"""The map patch's poses against the mapped walls (icploc.mappatch.MappedWalls): a
stretch's scan that partly sees the map is matched against it, in the directions the
mapped walls constrain, using only its beams that end on mapped space."""

from __future__ import annotations

import math

import numpy as np
from icploc.mappatch import MappedWalls
from icploc.outside import MappedArea, OutsideConfig


def _line(a: tuple[float, float], b: tuple[float, float], n: int = 200) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    return np.column_stack([a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])])


def _walls(pts: np.ndarray) -> MappedWalls:
    from icploc._core import MapIndex

    index = MapIndex(pts)
    return MappedWalls(index, MappedArea.of(pts, index, OutsideConfig(reach=1.0)))


def _robot_frame(pose: tuple[float, float, float], world: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = world - np.array(pose[:2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def test_a_scan_seeing_a_mapped_corner_gets_a_prior_at_its_true_pose() -> None:
    mapped = np.concatenate([_line((0, 0), (8, 0)), _line((0, 0), (0, 6))])
    truth = (3.0, 2.0, 0.2)
    # the scan also sees a wall the map lacks (x = 9 .. 12, farther than 1 m from the map):
    # it must not be matched to the map
    unmapped = _line((12, -2), (12, 8))
    scan = _robot_frame(truth, np.concatenate([mapped, unmapped]))
    guess = np.array([[0.0, 0.0, 0.0], [3.08, 1.95, 0.21]])
    (k, z, _), *rest = _walls(mapped).priors(guess, [scan])
    assert [k, len(rest), math.dist(z[:2], truth[:2]) < 0.01] == [1, 0, True]


def test_a_prior_from_one_mapped_wall_says_nothing_along_it() -> None:
    mapped = _line((0, 0), (8, 0))
    truth = (3.0, 2.0, 0.0)
    scan = _robot_frame(truth, mapped)
    guess = np.array([[0.0, 0.0, 0.0], [3.1, 2.05, 0.0]])
    (_, _, info), = _walls(mapped).priors(guess, [scan])
    cov = np.linalg.inv(info[:2, :2])
    assert [math.sqrt(cov[0, 0]) > 1.0, math.sqrt(cov[1, 1]) < 0.05] == [True, True]


def test_a_scan_that_lands_off_the_map_gets_no_prior() -> None:
    mapped = _line((0, 0), (8, 0))
    scan = _robot_frame((30.0, 30.0, 0.0), _line((28, 28), (32, 28)))
    guess = np.array([[0.0, 0.0, 0.0], [30.0, 30.0, 0.0]])
    assert _walls(mapped).priors(guess, [scan]) == []
