"""The kidnap trigger (icploc.kidnap): when a tracking localizer asks for a global check."""

from __future__ import annotations

from icploc.kidnap import KidnapTrigger


def _settle(t: KidnapTrigger, hit: float = 0.9, n: int = 10) -> None:
    for _ in range(n):
        assert not t.observe(hit, True)


def test_fires_after_doubt_scans_below_the_usual_share() -> None:
    t = KidnapTrigger()
    _settle(t)
    fired = [t.observe(0.6, True) for _ in range(t.doubt_scans)]  # 0.6 < 0.8 x 0.9
    assert fired == [False] * (t.doubt_scans - 1) + [True]


def test_ordinary_scans_never_fire() -> None:
    t = KidnapTrigger()
    assert not any(t.observe(0.9 - 0.01 * (k % 5), True) for k in range(200))


def test_a_fit_far_against_the_odometry_fires_at_once() -> None:
    t = KidnapTrigger()
    _settle(t)
    assert t.observe(0.85, True, jumped=True)


def test_quiet_after_a_check_and_longer_each_time() -> None:
    t = KidnapTrigger()
    _settle(t)
    quiet = []
    for _ in range(2):
        t.backoff()
        n = 0
        while not t.observe(0.5, True):
            n += 1
        quiet.append(n)
    assert quiet[0] >= t.doubt_scans and quiet[1] >= 2 * t.doubt_scans, quiet


def test_a_confirmed_pose_makes_its_share_the_usual_one() -> None:
    t = KidnapTrigger()
    _settle(t, 0.9)
    t.confirmed()
    # 0.6 is now the usual share: never doubtful, long past the quiet period
    assert not any(t.observe(0.6, True) for _ in range(t.backoff_max + 3 * t.doubt_scans))


def test_the_usual_share_follows_the_recent_ordinary_scans() -> None:
    t = KidnapTrigger()
    _settle(t, 0.9, 50)
    for _ in range(100):  # 0.75 >= 0.8 x 0.9: ordinary, and the new usual
        t.observe(0.75, True)
    ref = t.reference()
    assert ref is not None and abs(ref - 0.75) < 0.01, ref


def test_a_low_share_that_fits_tightly_is_a_crowd_not_a_doubt() -> None:
    t = KidnapTrigger()
    _settle(t)
    assert not any(t.observe(0.5, True, tight=True) for _ in range(3 * t.doubt_scans))
