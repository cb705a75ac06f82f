"""What ``icploc`` imports to start a command: a top-level command (replay, run, ...) does
not import the ``map`` / ``sim`` sub-apps; help still lists every command."""

from __future__ import annotations

import os
import subprocess
import sys


def test_the_replay_command_does_not_import_the_sub_apps() -> None:
    """``icploc replay ...`` (here its usage error) imports neither ``map`` nor ``sim``'s CLI."""
    code = (
        "import sys, icploc.cli as c\n"
        "sys.argv = ['icploc', 'replay', '--help']\n"
        "try:\n    c.main()\nexcept SystemExit:\n    pass\n"
        "print('icploc.sim.cli' in sys.modules, 'icploc.maps.cli' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False False"


def test_top_level_help_still_lists_the_sub_apps() -> None:
    code = (
        "import sys, icploc.cli as c\n"
        "sys.argv = ['icploc', '--help']\n"
        "try:\n    c.main()\nexcept SystemExit:\n    pass\n"
    )
    env = {**os.environ, "COLUMNS": "120", "TERM": "dumb"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert ("map " in out.stdout, "sim " in out.stdout) == (True, True)
