"""Simulation: worlds with exact truth, a kinematic simulator, and device simulators.

The worlds and the kinematic simulator are importable from here::

    from icploc import sim
    frames = sim.simulate(sim.lab(), sim.lab_random_walk(8.0), seed=1)

* :mod:`icploc.sim.world` — :class:`World` (walls by the Rust ray caster, glass under a
  glass model, walking people) and :class:`Person`;
* :mod:`icploc.sim.scenes` — the built-in worlds (lab, crowd, aisles, box, any floor
  plan) and paths through them;
* :mod:`icploc.sim.pursuit` — the one pure-pursuit path follower;
* :mod:`icploc.sim.kinematic` — :func:`simulate`: true pose, drifting odometry and noisy
  scans at the laser rate, without devices;
* :mod:`icploc.sim.robot` — differential drive with PowerBot dimensions, noisy encoders;
* :mod:`icploc.sim.pls_device`, :mod:`icploc.sim.powerbot_device` — protocol engines that
  speak the SICK telegram and ARCOS packet protocols byte for byte, with fault injection
  (:class:`icploc.sim.device.Faults`);
* :mod:`icploc.sim.device` — the runner thread that puts an engine on a transport, in
  real time (byte time at the current baud rate, scan / SIP periods) or as fast as
  possible, and the periodic stream both engines send;
* :mod:`icploc.sim.pty` — pseudo-terminal pairs the drivers open like serial ports;
* :mod:`icploc.sim.session` — both devices for one world and robot, ready for
  ``PLS(session.laser_port)`` and ``PowerBot(session.base_port)``; ``icploc sim serve``;
* :mod:`icploc.sim.harness` — the live path (:mod:`icploc.live`) against the device
  simulators (``icploc run --simulate``, the demo).
"""

from icploc.sim.kinematic import SimFrame, simulate
from icploc.sim.pursuit import PurePursuit
from icploc.sim.scenes import (
    aisles,
    box,
    circle_path,
    crowd,
    from_plan,
    lab,
    lab_random_walk,
    rect,
    tour_path,
)
from icploc.sim.world import GlassModel, IncidenceGlass, Person, RandomGlass, World

__all__ = [
    "GlassModel",
    "IncidenceGlass",
    "Person",
    "PurePursuit",
    "RandomGlass",
    "SimFrame",
    "World",
    "aisles",
    "box",
    "circle_path",
    "crowd",
    "from_plan",
    "lab",
    "lab_random_walk",
    "rect",
    "simulate",
    "tour_path",
]
