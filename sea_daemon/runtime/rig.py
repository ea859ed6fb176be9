"""The hardware a run is against, and what was started with it: :class:`Rig`.

* :func:`make_rig` — what ``sea-daemon run`` and ``sea-daemon calibrate`` run against: the CAN
  bus of the configuration (``--bus/--channel`` overrides, :func:`bus_overrides`), or for tests,
  the demo and the benchmarks the device model started in this process on a fresh virtual
  channel (``--device-model SCENARIO``: the scenario's true plant and subject behind CANopen,
  lock-step with SYNC), or the simulator's plant without CAN (``--sim SCENARIO``).
* :func:`device_model_rig` — a plant behind the device model and the CANopen driver, each on
  its own handle of one bus channel (the device-model rig of :func:`make_rig`, the
  hardware-in-the-loop session, the benchmarks and the HIL tests).
* :func:`subject_torque` — the scenario's subject over a run of one phase.
"""
from __future__ import annotations

import dataclasses
import uuid
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from sea_daemon.hw.interface import HardwareInterface
from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import InputError
from sea_daemon.io.scenario import Scenario, human_torque, load_scenario, make_plant, task_plant
from sea_daemon.hw.bus import make_bus
from sea_daemon.hw.canopen_buses import make_canopen_hardware
from sea_daemon.hw.device_model import DeviceModel
from sea_daemon.hw.sim_hw import SimHardware


@dataclass
class Rig:
    """The hardware and what was started with it (device model, bus handles).

    ``start()`` starts the device model (when there is one and it is not running yet) and then
    the hardware with ``initial_torque``; ``stop()`` stops both and shuts the bus handles the
    rig opened; idempotent.
    """

    hw: HardwareInterface
    description: str
    initial_torque: np.ndarray                    # what hw.start() primes with
    hold_torque: np.ndarray | None = None         # known for a simulated plant (experimenter's calibration)
    tau_h_act: Callable[[float], np.ndarray] | None = None   # the simulated subject (truth), plant time
    plant: Any = None                             # the simulated plant, when there is one
    device_model: Any = None                      # sea_daemon.hw.device_model.DeviceModel
    cfg: ModelConfig | None = None                # the configuration the hardware runs with
    dev_bus: Any = None                           # the device model's bus handle
    drv_bus: Any = None                           # the driver's bus handle
    more_buses: list = dataclasses.field(default_factory=list)   # the handles of the other buses

    def start_device_model(self) -> None:
        """Boot the device model's nodes (when there is one and it is not running yet)."""
        if self.device_model is not None and not self.device_model.running:
            self.device_model.start()

    def start(self) -> None:
        self.start_device_model()
        self.hw.start(initial_torque=self.initial_torque)

    def stop(self) -> None:
        try:
            self.hw.stop()
        finally:
            try:
                if self.device_model is not None:
                    self.device_model.stop()
            finally:
                for bus in (self.drv_bus, self.dev_bus, *self.more_buses):
                    if bus is not None:
                        bus.shutdown()
                self.drv_bus = self.dev_bus = None
                self.more_buses = []

    @property
    def drive(self):
        """The device model's first drive (a :class:`sea_daemon.hw.device_model.DriveNode`)."""
        return self.device_model.drives[0]

    @property
    def encoder(self):
        """The device model's first load encoder (a :class:`sea_daemon.hw.device_model.EncoderNode`)."""
        return self.device_model.encoders[0]


def bus_overrides(cfg: ModelConfig, bus: str | None, channel: str | None) -> ModelConfig:
    """``cfg`` with ``--bus`` / ``--channel`` (None: the configuration's)."""
    b = cfg.hardware.bus
    b = dataclasses.replace(b, interface=bus or b.interface)
    if channel:
        b = b.with_channel(channel)
    for c in b.channels():
        if b.interface == "remote" and not str(c).startswith(("ws://", "wss://")):
            raise InputError(f"--channel {c!r}: the remote bus needs ws://HOST:PORT/")
    return dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))


def on_fresh_virtual_channel(cfg: ModelConfig, prefix: str) -> ModelConfig:
    """``cfg`` on a new python-can virtual channel ``PREFIX-<random>`` (one per bus of the
    configuration), with PDO, heartbeat and SDO timeouts fit for a loaded machine (the device
    model shares the process)."""
    b = cfg.hardware.bus
    tag = uuid.uuid4().hex[:8]
    names = {c: f"{prefix}-{tag}" + (f"-{i + 1}" if i else "") for i, (c, _) in enumerate(b.buses())}
    b = dataclasses.replace(b, interface="virtual", pdo_timeout_ms=1000.0, heartbeat_timeout_ms=2000,
                            sdo_timeout_ms=3000).with_channel(",".join(names[c] for c in b.channels()))
    return dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))


