"""``bench loop``'s rig: the device model in this process or in its own (:func:`bench_rig`), and
for ``--joints N`` (N > 1) the configuration, the controller, the GP's training and the bus
load per bus.

The configuration for two joints is the shoulder–elbow exoskeleton of a URDF
(``configs/exo_2dof.yaml``: its joints coupled through M(q) and the bias, the device model's plant
the coupled one), otherwise (or ``--uncoupled``) the simulated exoskeleton's
(``configs/exo_1dof_sim.yaml``) for N joints (its per-joint estimator noise repeated per joint);
a bus per joint (``hardware.bus.channel`` a list, docs/can.md "Bus load"; ``--one-bus``: every
joint on one bus).  The device model's plant is that configuration's (N joints, no subject;
uncoupled joints as one-joint plants on their compiled path); the controller a PD per joint
around slow sines from the holding torque; the GP-AKF's residual is learned by a lock-step run of the same
controller against the device model in this process (``--train`` cycles at ``--model-rate``,
the Theorem-1 bound off while it learns), then frozen.
"""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np

from sea_daemon.apps.bench.can_cycle import remote_relay
from sea_daemon.hw.canopen_buses import make_canopen_hardware
from sea_daemon.io.configfile import import_root, save_config
from sea_daemon.runtime.rig import Rig, make_rig

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.sim.plant import Plant
from sea_daemon.hw.busload import bus_loads, measured_load
from sea_daemon.core.rates import at_rate
from sea_daemon.hw.device_model.split_plant import SplitPlant
from sea_daemon.io.configfile import data_root, load_config, load_yaml, read_urdf
from sea_daemon.runtime.loop import FixedRateLoop
from sea_daemon.runtime.rig import device_model_rig, on_fresh_virtual_channel

#: the estimator's per-joint vectors of the one-joint configuration, repeated per joint
_PER_JOINT = ("R", "Sigma_nom")
#: the start angle of every joint [rad] (the device model's --q0)
Q0 = 0.3


def joints_config(n: int, one_bus: bool = False, uncoupled: bool = False) -> ModelConfig:
    """The exoskeleton with ``n`` joints, a bus per joint (or one bus): for two joints the
    shoulder–elbow exoskeleton of a URDF (``configs/exo_2dof.yaml``, coupled through M(q) and the
    bias); otherwise, or ``uncoupled``, the simulated one-joint exoskeleton ``n`` times."""
    coupled = n == 2 and not uncoupled
    name = "exo_2dof.yaml" if coupled else "exo_1dof_sim.yaml"
    raw = load_yaml(data_root() / "configs" / name)
    if not coupled:
        raw["joints"] = n
        est = raw.setdefault("estimator", {})
        for key in _PER_JOINT:
            if key in est:
                est[key] = np.repeat(np.asarray(est[key], dtype=float), n).tolist()
    bus = raw.setdefault("hardware", {}).setdefault("bus", {})
    channel = bus.get("channel", "sea-daemon")
    bus["channel"] = channel if one_bus else [f"{channel}-j{j + 1}" for j in range(n)]
    path = data_root() / "configs" / name
    # the file's path as the source: its model.urdf is relative to it (save_config rewrites it)
    return ModelConfig.from_dict(raw, str(path), urdf_text=read_urdf(raw, path))


def one_joint_config(rate: float) -> ModelConfig:
    """The simulated exoskeleton's one-joint configuration at ``rate``."""
    return at_rate(load_config(data_root() / "configs" / "exo_1dof_sim.yaml"), rate)


def joints_plant(cfg: ModelConfig, seed: int | None = None):
    """The device model's plant of ``cfg`` at :data:`Q0`: the coupled plant of its URDF, or
    :func:`split_plant` (one-joint plants side by side)."""
    if cfg.model.urdf:
        return Plant(cfg, q0=Q0, seed=seed)
    return split_plant(cfg.joints, cfg.rate_hz)


def split_plant(n: int, rate: float) -> SplitPlant:
    """The device model's plant for ``n`` joints: ``n`` one-joint plants at :data:`Q0` (as
    ``sea-daemon device-model --joints n``)."""
    return SplitPlant([Plant(one_joint_config(rate), q0=Q0) for _ in range(n)])


class SwayController:
    """PD per joint around q0 + 0.2 sin(2π f_j t) (f_j = 0.3, 0.4, ... Hz) on top of the torque that
    holds the arm at q0; preallocated, no estimate used."""

    KP, KD, AMP = 40.0, 1.0, 0.2

    def __init__(self, n: int, hold: np.ndarray, q0: float = Q0):
        self.hold = np.asarray(hold, dtype=float).reshape(n)
        self.freq = 2 * np.pi * (0.3 + 0.1 * np.arange(n))
        self.q0 = q0
        self.tau = np.zeros(n)
        self._ref = np.zeros(n)
        self._q_prev = None
        self._t_prev = 0.0

    def update(self, t: float, q: np.ndarray, theta_m: np.ndarray, est) -> np.ndarray:
        np.multiply(self.freq, t, out=self._ref)
        np.sin(self._ref, out=self._ref)
        tau = self.tau
        np.subtract(self.q0 + self.AMP * self._ref, q, out=tau)
        tau *= self.KP
        if self._q_prev is not None and t > self._t_prev:
            tau -= self.KD * (q - self._q_prev) / (t - self._t_prev)
            self._q_prev[:] = q
        else:
            self._q_prev = np.array(q, dtype=float)
        self._t_prev = t
        tau += self.hold
        return tau


