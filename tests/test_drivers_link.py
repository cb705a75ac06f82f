"""The drivers' shared reconnect loop (icploc.drivers._link)."""

from __future__ import annotations

import threading

from icploc.drivers._link import close_quietly, retry_with_backoff


class _Flaky:
    """Fails ``failures`` times with OSError, then succeeds; counts closes."""

    def __init__(self, failures: int) -> None:
        self.left = failures
        self.attempts = 0
        self.closes = 0

    def attempt(self) -> None:
        self.attempts += 1
        if self.left > 0:
            self.left -= 1
            raise OSError(f"no device (attempt {self.attempts})")

    def close(self) -> None:
        self.closes += 1


def _retry(f: _Flaky, stop: threading.Event, timeout: float) -> tuple[bool, BaseException | None]:
    return retry_with_backoff(f.attempt, close=f.close, failures=(OSError,), stop=stop,
                              timeout=timeout, backoff=0.001, backoff_max=0.002)  # fmt: skip


def test_a_line_that_comes_back_is_linked_after_its_failures() -> None:
    f = _Flaky(failures=2)
    assert (_retry(f, threading.Event(), timeout=30.0), f.attempts, f.closes) == ((True, None), 3, 3)


def test_a_line_that_never_comes_back_returns_the_last_failure_after_the_timeout() -> None:
    f = _Flaky(failures=10**9)
    linked, last = _retry(f, threading.Event(), timeout=0.05)
    assert (linked, str(last)) == (False, f"no device (attempt {f.attempts})")


def test_a_stopped_loop_attempts_nothing() -> None:
    stop = threading.Event()
    stop.set()
    f = _Flaky(failures=0)
    assert (_retry(f, stop, timeout=30.0), f.attempts) == ((False, None), 0)


def test_closing_a_port_that_fails_to_close_is_quiet() -> None:
    class Broken:
        calls = 0

        def close(self) -> None:
            self.calls += 1
            raise OSError("gone")

    port = Broken()
    close_quietly(port)
    assert port.calls == 1
