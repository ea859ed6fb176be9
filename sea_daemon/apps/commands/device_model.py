"""``sea-daemon device-model``: the exoskeleton's CANopen devices on a bus, around the simulator.

Runs a CiA 402 drive and a CiA 406 load encoder per joint (:mod:`sea_daemon.hw.device_model`) with
the simulator's true plant as their physics, until SIGINT/SIGTERM or ``--duration``.  With
``--bus remote`` it joins a ``python -m can_remote`` server, so a driver in another process can
talk to it where the kernel has no SocketCAN.  Prints one line ``device-model ready ...`` on
stdout once the nodes have booted.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import signal
import threading

from sea_daemon.core.config import BusConfig
from sea_daemon.core.sim.plant import Plant
from sea_daemon.errors import InputError
from sea_daemon.hw.bus import make_bus
from sea_daemon.hw.device_model import DeviceModel, parse_fault
from sea_daemon.hw.device_model.split_plant import SplitPlant
from sea_daemon.hw.errors import DeviceMismatch
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.io.scenario import human_torque, load_scenario, make_plant, task_plant
from sea_daemon.runtime.affinity import parse_cpus, pin_thread
from sea_daemon.runtime.realtime import freeze_heap, try_realtime
from sea_daemon.runtime.rig import bus_overrides

DESCRIPTION = __doc__


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bus", choices=BusConfig.INTERFACES, help="bus interface (default: hardware.bus.interface)")
    p.add_argument("--channel", help="virtual: a name; socketcan: can0 / vcan0; remote: ws://127.0.0.1:PORT/; "
                   "a comma-separated name per joint: a bus per joint (joints of one name share its bus)")
    p.add_argument("--config", default=None, help="true model configuration YAML (default: configs/exo_1dof.yaml)")
    p.add_argument("--scenario", default=None, help="simulator scenario YAML (true plant with hidden effects; "
                   "human: track starts the task's subject at rest at its first target)")
    p.add_argument("--joints", type=int, default=1,
                   help="N joints as N uncoupled copies of the one-joint --config's plant, a drive and a load "
                        "encoder each (node ids 2j-1, 2j; without --scenario; default 1)")
    p.add_argument("--q0", type=float, default=0.3, help="initial link angle [rad] without --scenario (default 0.3)")
    p.add_argument("--seed", type=int, default=None, help="seed of the plant's torque noise")
    p.add_argument("--fault", action="append", default=[], metavar="KIND[:k=v,...]",
                   help="inject a fault (repeatable): drop, delay, stuck, jump, emcy, heartbeat, busoff; "
                        "keys target=drive|encoder, joint=, at=SECONDS, count=, seconds=, rad=, code=")
    p.add_argument("--free-running", action="store_true",
                   help="step the physics in real time instead of once per SYNC (lock-step)")
    p.add_argument("--position-preset", type=int, default=0, help="added to the drive's 0x6064 (int32 wrap tests)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (wall clock)")
    p.add_argument("--rt-priority", type=int, default=0,
                   help="SCHED_FIFO priority for the device model's threads (0: not asked; stands in for hardware "
                        "that answers in its own time)")
    p.add_argument("--cpu", type=int, default=None,
                   help="pin the device model's threads to this CPU (docs/daemon.md \"CPU placement\"; default: "
                        "not pinned)")
    p.add_argument("--stats", action="store_true",
                   help="print one JSON line 'device-model stats {...}' at exit: answer latency to SYNC and the "
                        "SYNC handler's CPU time")


def _plant(args, cfg):
    if args.joints > 1:
        plant = SplitPlant([Plant(cfg, q0=args.q0, seed=None if args.seed is None else args.seed + j)
                            for j in range(args.joints)])
        bus = {k: v for k, v in cfg.hardware.bus.to_dict().items()
               if k not in ("drive_node", "encoder_node", "q_offset", "theta_m_offset", "channel")}
        b = BusConfig.from_dict(bus, args.joints, "--joints")
        return plant, dataclasses.replace(cfg, joints=args.joints, hardware=dataclasses.replace(
            cfg.hardware, bus=b)), None
    if args.scenario:
        sc = load_scenario(args.scenario)
        if sc.human == "track":
            # the task's estimation phase: the subject tracks from t = 0, the arm at rest at its start
            plant, subject = task_plant(sc, seed=args.seed)
            return plant, sc.nominal, subject
        return make_plant(sc, args.seed), sc.nominal, human_torque(sc)
    return Plant(cfg, q0=args.q0, seed=args.seed), cfg, None


def run(args) -> int:
    cfg = load_config(args.config or default_config_path())
    faults = [parse_fault(f) for f in args.fault]
    cpu = None if args.cpu is None else parse_cpus(str(args.cpu), "--cpu", ("device model",))[0]
    if not 1 <= args.joints <= 16 or (args.joints > 1 and (args.scenario or cfg.joints != 1)):
        raise InputError(f"--joints {args.joints}: allowed 1..16; more than 1 copies a one-joint --config's "
                         f"plant (its configuration has {cfg.joints}), without --scenario")
    b = bus_overrides(cfg, args.bus, None if args.joints > 1 else args.channel).hardware.bus
    plant, cfg, tau_h_act = _plant(args, cfg)
    b = dataclasses.replace(cfg.hardware.bus, interface=b.interface, channel=b.channel,
                            joint_channel=b.joint_channel if args.joints == 1 else ())
    if args.joints > 1 and args.channel:
        b = b.with_channel(args.channel)
    buses = b.buses()
    handles = []
    try:
        for c, _ in buses:
            handles.append(make_bus(dataclasses.replace(b, channel=c)))
    except DeviceMismatch as e:
        for h in handles:
            h.shutdown()
        raise InputError(str(e)) from None
    index = {c: i for i, (c, _) in enumerate(buses)}
    model = DeviceModel(handles, plant, drive_nodes=b.drive_node, encoder_nodes=b.encoder_node,
                        lock_step=not args.free_running, position_preset=args.position_preset, owns_bus=True,
                        tau_h_act=tau_h_act, joint_bus=[index[c] for c in b.channels()])
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    rt = "not asked"
    if args.rt_priority:
        # before the threads start: they inherit it
        r = try_realtime(args.rt_priority)
        rt = f"{r['sched']}, memory {r['mlockall']}"
    # before the threads start: they inherit it
    pin_thread(cpu)
    # the SYNC handler's collections walk only what it creates, not the whole heap (tens of ms)
    freeze_heap()
    model.start()
    try:
        for f in faults:
            model.schedule(f)
        print(f"device-model ready on {b.interface} {','.join(c for c, _ in buses)}: drives {list(b.drive_node)}, "
              f"encoders {list(b.encoder_node)}, {'free-running' if args.free_running else 'lock-step'}; sched {rt}",
              flush=True)
        stop.wait(args.duration)
        if model.error is not None:
            logging.getLogger("sea_daemon.device_model").error("the SYNC handler failed: %s", model.error)
            return 1
    finally:
        model.stop()
        if args.stats:
            print("device-model stats " + json.dumps(model.answer_stats()), flush=True)
    return 0