def trained_estimator(cfg_model: ModelConfig, cfg: ModelConfig, train: int, estimator: str, bound: bool):
    """The estimator of the run (at ``cfg``'s rate): the GP-AKF with a residual learned over
    ``train`` lock-step cycles at ``cfg_model``'s rate (device model in this process), frozen;
    or the AKF.  (estimator, its residual or None)."""
    if estimator != "gp-akf":
        return make_estimator("akf", cfg, dt=cfg.dt, bound=bound), None
    c = on_fresh_virtual_channel(cfg_model, "bench-train")
    plant = Plant(c, q0=Q0, seed=1)
    rig = device_model_rig(c, plant, initial_torque=plant.hold_torque)
    learner = make_estimator("gp-akf", c, dt=c.dt, learning=True, bound=False)
    try:
        rig.start()
        FixedRateLoop(rig.hw, learner, SwayController(c.joints, plant.hold_torque), n=c.joints, period=c.dt,
                      realtime=False, initial_torque=plant.hold_torque, fail_fast=True).run(train)
    finally:
        rig.stop()
    return make_estimator("gp-akf", cfg, dt=cfg.dt, residual=learner.gp, learning=False, bound=bound), learner.gp


def per_bus_load(cfg: ModelConfig, rate: float, dev_stats: dict | None, publisher) -> list[dict]:
    """Per bus: the frames per cycle measured (the device model's frames on that bus and the
    daemon's TPDOs sent on it, over its SYNCs) and their load at the bus's bitrate without and
    with worst-case stuffing (:func:`~sea_daemon.hw.busload.measured_load`), beside the arithmetic of
    :func:`sea_daemon.hw.busload.bus_loads`."""
    b = cfg.hardware.bus
    planned = bus_loads(b, rate)
    tpdo = getattr(publisher, "tpdo", None)
    parts = getattr(tpdo, "parts", None) or ([tpdo] if tpdo is not None else [])
    dev_buses = (dev_stats or {}).get("buses") or ([dev_stats] if dev_stats else [])
    out = []
    for i, p in enumerate(planned):
        d = dev_buses[i] if i < len(dev_buses) else None
        row = {**p.to_dict(), "measured": None}
        if d and d.get("syncs"):
            sent = parts[i].sent if i < len(parts) else 0
            sent_bytes = parts[i].sent_bytes if i < len(parts) else 0
            fpc, load, worst = measured_load(d["frames"] + sent, d["data_bytes"] + sent_bytes, d["syncs"], rate,
                                             b.bitrate)
            row["measured"] = {"frames_per_cycle": fpc, "load": load, "load_worst_stuffing": worst}
        out.append(row)
    return out


def describe_bus_load(rows: list[dict]) -> list[str]:
    """The printed lines of :func:`per_bus_load`."""
    lines = []
    for r in rows:
        m = r["measured"]
        got = (f"measured {m['frames_per_cycle']:.2f} frames per cycle, {m['load'] * 100:.1f} % without stuffing, "
               f"{m['load_worst_stuffing'] * 100:.1f} % with worst-case stuffing" if m else "not measured")
        lines.append(f"bus {r['channel']} (joints {', '.join(map(str, r['joints']))}): {got}; arithmetic "
                     f"{r['frames_per_cycle']:.2f} frames, {r['load'] * 100:.1f} % / {r['load_worst_stuffing'] * 100:.1f} %")
    return lines


def fresh_channels(cfg: ModelConfig, interface: str, **bus) -> ModelConfig:
    """``cfg`` on ``interface`` with a new channel name per bus (``bus``: other fields to set)."""
    b = cfg.hardware.bus
    tag = uuid.uuid4().hex[:8]
    names = {c: f"bench-{tag}-{i + 1}" for i, (c, _) in enumerate(b.buses())}
    b = dataclasses.replace(b, interface=interface, **bus).with_channel(",".join(names[c] for c in b.channels()))
    return dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))


def _wait_line(proc, text: str, timeout: float) -> str:
    import selectors
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise RuntimeError(f"process exited with {proc.returncode} before printing {text!r}")
        if sel.select(0.2):
            line = proc.stdout.readline()
            if text in line:
                return line
    raise RuntimeError(f"no {text!r} within {timeout} s")


