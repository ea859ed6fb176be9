"""Scenario files (``configs/scenarios/*.yaml``) as validated, frozen dataclasses.

A scenario says which nominal model the estimator is told about, which effects the true
plant has on top (hidden from the estimator), how the subject behaves, which controller
drives the exoskeleton, and how long the training and estimation phases are::

    model: ../exo_1dof.yaml        # nominal model config, path relative to this file
    seed: 1                        # motor-torque noise (overridable by --seed)
    human: passive                 # passive (τ_h,act = 0) | resist (τ_h,act = −τ_des) | track
    # task: {q_deg: [20, 70], move_s: 2.0, hold_s: 2.0, kp: 15.0, kd: 1.0, ki: 20.0,
    #        activation_s: 0.04, delay_s: 0.03, max_torque: 15.0}
    #                              # human: track — the subject tracks a target angle with muscle
    #                              # torque (sea_daemon.core.sim.subject); its estimation phase
    #                              # runs the assist controller (docs/assist.md)
    tau_h_act_rate: 1.26           # optional [N m/s]: what the experimenter declares about the
                                   # subject, |dτ_h,act/dt| <= this (estimator.tau_h_act_rate)
    plant:
      substep_hz: 1000             # internal RK4 rate [Hz]
      sign_eps: 0.003              # friction-sign smoothing of the true plant [rad/s]
      torque_noise: 0.02           # optional override of hardware.torque_noise [N m]: a number
                                   # (every joint) or a list of one per joint
      effects:                     # hidden effects, docs/interfaces.md §2 vocabulary
        - {type: coulomb, side: load, F_c: 0.4}
    controller:                    # one of:
      type: pid                    #   PID position control on a minimum-jerk trajectory
      kp: 40.0                     #   [N m/rad]
      ki: 80.0                     #   [N m/(rad s)]
      kd: 2.0                      #   [N m s/rad]
      velocity_filter_hz: 30.0     #   low-pass of the differentiated angle [Hz]
      derivative: motor            #   D term on the motor (collocated) or load velocity
      trajectory: {q_start_deg: 10, q_end_deg: 75, move_s: 3.5, moves: 6}   # optional hold_s [s] before each move
    # controller: {type: open_loop, q0_deg: 10,
    #              tau_des: {amplitude: 2.0, frequency_hz: 0.1, offset: 2.0}}
    phases:
      training: {samples: 2100}
      estimation: {samples: 2100}

Unknown keys, missing keys, bad values and unknown effect types raise
:class:`~sea_daemon.errors.ConfigError` naming the key and the allowed values.
"""
from __future__ import annotations

import math
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.hardware_config import per_joint
from sea_daemon.core.validate import check_keys as _check_keys, num as _num
from sea_daemon.core.control import PIDGains, cosine_torque
from sea_daemon.io.configfile import load_config, load_yaml
from sea_daemon.core.effects import Effect, effect_from_dict
from sea_daemon.core.model import SEAModel
from sea_daemon.core.sim.plant import Plant
from sea_daemon.core.sim.subject import TrackingSubject, TrackingTask
from sea_daemon.errors import ConfigError, InputError
from sea_daemon.io.scenario_joints import check_human, links_from_dict
from sea_daemon.io.scenario_joints import controller_from_dict as joints_controller

HUMAN_MODES = ("passive", "resist", "track")
CONTROLLER_TYPES = ("pid", "open_loop")
DERIVATIVES = ("motor", "load")


def _choice(source: str, key: str, v: Any, allowed: tuple[str, ...]) -> str:
    if v not in allowed:
        raise ConfigError(source, key, f"{v!r} is not allowed; allowed: {', '.join(allowed)}")
    return v


