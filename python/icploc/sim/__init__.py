"""Device simulators and the simulated world behind them.

* :mod:`icploc.sim.world` — walls (Rust ray caster), glass, walking people;
* :mod:`icploc.sim.robot` — differential drive with PowerBot dimensions, noisy encoders;
* :mod:`icploc.sim.pls_device`, :mod:`icploc.sim.powerbot_device` — protocol engines that
  speak the SICK telegram and ARCOS packet protocols byte for byte, with fault injection
  (:class:`icploc.sim.device.Faults`);
* :mod:`icploc.sim.device` — the runner thread that puts an engine on a transport, in
  real time (byte time at the current baud rate, scan / SIP periods) or as fast as possible;
* :mod:`icploc.sim.pty` — pseudo-terminal pairs the drivers open like serial ports;
* :mod:`icploc.sim.session` — both devices for one world and robot, ready for
  ``PLS(session.laser_port)`` and ``PowerBot(session.base_port)``.
"""