def device_model_process(cfg, tmp: Path, extra: list[str], rt_priority: int = 70, dev_cfg=None, cpu=None):
    """``sea-daemon device-model`` in its own process on ``cfg``'s bus or buses (``--stats``,
    SCHED_FIFO ``rt_priority``; ``extra``: its plant arguments; ``dev_cfg``: its --config, default
    ``cfg``; ``cpu``: its --cpu), and the driver's :class:`Rig` for it."""
    path = Path(tmp) / "device-model.yaml"
    save_config(dev_cfg or cfg, path)
    b = cfg.hardware.bus
    channels = ",".join(b.channels()) if b.joint_channel else b.channel
    proc = subprocess.Popen([sys.executable, "-m", "sea_daemon", "device-model", "--bus", b.interface, "--channel",
                             channels, "--config", str(path), "--stats", "--rt-priority", str(rt_priority), *extra,
                             *([] if cpu is None else ["--cpu", str(cpu)])],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env=dict(os.environ, PYTHONPATH=str(import_root())))
    try:
        ready = _wait_line(proc, "device-model ready", 120)
    except BaseException:
        proc.kill()
        raise
    where = ", ".join(c for c, _ in b.buses())
    return proc, Rig(make_canopen_hardware(cfg), f"device model process on {b.interface} {where} "
                     f"({ready.split(';')[-1].strip()})", np.zeros(cfg.joints), cfg=cfg)


def bench_rig(args, cfg, scen: str, tmp: Path, procs: list):
    """The rig of --bus: the device model in this process (virtual) or in its own process
    (ipc, remote: appended to ``procs`` with the relay); (rig, device model process or None).
    One joint: the passive scenario's plant; more: ``cfg``'s plant at :data:`Q0` (no subject)."""
    dev_cpu = args.cpus[2] if getattr(args, "cpus", None) and len(args.cpus) > 2 else None
    deadline_ms = args.tpdo_deadline * cfg.dt * 1e3
    timing = {"pdo_timeout_ms": deadline_ms}
    if args.max_missed is not None:               # else the configuration's tolerance (a duration)
        timing["max_missed_cycles"] = args.max_missed
        timing["max_missed_ms"] = None
    if args.bus == "virtual":
        if cfg.joints == 1:
            rig = make_rig(cfg, device_model=scen, phase="estimation")
        else:
            c = on_fresh_virtual_channel(cfg, "bench")
            plant = joints_plant(c)
            rig = device_model_rig(c, plant, initial_torque=plant.hold_torque)
        b = dataclasses.replace(rig.cfg.hardware.bus, **timing)
        rig.cfg = dataclasses.replace(rig.cfg, hardware=dataclasses.replace(rig.cfg.hardware, bus=b))
        buses = {c: h for c, h in zip((c for c, _ in b.buses()), [rig.drv_bus] + rig.more_buses[len(b.buses()) - 1:])}
        rig.hw = make_canopen_hardware(rig.cfg, buses)
        return rig, None
    slow = {"heartbeat_timeout_ms": 2000, "sdo_timeout_ms": 3000}
    if args.bus == "remote":
        if cfg.joints > 1:
            raise ValueError("--bus remote: one joint only (one relay)")
        server, url = remote_relay()
        procs.append(server)
        cfg_r = fresh_channels(cfg, "remote", **timing, **slow)
        cfg_r = dataclasses.replace(cfg_r, hardware=dataclasses.replace(
            cfg_r.hardware, bus=dataclasses.replace(cfg_r.hardware.bus, channel=url)))
    else:
        cfg_r = fresh_channels(cfg, "ipc", **timing, **slow)
    if cfg.joints == 1:
        dev, rig = device_model_process(cfg_r, tmp, ["--scenario", scen], args.device_rt_priority, cpu=dev_cpu)
    elif cfg.model.urdf:
        # the coupled plant of the URDF behind a drive and an encoder per joint
        dev, rig = device_model_process(cfg_r, tmp, ["--q0", str(Q0)], args.device_rt_priority, cpu=dev_cpu)
    else:
        one = one_joint_config(cfg.rate_hz)
        b1 = dataclasses.replace(cfg_r.hardware.bus.for_joints((0,), cfg_r.hardware.bus.channel))
        one = dataclasses.replace(one, hardware=dataclasses.replace(one.hardware, bus=b1))
        dev, rig = device_model_process(cfg_r, tmp, ["--joints", str(cfg.joints), "--q0", str(Q0)],
                                        args.device_rt_priority, dev_cfg=one, cpu=dev_cpu)
    procs.append(dev)
    return rig, dev


def stop_procs(procs: list, dev) -> dict | None:
    """Stop the helper processes; the device model's statistics line, when it printed one."""
    dev_stats = None
    for p in reversed(procs):
        p.terminate()
        try:
            out_text, _ = p.communicate(timeout=20)
            if p is dev:
                for line in (out_text or "").splitlines():
                    if line.startswith("device-model stats "):
                        dev_stats = json.loads(line[len("device-model stats "):])
        except subprocess.TimeoutExpired:
            p.kill()
    return dev_stats
