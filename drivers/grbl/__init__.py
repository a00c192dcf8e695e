"""GRBL 1.1 over serial.

* :mod:`drivers.grbl.protocol` — pure parsers: byte chunks -> lines -> messages;
  real-time bytes and overrides.
* :mod:`drivers.grbl.readings` — what the messages mean in mm: status reports ->
  :class:`~drivers.state.MachineState`, units, the work offset in force, limits.
* :mod:`drivers.grbl.driver` — :class:`GrblController` on any pyserial port
  (``grbl://``, ``grbl+pty://``, ``grbl+socket://`` URLs).
* :mod:`drivers.grbl.peer` — :class:`GrblPeer`, the virtual machine speaking GRBL 1.1 on
  a pseudo-terminal or TCP socket, as the Grbl 1.1h firmware does; its ``$`` commands
  are in :mod:`drivers.grbl.peer_system`, its reports in :mod:`drivers.grbl.peer_report`,
  its G-code execution (planner feeding, spindle/coolant/offset syncs) in
  :mod:`drivers.grbl.peer_gcode`.
* :mod:`drivers.grbl.passthrough` — the machine's port offered to the user's sender,
  watched as bytes pass.
* :mod:`drivers.grbl.endpoints` — the pty/TCP byte pipes the last two share.

Only this package imports pyserial (``driver`` and ``passthrough``).
"""