def _int(source: str, key: str, v: Any, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ConfigError(source, key, f"must be an integer in {lo}..{hi}, got {v!r}")
    return v


@dataclass(frozen=True)
class PlantSpec:
    """The true plant: hidden effects and integration settings."""

    effects: tuple[Effect, ...] = ()
    substep_hz: float = 1000.0
    sign_eps: float = 3e-3
    torque_noise: float | tuple[float, ...] | None = None   # [N m] every joint's, or each joint's
    link_mass: tuple = ()           # ((URDF link, mass factor), ...) of the true arm (model.urdf)
    link_length: tuple = ()         # ((URDF link, length factor), ...)

    KEYS = ["effects", "substep_hz", "sign_eps", "torque_noise", "links"]

    @classmethod
    def from_dict(cls, d: Mapping, n: int, source: str, urdf: str | None = None) -> "PlantSpec":
        _check_keys(source, "plant.", d, cls.KEYS, ["effects"])
        eff = d["effects"]
        if eff is None:
            eff = []
        if not isinstance(eff, list):
            raise ConfigError(source, "plant.effects", f"must be a list of effect mappings, got {eff!r}")
        return cls(
            effects=tuple(effect_from_dict(e, n, source, f"plant.effects[{i}]") for i, e in enumerate(eff)),
            substep_hz=_num(source, "plant.substep_hz", d.get("substep_hz", 1000.0), lo=10.0, hi=1e6),
            sign_eps=_num(source, "plant.sign_eps", d.get("sign_eps", 3e-3), positive=True),
            torque_noise=(None if d.get("torque_noise") is None else
                          per_joint(source, "plant.torque_noise", d["torque_noise"], n, non_negative=True)),
            **({} if "links" not in d else dict(zip(("link_mass", "link_length"),
                                                    links_from_dict(d["links"], urdf, source)))),
        )


@dataclass(frozen=True)
class TrajectorySpec:
    """Minimum-jerk moves q_start → q_end → q_start … (Sec. V-B)."""

    q_start_deg: float = 10.0
    q_end_deg: float = 75.0
    move_s: float = 3.5
    moves: int = 6
    hold_s: float = 0.0             # [s] hold before each move (optional)

    KEYS = ["q_start_deg", "q_end_deg", "move_s", "moves", "hold_s"]
    REQUIRED = ["q_start_deg", "q_end_deg", "move_s", "moves"]

    @classmethod
    def from_dict(cls, d: Mapping, source: str) -> "TrajectorySpec":
        p = "controller.trajectory."
        _check_keys(source, p, d, cls.KEYS, cls.REQUIRED)
        return cls(q_start_deg=_num(source, p + "q_start_deg", d["q_start_deg"], lo=-360.0, hi=360.0),
                   q_end_deg=_num(source, p + "q_end_deg", d["q_end_deg"], lo=-360.0, hi=360.0),
                   move_s=_num(source, p + "move_s", d["move_s"], positive=True),
                   moves=_int(source, p + "moves", d["moves"], 1, 100000),
                   hold_s=_num(source, p + "hold_s", d.get("hold_s", 0.0), lo=0.0, hi=3600.0))


@dataclass(frozen=True, kw_only=True)
class PIDSpec(PIDGains):
    """PID position control on the load angle tracking a minimum-jerk trajectory: the gains
    (:class:`~sea_daemon.core.control.PIDGains`) and the trajectory."""

    trajectory: TrajectorySpec
    type: str = "pid"

    KEYS = ["type", "kp", "ki", "kd", "velocity_filter_hz", "derivative", "trajectory"]
    REQUIRED = ["type", "kp", "ki", "kd", "trajectory"]

    @property
    def q0(self) -> float:
        return math.radians(self.trajectory.q_start_deg)

    @classmethod
    def from_dict(cls, d: Mapping, source: str) -> "PIDSpec":
        _check_keys(source, "controller.", d, cls.KEYS, cls.REQUIRED)
        return cls(kp=_num(source, "controller.kp", d["kp"], non_negative=True),
                   ki=_num(source, "controller.ki", d["ki"], non_negative=True),
                   kd=_num(source, "controller.kd", d["kd"], non_negative=True),
                   velocity_filter_hz=_num(source, "controller.velocity_filter_hz",
                                           d.get("velocity_filter_hz", 20.0), positive=True),
                   derivative=_choice(source, "controller.derivative", d.get("derivative", "motor"), DERIVATIVES),
                   trajectory=TrajectorySpec.from_dict(d["trajectory"], source))


@dataclass(frozen=True)
class OpenLoopSpec:
    """Sec. V-C: τ_m = τ_des + τ_comp at a fixed arm position q0; τ_des = −A cos(2πft) + offset."""

    q0_deg: float = 10.0
    amplitude: float = 2.0
    frequency_hz: float = 0.1
    offset: float = 2.0
    type: str = "open_loop"

    KEYS = ["type", "q0_deg", "tau_des"]
    TAU_KEYS = ["amplitude", "frequency_hz", "offset"]

    @property
    def q0(self) -> float:
        return math.radians(self.q0_deg)

    @classmethod
    def from_dict(cls, d: Mapping, source: str) -> "OpenLoopSpec":
        _check_keys(source, "controller.", d, cls.KEYS, cls.KEYS)
        td = d["tau_des"]
        _check_keys(source, "controller.tau_des.", td, cls.TAU_KEYS, cls.TAU_KEYS)
        return cls(q0_deg=_num(source, "controller.q0_deg", d["q0_deg"], lo=-360.0, hi=360.0),
                   amplitude=_num(source, "controller.tau_des.amplitude", td["amplitude"]),
                   frequency_hz=_num(source, "controller.tau_des.frequency_hz", td["frequency_hz"], positive=True),
                   offset=_num(source, "controller.tau_des.offset", td["offset"]))


TASK_KEYS = ["q_deg", "move_s", "hold_s", "kp", "kd", "ki", "activation_s", "delay_s", "max_torque"]


def task_from_dict(d: Any, source: str) -> TrackingTask:
    """The ``task`` section of a ``human: track`` scenario (defaults: :class:`TrackingTask`)."""
    if not isinstance(d, Mapping):
        raise ConfigError(source, "task", f"must be a mapping with keys {', '.join(TASK_KEYS)}, got {d!r}")
    _check_keys(source, "task.", d, TASK_KEYS, [])
    base = TrackingTask()
    qd = d.get("q_deg", list(base.q_deg))
    if not isinstance(qd, (list, tuple)) or len(qd) != 2:
        raise ConfigError(source, "task.q_deg", f"must be a list of 2 angles [deg], got {qd!r}")
    q = tuple(_num(source, "task.q_deg", v, lo=-180.0, hi=180.0) for v in qd)

    def pos(key, lo=0.0, hi=1e4, strict=True):
        v = d.get(key, getattr(base, key))
        v = _num(source, f"task.{key}", v, lo=lo, hi=hi)
        if strict and v <= 0:
            raise ConfigError(source, f"task.{key}", f"must be > 0, got {v}")
        return v
    return TrackingTask(q_deg=q, move_s=pos("move_s", hi=3600.0), hold_s=pos("hold_s", hi=3600.0, strict=False),
                        kp=pos("kp", strict=False), kd=pos("kd", strict=False), ki=pos("ki", strict=False),
                        activation_s=pos("activation_s", hi=1.0, strict=False), delay_s=pos("delay_s", hi=0.5,
                                                                                           strict=False),
                        max_torque=pos("max_torque", hi=1000.0))


@dataclass(frozen=True)
class Scenario:
    """One simulated experiment: training phase then estimation phase."""

    source: str
    model_path: Path
    nominal: ModelConfig
    plant: PlantSpec
    human: str
    controller: PIDSpec | OpenLoopSpec
    training_samples: int
    estimation_samples: int
    seed: int = 0
    description: str = ""
    tau_h_act_rate: float | None = None     # declared |dτ_h,act/dt| bound [N m/s] (None: not declared)
    task: TrackingTask | None = None        # human: track — the subject's task

    TOP_KEYS = ["description", "model", "seed", "human", "tau_h_act_rate", "task", "plant", "controller", "phases"]
    REQUIRED = ["model", "human", "plant", "controller", "phases"]

    def true_config(self) -> ModelConfig:
        """Nominal model + hidden effects (and, for a ``model.urdf``, the links' masses and lengths
        scaled by ``plant.links``): the configuration of the true plant."""
        cfg = self.nominal.with_effects(tuple(self.nominal.model.effects) + tuple(self.plant.effects))
        if self.plant.link_mass or self.plant.link_length:
            rigid = cfg.model.rigid.scaled(mass=dict(self.plant.link_mass), length=dict(self.plant.link_length))
            cfg = dataclasses.replace(cfg, model=cfg.model.with_rigid(rigid))
        return cfg

    def declared(self, cfg: ModelConfig) -> ModelConfig:
        """``cfg`` with what the scenario declares to the estimator: ``estimator.tau_h_act_rate``
        when the scenario gives one (the Theorem-1 bound's human-torque rate, docs/bounds.md §6)."""
        if self.tau_h_act_rate is None:
            return cfg
        return dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator,
                                                                      tau_h_act_rate=self.tau_h_act_rate))

    @classmethod
    def from_dict(cls, d: Any, source: str, base_dir: Path | None = None) -> "Scenario":
        _check_keys(source, "", d, cls.TOP_KEYS, cls.REQUIRED)
        base_dir = Path(source).parent if base_dir is None else base_dir
        mp = d["model"]
        if not isinstance(mp, str) or not mp:
            raise ConfigError(source, "model", f"must be the path of a model YAML (e.g. ../exo_1dof.yaml), got {mp!r}")
        model_path = (base_dir / mp) if not Path(mp).is_absolute() else Path(mp)
        if not model_path.is_file():
            raise ConfigError(source, "model", f"model config {str(model_path)!r} not found "
                                               "(path is relative to the scenario file)")
        nominal = load_config(model_path)
        human = _choice(source, "human", d["human"], HUMAN_MODES)
        ctrl = d["controller"]
        if not isinstance(ctrl, Mapping):
            raise ConfigError(source, "controller", f"must be a mapping with a type ({', '.join(CONTROLLER_TYPES)})")
        typ = ctrl.get("type")
        if nominal.joints > 1:        # per-joint values (io.scenario_joints)
            controller = joints_controller(ctrl, nominal.joints, source)
            check_human(source, human, controller)
            if "task" in d:
                raise ConfigError(source, "task", "is only allowed with human: track (one joint)")
        elif typ == "pid":
            controller: PIDSpec | OpenLoopSpec = PIDSpec.from_dict(ctrl, source)
        elif typ == "open_loop":
            controller = OpenLoopSpec.from_dict(ctrl, source)
        else:
            raise ConfigError(source, "controller.type", f"unknown controller type {typ!r}; "
                                                         f"allowed: {', '.join(CONTROLLER_TYPES)}")
        if nominal.joints > 1:
            pass
        elif human == "resist" and typ != "open_loop":
            raise ConfigError(source, "human", "'resist' (τ_h,act = −τ_des) needs controller.type open_loop; "
                                               "allowed with pid: passive, track")
        if human == "track" and typ != "pid":
            raise ConfigError(source, "human", "'track' needs controller.type pid (it moves the passive arm in "
                                               "the training phase); allowed with open_loop: passive, resist")
        task = None
        if human == "track":
            task = task_from_dict(d.get("task", {}), source)
        elif "task" in d:
            raise ConfigError(source, "task", f"is only allowed with human: track, got human: {human}")
        ph = d["phases"]
        _check_keys(source, "phases.", ph, ["training", "estimation"], ["training", "estimation"])
        samples = {}
        for k in ("training", "estimation"):
            _check_keys(source, f"phases.{k}.", ph[k], ["samples"], ["samples"])
            samples[k] = _int(source, f"phases.{k}.samples", ph[k]["samples"], 2, 10_000_000)
        seed = _int(source, "seed", d.get("seed", 0), 0, 2**32 - 1)
        desc = d.get("description", "")
        if not isinstance(desc, str):
            raise ConfigError(source, "description", f"must be a string, got {desc!r}")
        rate = d.get("tau_h_act_rate")
        if rate is not None:
            rate = _num(source, "tau_h_act_rate", rate, non_negative=True)
        return cls(source=source, model_path=model_path, nominal=nominal,
                   plant=PlantSpec.from_dict(d["plant"], nominal.joints, source,
                                             None if nominal.model.rigid is None else nominal.model.rigid.urdf),
                   human=human, controller=controller, training_samples=samples["training"],
                   estimation_samples=samples["estimation"], seed=seed, description=desc,
                   tau_h_act_rate=rate, task=task)


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a scenario YAML; raises ConfigError naming the key."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(str(p), "<file>", "scenario file not found")
    return Scenario.from_dict(load_yaml(p), source=str(p), base_dir=p.parent)