def subject_torque(sc: Scenario, phase: str) -> Callable[[float], np.ndarray]:
    """τ_h,act(t) of the scenario's subject for a run that starts at plant time 0 in ``phase``
    (an open-loop subject; ``human: track`` in the estimation phase reacts to the plant: :func:`make_rig`)."""
    if phase == "training":
        n = sc.nominal.joints
        return lambda t, _z=np.zeros(n): _z                 # ass:passive_human: the subject is passive
    f = human_torque(sc)
    t_est = sc.training_samples * sc.nominal.dt
    return lambda t: f(t + t_est)                          # the estimation phase starts at t = 0


def device_model_rig(cfg: ModelConfig, plant, *, tau_h_act: Callable[[float], np.ndarray] | None = None,
                     initial_torque: np.ndarray | None = None, position_preset: int = 0, lock_step: bool = True,
                     description: str | None = None) -> Rig:
    """``plant`` behind the device model (``tau_h_act``, ``position_preset``, ``lock_step``: see
    :class:`sea_daemon.hw.device_model.DeviceModel`) and the CANopen driver
    (:func:`sea_daemon.hw.canopen_buses.make_canopen_hardware`), on two handles of each bus of
    ``cfg``; nothing started yet.  ``initial_torque``: default zero."""
    n, b = cfg.joints, cfg.hardware.bus
    buses = b.buses()
    handles: list = []
    try:
        for c, _ in buses:
            handles.append(make_bus(dataclasses.replace(b, channel=c)))
            handles.append(make_bus(dataclasses.replace(b, channel=c)))
    except BaseException:
        for h in handles:
            h.shutdown()
        raise
    dev, drv = handles[0::2], handles[1::2]
    index = {c: i for i, (c, _) in enumerate(buses)}
    model = DeviceModel(dev if len(dev) > 1 else dev[0], plant, drive_nodes=b.drive_node,
                        encoder_nodes=b.encoder_node, position_preset=position_preset, lock_step=lock_step,
                        tau_h_act=tau_h_act, joint_bus=[index[c] for c in b.channels()])
    init = np.zeros(n) if initial_torque is None else np.array(initial_torque, dtype=float).reshape(n)
    hw = make_canopen_hardware(cfg, {c: h for (c, _), h in zip(buses, drv)})
    where = ", ".join(c for c, _ in buses)
    return Rig(hw, description or f"device model on {b.interface} {where}", init,
               np.array(plant.hold_torque, dtype=float).reshape(n), tau_h_act, plant=plant, device_model=model,
               cfg=cfg, dev_bus=dev[0], drv_bus=drv[0], more_buses=dev[1:] + drv[1:])


def make_rig(cfg: ModelConfig, *, sim: str | None = None, device_model: str | None = None,
             phase: str = "estimation") -> Rig:
    """The hardware for ``cfg`` (see the module docstring); ``phase`` picks the subject's torque."""
    n = cfg.joints
    if sim and device_model:
        raise InputError("--sim and --device-model exclude each other")
    scen = sim or device_model
    if not scen:
        b = cfg.hardware.bus
        return Rig(make_canopen_hardware(cfg), f"CAN {b.interface} {', '.join(c for c, _ in b.buses())}",
                   np.zeros(n), cfg=cfg)
    sc = load_scenario(scen)
    if sc.nominal.joints != n:
        raise InputError(f"scenario {scen}: {sc.nominal.joints} joint(s), the configuration has {n}")
    if sc.human == "track" and phase == "estimation":
        # the subject does its task from t = 0, the exoskeleton compensating itself (docs/assist.md)
        plant, tau_h = task_plant(sc, cfg.dt)
    else:
        plant = make_plant(sc)
        tau_h = subject_torque(sc, phase)
    hold = np.array(plant.hold_torque, dtype=float).reshape(n)
    if sim:
        hw = SimHardware(plant, cfg.dt, torque_limit=cfg.hardware.torque_limits(n), tau_h_act=tau_h)
        return Rig(hw, f"simulator ({scen}), no CAN", hold, hold, tau_h, plant=plant, cfg=cfg)
    cfg = on_fresh_virtual_channel(cfg, "sea-daemon")
    return device_model_rig(cfg, plant, tau_h_act=tau_h, initial_torque=hold,
                            description=f"device model ({scen}) on virtual CAN {cfg.hardware.bus.channel}")
