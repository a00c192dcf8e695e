"""``dexmon serve-virtual``: the virtual controller as a GRBL device and/or Modbus server.

    dexmon serve-virtual job.nc --modbus tcp:5020 --speed 4
    dexmon serve-virtual --grbl pty                  # a sender (UGS, CNCjs ...) streams to it
    dexmon serve-virtual --grbl tcp:0 --modbus tcp:0 # both, on free ports

Prints one line per endpoint (``grbl pty: /dev/pts/7``, ``grbl tcp: 127.0.0.1:40123``,
``modbus tcp: 127.0.0.1:5020 map generic``), flushed, then serves until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import signal
import sys
import threading

from drivers.errors import DriverError
from monitor.options import number

HELP = "expose the virtual controller as a GRBL device and/or Modbus server"


def add_arguments(parser) -> None:
    parser.add_argument("program", nargs="?", metavar="PROGRAM",
                        help="G-code job the machine runs by itself (Modbus only). With --grbl a sender "
                             "streams the job, so PROGRAM is optional and is not run")
    parser.add_argument("--grbl", metavar="pty|tcp:PORT",
                        help="speak GRBL 1.1 on a new pseudo-terminal (its path is printed) or a TCP port (0: any free port)")
    parser.add_argument("--modbus", metavar="tcp:PORT",
                        help="serve the register map over Modbus TCP on PORT (0: any free port)")
    parser.add_argument("--map", default="generic", metavar="FILE",
                        help="register map (TOML file or shipped name: generic, iai_robo_cylinder); default generic")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--speed", type=float, default=1.0, metavar="N", help="run N times faster than real time (default 1)")
    parser.add_argument("--max-rate", default="500,500,500", metavar="X,Y,Z",
                        help="axis maximum rates, mm/min (GRBL $110-$112; default 500,500,500)")
    parser.add_argument("--accel", default="10,10,10", metavar="X,Y,Z",
                        help="axis accelerations, mm/s^2 (GRBL $120-$122; default 10,10,10)")
    parser.add_argument("--travel", metavar="X,Y,Z",
                        help="enable soft limits with this travel per axis, mm (machine range [-travel, 0])")
    parser.add_argument("--faults", metavar="SPEC",
                        help="fault injection for the Modbus server and the program, e.g. 'late=0.1,alarm=30:1,seed=2'")
    parser.add_argument("--exit-when-done", action="store_true",
                        help="stop serving once PROGRAM has run to the end (or the machine alarmed)")


def _floats(text: str, option: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise DriverError(f"{option} {text!r}: expected comma-separated numbers, e.g. 500,500,500") from None
    if not vals or any(v <= 0 for v in vals):
        raise DriverError(f"{option} {text!r}: expected positive numbers")
    return vals


def _endpoint(text: str, option: str, allow_pty: bool) -> tuple[str, int]:
    if allow_pty and text == "pty":
        return "pty", 0
    kind, _, port = text.partition(":")
    if kind == "tcp" and port.isdigit() and int(port) <= 65535:
        return "tcp", int(port)
    expected = "'pty' or 'tcp:PORT'" if allow_pty else "'tcp:PORT'"
    raise DriverError(f"{option} {text!r}: expected {expected}")


def _say(text: str) -> None:
    print(text, flush=True)


def run(args) -> int:
    from drivers.virtual.faults import FaultInjector
    from drivers.virtual.machine import VirtualMachine
    from drivers.virtual.machine_config import MachineConfig
    from drivers.virtual.runner import RealTimeRunner

    if not args.grbl and not args.modbus:
        raise DriverError("serve-virtual: nothing to serve; give --grbl pty|tcp:PORT and/or --modbus tcp:PORT")
    number(args.speed, "--speed")  # inf advanced the machine by inf (0 x inf: nan) seconds a tick
    grbl = _endpoint(args.grbl, "--grbl", True) if args.grbl else None
    modbus = _endpoint(args.modbus, "--modbus", False) if args.modbus else None
    rates = _floats(args.max_rate, "--max-rate")
    accels = _floats(args.accel, "--accel")
    if len(rates) != len(accels):
        raise DriverError("--max-rate and --accel must name the same number of axes")
    travel = dict(travel_min=None, travel_max=None)
    if args.travel:
        tr = _floats(args.travel, "--travel")
        travel = dict(travel_min=tuple(-v for v in tr), travel_max=tuple(0.0 for _ in tr))
    config = MachineConfig(max_rate=rates, accel=accels, **travel)
    faults = FaultInjector(args.faults) if args.faults else None
    regmap = None
    if modbus:
        from drivers.modbus.regmap import load_map

        regmap = load_map(args.map)  # before anything listens: a bad map is a one-line error

    moves = None
    if args.program and not grbl:
        from drivers.virtual.controller import load_moves

        moves, _ = load_moves(args.program)
    start = moves["start"][0] if moves is not None and len(moves) else None
    vm = VirtualMachine(config, position=start)
    done = threading.Event()
    stop = threading.Event()

    peer = server = runner = None
    previous = {}
    # handlers first: a signal that comes while the endpoints open still stops us cleanly
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        if grbl:
            try:
                from drivers.grbl.peer import GrblPeer
            except ImportError as exc:
                raise DriverError(f"--grbl: the GRBL peer is not available in this build ({exc})") from None
            peer = GrblPeer(vm, speed=args.speed, run=True)
            runner = peer.runner
            if grbl[0] == "pty":
                _say(f"grbl pty: {peer.serve_pty()}")
            else:
                _say(f"grbl tcp: {args.host}:{peer.serve_tcp(host=args.host, port=grbl[1])}")
            if args.program:
                _say(f"note: {args.program} is not run: with --grbl the sender streams the job")
        else:
            from drivers.virtual.controller import ProgramFeeder

            feeder = ProgramFeeder(moves, faults) if moves is not None else None

            def tick(machine):
                if feeder is not None:
                    feeder(machine)
                    if feeder.all_queued and not machine.busy or machine.state.value == "Alarm":
                        done.set()

            runner = RealTimeRunner(vm, speed=args.speed, on_tick=tick).start()
        if modbus:
            from drivers.modbus.server import ModbusVirtualServer

            server = ModbusVirtualServer(vm, regmap, host=args.host, port=modbus[1], faults=faults).start()
            _say(f"modbus tcp: {args.host}:{server.port} map {regmap.name}")
        _say(f"serving at {args.speed:g}x real time; Ctrl-C to stop")

        while not stop.is_set():
            if args.exit_when_done and done.is_set():
                with vm.lock:
                    st = vm.snapshot()
                _say(f"program done: {st.state.value} at X{st.mpos[0]:.3f} Y{st.mpos[1]:.3f} Z{st.mpos[2]:.3f}"
                     + (f" (ALARM:{st.alarm})" if st.alarm else ""))
                break
            if runner is not None and runner.error is not None:
                raise DriverError(f"virtual machine stopped: {runner.error}")
            stop.wait(0.1)  # a Ctrl-C / SIGTERM sets ``stop``; the timeout lets us notice ``done``
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if server is not None:
            server.stop()
        if peer is not None:
            peer.close()
        elif runner is not None:
            runner.stop()
    _say("stopped")
    return 0


if __name__ == "__main__":  # pragma: no cover
    from monitor.cli import main

    sys.exit(main(["serve-virtual", *sys.argv[1:]]))