def make_plant(sc: Scenario, seed: int | None = None) -> Plant:
    """The scenario's true plant at rest at the controller's start angle."""
    try:
        return Plant(sc.true_config(), q0=sc.controller.q0, seed=sc.seed if seed is None else seed,
                     substep_hz=sc.plant.substep_hz, sign_eps=sc.plant.sign_eps,
                     torque_noise=sc.plant.torque_noise)
    except ValueError as e:
        raise ConfigError(sc.source, "plant.substep_hz", str(e)) from None


def task_plant(sc: Scenario, dt: float | None = None, seed: int | None = None) -> tuple[Plant, TrackingSubject]:
    """``human: track``: the plant at rest at the task's first target angle and the subject bound to it.

    At rest the exoskeleton holds what its nominal model knows — the static load torque of
    ``sc.nominal`` at that angle, the torque the assist controller's compensation commands
    there — and the subject's muscles hold the rest of the arm (its feed-forward starts with
    that torque), so the task starts without a jolt.  ``dt``: the subject's step (default the
    scenario's period).  The plant's :attr:`~Plant.hold_torque` is the compensation.
    """
    if sc.task is None:
        raise InputError(f"scenario {sc.source}: human {sc.human!r} has no task (allowed: human: track)")
    n = sc.nominal.joints
    q0 = np.full(n, math.radians(sc.task.q_deg[0]))
    z = np.zeros(n)
    comp = SEAModel.from_config(sc.nominal).load_torque(q0, z, z)
    seed = sc.seed if seed is None else seed
    kw = dict(seed=seed, substep_hz=sc.plant.substep_hz, sign_eps=sc.plant.sign_eps,
              torque_noise=sc.plant.torque_noise)
    try:
        at_rest = Plant(sc.true_config(), q0=q0, **kw)
        tau0 = at_rest.hold_torque - comp           # the subject holds what the compensation does not
        plant = Plant(sc.true_config(), q0=q0, tau_h_act0=tau0, **kw)
    except ValueError as e:
        raise ConfigError(sc.source, "plant.substep_hz", str(e)) from None
    return plant, TrackingSubject(sc.task, plant, dt or sc.nominal.dt, tau0=tau0)


