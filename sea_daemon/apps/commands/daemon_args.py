"""Arguments shared by ``sea-daemon run`` and ``sea-daemon calibrate``."""
from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path

from sea_daemon.client import default_socket
from sea_daemon.core.config import BusConfig
from sea_daemon.core.rates import at_rate
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import load_config
from sea_daemon.io.files import check_output_dir, check_outputs
from sea_daemon.io.owned import check_owned
from sea_daemon.runtime.affinity import parse_cpus
from sea_daemon.runtime.rig import bus_overrides
from sea_daemon.runtime.safety import SafetySupervisor

log = logging.getLogger("sea_daemon")


def add_common(p, *, cycles_help: str) -> None:
    p.add_argument("--config", metavar="MODEL.yaml", required=True, help="model configuration (docs/interfaces.md §2)")
    p.add_argument("--log-dir", metavar="DIR", required=True, help="directory of the measured logs")
    p.add_argument("--state-dir", metavar="DIR", default=None,
                   help="where the pid file for `sea-daemon reset` goes (default: --log-dir)")
    p.add_argument("--bus", choices=BusConfig.INTERFACES, default=None, help="override hardware.bus.interface")
    p.add_argument("--channel", default=None, help="override hardware.bus.channel (can0, vcan0, ws://HOST:PORT/ ...)")
    p.add_argument("--cycles", type=int, default=None, help=cycles_help)
    p.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                   help="instead of --cycles: the session's length in seconds, the same at every rate")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="loop rate [Hz] instead of the configuration's rate_hz: the same configuration and model "
                        "file at another rate (the differentiator window keeps its span in time; "
                        "sea_daemon.core.rates)")
    hw = p.add_mutually_exclusive_group()
    hw.add_argument("--device-model", metavar="SCENARIO.yaml", default=None,
                    help="start the device model (the scenario's true plant and subject as CANopen drive + "
                         "encoder) in this process on a fresh virtual CAN channel (tests, demo, bench)")
    hw.add_argument("--sim", metavar="SCENARIO.yaml", default=None,
                    help="the scenario's simulated plant without CAN (SimHardware; tests, bench)")
    p.add_argument("--pace", choices=("realtime", "lockstep"), default=None,
                   help="realtime: sleep to each absolute deadline (default on a real bus); lockstep: no sleep, "
                        "the simulated plant steps once per cycle as fast as the loop goes (default with "
                        "--device-model / --sim)")
    p.add_argument("--overrun-streak", type=int, default=5,
                   help="consecutive overruns that latch the OVERRUN_STREAK fault (default 5; 0: never, and no "
                        "LOOP_STALL either: timing faults off, for a run whose timing is not under test)")
    p.add_argument("--rt-priority", type=int, default=80,
                   help="SCHED_FIFO priority tried in realtime pace (0: do not try; default 80)")
    p.add_argument("--cpus", metavar="LOOP[,WORKER]", default=None,
                   help="pin the loop's thread to CPU LOOP and the bound worker's process to CPU WORKER "
                        "(docs/daemon.md \"CPU placement\"; default: not pinned, the kernel places them)")
    p.add_argument("--socket", metavar="PATH", default=None,
                   help="UNIX socket the estimate is published on every cycle for local readers "
                        "(sea-daemon watch, sea_daemon.client; default: STATE_DIR/sea-daemon.sock; none: off)")


def inputs(args) -> list:
    """The files the command reads (none of them may be an output)."""
    return [args.config, args.device_model, args.sim, getattr(args, "scenario", None), getattr(args, "model", None)]


def load(args, outputs: list | tuple = ()):
    """(cfg, log_dir, state_dir, realtime) from the parsed arguments; InputError on bad input.

    Before anything starts: ``outputs`` ((flag, path) pairs) can be written and are none of the
    inputs; the log and state directories exist (created), can be written, and are this user's
    (or root's) and nobody else may write them (:func:`sea_daemon.io.owned.check_owned`)."""
    check_outputs(outputs, inputs=inputs(args))
    cfg = at_rate(bus_overrides(load_config(args.config), args.bus, args.channel), getattr(args, "rate", None))
    if args.cycles is not None and args.cycles < 1:
        raise InputError(f"--cycles {args.cycles}: allowed >= 1")
    duration = getattr(args, "duration", None)
    if duration is not None:
        if args.cycles is not None:
            raise InputError("--cycles and --duration: give one (--duration is in seconds, --cycles in cycles)")
        if not (math.isfinite(duration) and 0 < duration <= 1e7):
            raise InputError(f"--duration {duration:g}: allowed 0 < SECONDS <= 1e7")
        # the loop's cycles at the configuration's rate (after --rate): the same seconds at every rate
        args.cycles = max(1, int(round(duration * cfg.rate_hz)))
    if args.overrun_streak < 0:
        raise InputError(f"--overrun-streak {args.overrun_streak}: allowed >= 0 (0: never)")
    if not 0 <= args.rt_priority <= 99:
        raise InputError(f"--rt-priority {args.rt_priority}: allowed 0..99")
    args.cpus = parse_cpus(args.cpus, "--cpus", ("loop", "worker"))
    log_dir = check_output_dir("--log-dir", args.log_dir, inputs(args))
    state_dir = check_output_dir("--state-dir", args.state_dir, inputs(args)) if args.state_dir else log_dir
    check_owned("--log-dir", log_dir)
    check_owned("--state-dir" if args.state_dir else "--log-dir", state_dir)
    simulated = bool(args.device_model or args.sim)
    pace = args.pace or ("lockstep" if simulated else "realtime")
    if pace == "lockstep" and not simulated:
        raise InputError("--pace lockstep needs --device-model or --sim (real drives run in real time)")
    if not simulated and cfg.hardware.bus.interface == "remote":
        log.warning("the remote bus (python-can-remote, %s) is for inspection and tools over a network, not "
                    "the real-time loop: its delays latch faults within a few dozen cycles; for separate "
                    "processes on one machine without SocketCAN use --bus ipc (docs/can.md)",
                    cfg.hardware.bus.channel)
    return cfg, log_dir, state_dir, pace == "realtime"


def bus_key(args, cfg) -> tuple[str, str] | list[tuple[str, str]] | None:
    """(interface, channel) of the bus the daemon will own (a list of them with a bus per joint),
    None for a private simulated one (``--device-model`` runs on a fresh virtual channel of its
    own, ``--sim`` has no bus)."""
    if args.device_model or args.sim:
        return None
    b = cfg.hardware.bus
    buses = [(b.interface, c) for c, _ in b.buses()]
    return buses[0] if len(buses) == 1 else buses


def log_name(log_dir: Path, prefix: str) -> Path:
    """``DIR/<prefix>-YYYYmmddTHHMMSSZ.csv``, with a counter when that exists already."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    p = log_dir / f"{prefix}-{stamp}.csv"
    i = 1
    while p.exists():
        p = log_dir / f"{prefix}-{stamp}-{i}.csv"
        i += 1
    return p


def supervisor(args):
    """The fault supervisor with the ``--overrun-streak`` limit."""
    return SafetySupervisor.with_streak(args.overrun_streak)


def socket_path(args, state_dir: Path) -> Path | None:
    """The publication socket of ``--socket`` (None for ``none``; default STATE_DIR/sea-daemon.sock)."""
    if args.socket is None:
        path = default_socket(state_dir)
        if len(os.fsencode(str(path))) >= 108:         # a UNIX socket path holds at most 107 bytes
            log.warning("%s is too long for a UNIX socket: no local publication (give --socket PATH)", path)
            return None
        return path
    if args.socket.lower() == "none":
        return None
    return Path(args.socket)
