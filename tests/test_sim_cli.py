"""``icploc sim serve``: the device simulators from the command line (was the argparse
``python -m icploc.sim.session``)."""

from __future__ import annotations

import subprocess
import sys

from icploc.cli import _register, app
from icploc.drivers.powerbot import PowerBot
from icploc.drivers.sick import PLS
from typer.testing import CliRunner


def test_sim_serve_is_an_icploc_command() -> None:
    _register()
    r = CliRunner().invoke(app, ["sim", "serve", "--help"])
    assert r.exit_code == 0 and "--people" in r.output and "--duration" in r.output


def test_sim_serve_rejects_a_negative_number_of_people() -> None:
    _register()
    assert CliRunner().invoke(app, ["sim", "serve", "--people", "-1"]).exit_code == 2


def test_sim_serve_prints_two_ports_the_drivers_talk_to() -> None:
    """The printed ports are a live PLS and PowerBot: both drivers connect and read."""
    cmd = [sys.executable, "-m", "icploc.cli", "sim", "serve", "--fast", "--duration", "60"]
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True) as proc:
        try:
            assert proc.stdout is not None
            laser_line, base_line = proc.stdout.readline(), proc.stdout.readline()
            with PLS(laser_line.split()[-1], baud_settle=0.0) as laser, PowerBot(base_line.split()[-1]) as bot:
                scans = list(laser.scans(limit=3))
                sips = list(bot.sips(limit=3))
        finally:
            proc.terminate()
    assert (laser_line.split()[0], base_line.split()[0], len(scans), len(sips)) == ("laser", "base", 3, 3)
