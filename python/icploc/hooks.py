"""The optional per-run extras of ``icploc replay`` / ``icploc run`` in one object:
``--mcap FILE`` (:mod:`icploc.mcap_export`), ``--state FILE`` (:mod:`icploc.state`) and
``--refine-start`` (:mod:`icploc.startrefine`).

The commands pass :meth:`RunHooks.on_localizer` to the function that builds the
Localizer, :meth:`RunHooks.observe` every estimate, and call :meth:`RunHooks.close` at
the end (also after an error or Ctrl-C)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from icploc.localizer import Estimate, Localizer

__all__ = ["RunHooks"]


class RunHooks:
    """``mcap``: record the run there. ``state``: restore the pose saved there (checked on
    the first scan) unless ``restore`` is False (an explicit initial pose), and save the
    last tracking pose there every ``state_every`` s of scan time and at the end.
    ``refine_start``: refine the start pose from the first stationary scans
    (:mod:`icploc.startrefine`; not with a restored state, which is checked on its own);
    the verdict goes to ``tell`` (refined) or ``warn`` (anything else) and stays in
    :attr:`start_verdict`. ``warn(message)`` reports what the run should tell the user
    (default: ignore)."""

    def __init__(
        self,
        *,
        mcap: str | Path | None = None,
        state: str | Path | None = None,
        restore: bool = True,
        state_every: float = 1.0,
        warn: Callable[[str], None] | None = None,
        inputs: tuple[str | Path, ...] = (),
        refine_start: bool = False,
        tell: Callable[[str], None] | None = None,
    ) -> None:
        self.warn = warn or (lambda _m: None)
        self.tell = tell or (lambda _m: None)
        self.refine_start = refine_start
        self.start_verdict: Any = None
        self.recorder: Any = None
        self.saver: Any = None
        self.check: Any = None
        self.failed = ""  #: why the MCAP could not be finished ("" when it was)
        self._told = False  # the saved pose's verdict was reported
        self._state = Path(state) if state is not None else None
        self._restore = restore
        self._state_every = state_every
        self._mcap: Path | None = None
        if mcap is not None:
            from icploc.mcap_export import McapError
            from icploc.outputs import OutputError, check_outputs

            try:  # checked now (an input, an unwritable path), created with the localizer
                check_outputs({"--mcap": mcap}, inputs)
            except OutputError as e:
                raise McapError(str(e)) from None
            self._mcap = Path(mcap)

    def on_localizer(self, loc: Localizer) -> None:
        restored = self._state is not None and self._restore and self._state.exists()
        if self.refine_start and not restored:
            loc.refine_start(on_verdict=self._verdict)
        elif self.refine_start:
            self.warn(f"--refine-start: not with the pose restored from {self._state} (it is checked on its own)")
        if self._mcap is not None:
            from icploc.mcap_export import McapRecorder, attach

            if self.recorder is None:
                self.recorder = McapRecorder(self._mcap)
            attach(loc, self.recorder)
        if self._state is not None:
            from icploc.state import StateError, StateSaver, restore

            if self._restore and self._state.exists():
                try:
                    self.check = restore(loc, self._state)
                except StateError as e:
                    self.warn(f"{e}; localizing without it")
            self.saver = StateSaver(loc, self._state, every=self._state_every, on_error=self.warn)

    def _verdict(self, v: Any) -> None:
        self.start_verdict = v
        (self.tell if v.verdict == "refined" else self.warn)(v.summary())

    def observe(self, e: Estimate) -> None:
        if self.check is not None and self.check.verdict and not self._told:
            self._told = True
            if self.check.verdict == "rejected":
                self.warn(
                    f"{self._state}: the saved pose does not match the first scan; "
                    "localizing globally"
                )
        if self.saver is not None:
            self.saver.observe(e)

    def close(self) -> None:
        """Save the last state and finish the MCAP; a failure is warned about (the run's
        other outputs are written) and kept in :attr:`failed`."""
        try:
            if self.saver is not None:
                self.saver.close()
        finally:
            if self.recorder is not None:
                from icploc.mcap_export import McapError

                try:
                    self.recorder.close()
                except McapError as e:
                    self.failed = str(e)
                    self.warn(self.failed)