def human_torque(scenario) -> Callable[[float], np.ndarray]:
    """τ_h,act(t) [N m] per joint for the device model's plant time t (open-loop subjects;
    ``human: track`` reacts to the plant: :func:`task_plant`)."""
    n = scenario.nominal.joints
    if scenario.human == "track":
        raise InputError(f"scenario {scenario.source}: human 'track' reacts to the plant; it runs with the "
                         "assist controller (sea-daemon run --device-model/--sim, docs/assist.md)")
    zero = np.zeros(n)
    if scenario.human != "resist":
        return lambda t: zero
    ctrl = scenario.controller
    dt = scenario.nominal.dt
    t_est = scenario.training_samples * dt
    out = np.zeros(n)

    def resist(t: float) -> np.ndarray:
        tp = t - t_est
        # Sec. V-C: the subject resists and holds the arm, τ_h,act = −τ_des (estimation phase only)
        if tp < -1e-9:
            out[:] = 0.0
        elif n > 1:                     # each joint's cosine (io.scenario_joints.JointsOpenLoop)
            for j in range(n):
                out[j] = -cosine_torque(tp, ctrl.amplitude[j], ctrl.frequency_hz[j], ctrl.offset[j])
        else:
            out[:] = -cosine_torque(tp, ctrl.amplitude, ctrl.frequency_hz, ctrl.offset)
        return out
    return resist
