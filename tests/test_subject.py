"""The simulated subject of a tracking task and the ``human: track`` scenario."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from sea_daemon.core.sim.subject import TrackingSubject, TrackingTask
from sea_daemon.errors import ConfigError, InputError
from _paths import repo_root
from sea_daemon.io.scenario import human_torque, load_scenario, task_plant

TRACK = repo_root() / "configs" / "scenarios" / "assist_track.yaml"


def test_target_holds_then_moves_back_and_forth():
    task = TrackingTask(q_deg=(20, 70), move_s=2.5, hold_s=2.0)
    a, b = math.radians(20), math.radians(70)
    assert task.target(-1.0) == (a, 0.0) and task.target(1.9) == (a, 0.0)
    q, dq = task.target(2.0 + 1.25)                          # mid-move: half-way, fastest
    assert q == pytest.approx((a + b) / 2) and dq == pytest.approx(1.875 * (b - a) / 2.5)
    assert task.target(5.0) == pytest.approx((b, 0.0))
    assert task.target(4.5 + 2.0 + 1.25)[0] == pytest.approx((a + b) / 2)
    assert task.target(4.5 + 2.0 + 1.25)[1] < 0
    assert task.target(9.0 + 1.0) == pytest.approx((a, 0.0))  # periodic


class StillPlant:
    def __init__(self, q=0.3):
        self.q, self.dq = np.array([q]), np.array([0.0])


def test_subject_steps_once_per_time_and_resists_an_error():
    task = TrackingTask(q_deg=(math.degrees(0.3), 60), hold_s=100.0, kp=10.0, kd=0.0, ki=0.0, activation_s=0.0,
                        delay_s=0.0)
    p = StillPlant(0.3)
    s = TrackingSubject(task, p, 0.01, tau0=1.0)
    assert s(0.0)[0] == pytest.approx(1.0)                    # starts holding with tau0
    p.q[:] = 0.2                                              # the arm sinks by 0.1 rad
    assert s(0.01)[0] == pytest.approx(1.0 + 10 * 0.1)        # pushes back
    p.q[:] = 0.0
    assert s(0.01)[0] == pytest.approx(2.0)                   # same t: no second update


def test_delay_and_activation():
    task = TrackingTask(q_deg=(0.0, 60), hold_s=100.0, kp=10.0, kd=0.0, ki=0.0, activation_s=0.04, delay_s=0.03)
    p = StillPlant(0.0)
    s = TrackingSubject(task, p, 0.01, tau0=0.0)
    assert s.delay_steps == 3
    s(0.0)
    p.q[:] = -0.1
    out = [float(s(0.01 * k)[0]) for k in range(1, 10)]
    assert out[:2] == [0.0, 0.0]                              # the sensed angle is 30 ms old
    assert 0 < out[3] < 1.0 and out[-1] < 1.0 and out[-1] > out[3]   # activation: first order towards 1 N m


def test_task_plant_starts_at_rest_held_by_compensation_and_subject():
    from sea_daemon.core.model import SEAModel
    sc = load_scenario(TRACK)
    plant, subject = task_plant(sc, seed=0)
    q0 = math.radians(sc.task.q_deg[0])
    comp = SEAModel.from_config(sc.nominal).load_torque(np.array([q0]), np.zeros(1), np.zeros(1))
    assert plant.hold_torque == pytest.approx(comp, abs=1e-9)
    assert subject.tau[0] == pytest.approx(-2.9, abs=0.2)    # the hypertonic elbow pulls up at 20 deg
    plant.noise_std = 0.0
    for k in range(150):                                      # the first hold: nothing moves
        t = plant.t
        plant.step(comp, 0.01, subject(t))
    assert plant.q[0] == pytest.approx(q0, abs=math.radians(0.2))


def test_track_scenario_validation(tmp_path):
    d = yaml.safe_load(TRACK.read_text())
    d["model"] = str((TRACK.parent / d["model"]).resolve())

    def load(**changes):
        dd = {**d, **changes}
        p = tmp_path / "s.yaml"
        p.write_text(yaml.safe_dump(dd))
        return load_scenario(p)
    assert load().task.q_deg == (20.0, 70.0)
    with pytest.raises(ConfigError, match="task.move_s: must be > 0"):
        load(task={"move_s": 0})
    with pytest.raises(ConfigError, match="task.kpp"):
        load(task={"kpp": 1})
    with pytest.raises(ConfigError, match="task.q_deg: must be a list of 2 angles"):
        load(task={"q_deg": [10]})
    with pytest.raises(ConfigError, match="task: is only allowed with human: track"):
        load(human="passive")
    with pytest.raises(ConfigError, match="'track' needs controller.type pid"):
        load(controller={"type": "open_loop", "q0_deg": 10, "tau_des": {"amplitude": 1, "frequency_hz": 0.1,
                                                                          "offset": 1}})
    with pytest.raises(InputError, match="reacts to the plant"):
        human_torque(load())
