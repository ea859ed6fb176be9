"""n coupled joints from a URDF through the filter and the plant: the 2-DoF shoulder-elbow example
(configs/exo_2dof.yaml) — F_nom, f_nom and G_μ = I_μ M⁻¹(q) of the filter against finite
differences and the model, the coupled plant at rest, and the GP-AKF with a LoG-GP per joint
estimating a human torque on both joints of a simulated arm whose masses, lengths and friction
differ from the nominal model."""
import dataclasses
import math

import numpy as np
import pytest

from sea_daemon.core.effects import effect_from_dict
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.model import SEAModel
from sea_daemon.core.model_core import RigidTables
from sea_daemon.core.sim.plant import Plant
from sea_daemon.io.configfile import load_config
from tests._paths import repo_root

RATE = 100.0


@pytest.fixture(scope="module")
def cfg():
    return load_config(repo_root() / "configs" / "exo_2dof.yaml")


def effects(cfg, specs):
    return tuple(effect_from_dict(d, cfg.joints, "test", f"effects[{i}]") for i, d in enumerate(specs))


HIDDEN = [{"type": "viscous", "side": "load", "b": 0.4, "joint": 1},
          {"type": "viscous", "side": "load", "b": 0.25, "joint": 2},
          {"type": "coulomb", "side": "load", "F_c": 0.3, "joint": 1},
          {"type": "coulomb", "side": "load", "F_c": 0.2, "joint": 2}]


def fd_jacobian(f, x, h=1e-6):
    return np.stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(len(x))], axis=1)


@pytest.mark.parametrize("declared", [[], HIDDEN + [{"type": "viscous", "side": "motor", "b": 0.1, "joint": 2}]])
def test_filter_dynamics_of_the_urdf_model(cfg, declared):
    """The filter's tables: f_nom, F_nom (vs central differences, the ∂M/∂q term included) and
    G_μ = I_μ M(q)⁻¹ at the linearisation point; the model's M and M⁻¹ at a state (SEAModel.at)."""
    model = SEAModel(cfg.model.with_effects(effects(cfg, declared)), sign_eps=0.5)
    n, d = 2, 10
    G_mu = np.zeros((d, n))
    tables = RigidTables(model, G_mu)
    x = np.array([0.6, 1.1, 0.02, -0.01, 0.8, -0.5, 0.05, 0.02, 1.5, -0.7])
    u = np.array([12.0, 3.0])
    A, xdot = np.empty((d, d)), np.empty(d)
    tables.f_and_F(x, u, A, xdot)
    np.testing.assert_allclose(xdot, model.f_nom(x, u), rtol=1e-12)
    np.testing.assert_allclose(A, model.F_nom(x, u), rtol=1e-12)
    np.testing.assert_allclose(A, fd_jacobian(lambda v: model.f_nom(v, u), x), rtol=1e-5, atol=1e-5)
    q = x[:n] + x[n:2 * n]
    M = model.rigid.mass_matrix(q)
    np.testing.assert_allclose(G_mu[3 * n:4 * n], np.linalg.inv(M), rtol=1e-10)
    assert not np.any(G_mu[:3 * n]) and not np.any(G_mu[4 * n:])
    model.at(x)
    np.testing.assert_allclose(model.M, M, rtol=1e-12)
    np.testing.assert_allclose(model.Minv, np.linalg.inv(M), rtol=1e-10)
    # θ̈_s = q̈ − θ̈_m with q̈ from eq:unknwn_load: M(q) q̈ = τ_h,act − C(q, q̇) q̇ − g(q) − Σ_load e − τ_s
    ddth_m, ddq = model.accelerations(x, u)
    tau_s = model.spring_torque(x[n:2 * n], x[3 * n:4 * n])
    lo, _, _ = model.load_effects_torque(q, x[2 * n:3 * n] + x[3 * n:4 * n])
    rhs = x[4 * n:] - model.rigid.bias(q, x[2 * n:3 * n] + x[3 * n:4 * n]) - lo - tau_s
    np.testing.assert_allclose(ddq, np.linalg.solve(M, rhs), rtol=1e-10)
    np.testing.assert_allclose(xdot[3 * n:4 * n], ddq - ddth_m, rtol=1e-12)


def test_coupled_plant_holds_its_static_equilibrium(cfg):
    """The plant of a URDF model starts at rest with the motors holding the arm (its g(q)) and stays."""
    plant = Plant(cfg, q0=np.array([0.9, 1.2]), seed=0, torque_noise=0.0)
    np.testing.assert_allclose(-plant.hold_torque, -cfg.model.rigid.gravity(np.array([0.9, 1.2])), rtol=1e-9)
    for _ in range(50):
        plant.step(plant.hold_torque, 0.01)
    np.testing.assert_allclose(plant.q, [0.9, 1.2], atol=1e-9)


def reference(t):
    """The arm's motion, within the URDF's joint ranges (shoulder [−0.52, 2.09], elbow [0, 2.27] rad:
    shoulder 0.6 ± 1.05, elbow 1.2 ± 1.05), clear of the simulated arm's end stops."""
    r = min(1.0, t)
    return np.array([0.6, 1.2]) + r * (0.5 * np.sin(2 * np.pi * np.array([0.23, 0.37]) * t)
                                       + 0.3 * (np.sin(2 * np.pi * np.array([0.61, 0.47]) * t + 1.0) - math.sin(1.0)))


def human(t):
    return np.array([1.5 * math.sin(2 * np.pi * 0.3 * t) + 0.5, 1.0 * math.sin(2 * np.pi * 0.45 * t + 0.7)])


def session(true_cfg, nominal, duration, subject, seed):
    """The arm tracks :func:`reference` by a collocated PD on the motors to θ_m,ref = q_ref − K_s⁻¹ g(q_ref)
    plus the nominal model's gravity torque; ``subject(t)`` the human torque (None: passive)."""
    dt = 1.0 / RATE
    plant = Plant(true_cfg, q0=reference(0.0), seed=seed, sign_eps=0.02)
    Ks = np.diag(nominal.K_s)
    N = int(duration * RATE)
    out = np.zeros((4, N, 2))
    u, tau_h, th_prev = plant.hold_torque.copy(), np.zeros(2), None
    for k in range(N):
        t = k * dt
        if k:
            plant.step(u, dt, tau_h)
        q, th = plant.measure()
        dth = np.zeros(2) if th_prev is None else (th - th_prev) / dt
        th_prev = th
        qr = reference(t)
        dqr = (reference(t + 1e-4) - reference(t - 1e-4)) / 2e-4
        g = nominal.C(qr)
        u = np.clip(g + np.array([150.0, 80.0]) * (qr - g / Ks - th) + np.array([8.0, 4.0]) * (dqr - dth), -40, 40)
        tau_h = np.zeros(2) if subject is None else subject(t)
        out[:, k] = q, th, u, tau_h
    return out


def estimate(est, data):
    q, th, u, tau = data
    est.reset(q[0], th[0], u[0])
    E, B = np.zeros_like(tau), np.zeros_like(tau)
    for k in range(1, len(q)):
        e = est.update(q[k], th[k], u[k], 1.0 / RATE)
        E[k], B[k] = e.tau_h_act_hat, e.tau_h_act_bound
    return E, B


def trained_gp(cfg, true_cfg, train_s, test_s):
    """A GP-AKF of ``cfg`` trained on a passive session of ``true_cfg`` (seed 1, ``train_s`` seconds),
    learning then off, and a session with :func:`human` (seed 2, ``test_s`` seconds)."""
    nominal = SEAModel.from_config(cfg)
    train = session(true_cfg, nominal, train_s, None, 1)
    test = session(true_cfg, nominal, test_s, human, 2)
    gp = make_estimator("gp-akf", cfg, bound=False)
    estimate(gp, train)
    gp.learning = False
    return gp, test


def test_gpakf_estimates_the_human_torque_on_both_joints(cfg):
    """The true arm: the wearer's upper arm 25 % heavier, forearm 20 % lighter and 10 % longer, the
    exoskeleton's forearm 10 % heavier, viscous and Coulomb friction on both joints — none of it in
    the nominal model.  After 20 s of passive training (one LoG-GP per joint on z ∈ R⁶), on 12 s with
    a human torque on both joints: the GP-AKF within 0.35 N m (shoulder) and 0.2 N m (elbow) RMS of
    the truth (1.2 and 0.7 N m RMS), under 0.6 × the AKF on the nominal model, and its Theorem-1 bound
    per joint covering ≥ 95 % of the samples."""
    rigid = cfg.model.rigid.scaled(mass={"human_upper_arm": 1.25, "human_forearm_hand": 0.8, "exo_forearm": 1.1},
                                   length={"human_forearm_hand": 1.1})
    true_cfg = dataclasses.replace(cfg, model=cfg.model.with_rigid(rigid).with_effects(effects(cfg, HIDDEN)))
    gp, test = trained_gp(cfg, true_cfg, 20.0, 12.0)
    assert gp.n_learned > 1500
    skip = int(2 * RATE)
    truth = test[3][skip:]

    def rmse(E):
        return np.sqrt(np.mean((E[skip:] - truth) ** 2, axis=0))
    E_akf, _ = estimate(make_estimator("akf", cfg, bound=False), test)
    E_gp, B_gp = estimate(make_estimator("gp-akf", cfg, residual=gp.gp, learning=False), test)
    r_akf, r_gp = rmse(E_akf), rmse(E_gp)
    assert np.all(r_gp <= [0.35, 0.2]), (r_gp, r_akf)
    assert np.all(r_gp < 0.6 * r_akf), (r_gp, r_akf)
    covered = np.mean(np.abs(E_gp[skip:] - truth) <= B_gp[skip:], axis=0)
    assert np.all(covered >= 0.95), covered


def test_linearisation_error_box_of_the_urdf_model(cfg):
    """The bound's sampled box |f_nom(x) − f_nom(x0) − A0 (x − x0)| of the URDF model (one ABA per
    point, the rest compiled) equals the plain evaluation with the model's f_nom, and is 0 for an
    exactly linear drift (points along which nothing non-linear moves)."""
    model = SEAModel(cfg.model.with_effects(effects(cfg, HIDDEN)), sign_eps=0.5)
    tables = RigidTables(model, np.zeros((10, 2)))
    rng = np.random.default_rng(5)
    x0 = np.array([0.6, 1.1, 0.02, -0.01, 0.8, -0.5, 0.05, 0.02, 1.5, -0.7])
    u = np.array([12.0, 3.0])
    A0, xdot = np.empty((10, 10)), np.empty(10)
    tables.f_and_F(x0, u, A0, xdot)
    X = x0 + 0.05 * rng.normal(size=(30, 10))
    plain = np.zeros(10)
    for x in X:
        plain = np.maximum(plain, np.abs(model.f_nom(x, u) - model.f_nom(x0, u) - A0 @ (x - x0)))
    np.testing.assert_allclose(tables.lin_error_box(X, u, x0, A0), plain, rtol=1e-9, atol=1e-12)
    assert np.all(plain[6:8] > 1e-4)                # the θ̈_s rows: M(q), C(q, q̇) are not linear
    along_tau = x0 + np.outer(np.linspace(-1, 1, 5), np.eye(10)[8])   # τ_h,act enters linearly
    assert not np.any(tables.lin_error_box(along_tau, u, x0, A0))


def test_a_session_of_the_two_joint_arm(cfg):
    """core.sim.session for n joints: a per-joint reference tracked by the session's PID, the
    subject's (2,) torque logged per joint at the sample times."""
    from sea_daemon.core.excitation import PerJoint
    from sea_daemon.core.sim.session import SineReference, run_session
    ref = PerJoint((SineReference(0.6, (0.4,), (0.3,), (0.0,)), SineReference(0.8, (0.4,), (0.4,), (0.0,))))
    log = run_session(cfg, 6.0, reference=ref, human=human, seed=1)
    assert log.q.shape == (600, 2) and log.tau_h_act.shape == (600, 2)
    np.testing.assert_allclose(log.tau_h_act[:-1], [human(t) for t in log.t[:-1]], rtol=1e-12)
    q_ref = np.array([ref.reference(t)[0] for t in log.t])
    assert np.max(np.abs(log.q[200:] - q_ref[200:])) < 0.15      # tracked (the human pushes, the PID holds)


def test_the_bound_takes_m_at_its_own_step(cfg):
    """The Theorem-1 bound of a URDF model reads M(q̂_{k−1}) of the record it gets, not what the
    model last held (a bound worker's copy of the filter never runs the filter's step)."""
    est = make_estimator("akf", cfg, bound=True)
    data = session(cfg, SEAModel.from_config(cfg), 0.5, None, 3)
    q, th, u, _ = data
    est.reset(q[0], th[0], u[0])
    for k in range(1, 20):
        est.update(q[k], th[k], u[k], 1.0 / RATE)
    x_prev = est.record.x_prev.copy()
    est.model.M[:] = np.eye(2)                      # stale, as in a copy that did not step
    est.bound.step(est.est, est.record)
    np.testing.assert_allclose(est.model.M, est.model.rigid.mass_matrix(x_prev[:2] + x_prev[2:4]), rtol=1e-12)


def test_the_multi_joint_excitation_covers_the_combinations_of_the_working_ranges():
    """Each joint within its working range, speed and acceleration limits; the (q₁, q₂) pairs over
    the whole 4 × 4 grid of the two ranges (the coupled terms need the combinations); seeded."""
    from sea_daemon.core.excitation import WorkingRange, excitation_joints
    ranges = (WorkingRange(-0.3, 1.6, v_max=1.5, a_max=10.0), WorkingRange(0.1, 2.0, v_max=2.0, a_max=12.0))
    ref = excitation_joints(ranges, 90.0, seed=4)
    assert ref.duration >= 90.0
    t = np.arange(0.0, ref.duration, 0.01)
    Q, V, A = (np.array(c) for c in zip(*(ref.reference(s) for s in t)))
    for j, wr in enumerate(ranges):
        assert wr.q_min - 1e-9 <= Q[:, j].min() and Q[:, j].max() <= wr.q_max + 1e-9
        assert np.abs(V[:, j]).max() <= wr.v_max + 1e-9 and np.abs(A[:, j]).max() <= wr.a_max + 1e-6
    cells = {(int(4 * (q1 + 0.3) / 1.9 - 1e-9), int(4 * (q2 - 0.1) / 1.9 - 1e-9)) for q1, q2 in Q}
    assert len(cells) == 16
    again = excitation_joints(ranges, 90.0, seed=4).reference(37.3)
    np.testing.assert_array_equal(again[0], ref.reference(37.3)[0])
    assert not np.array_equal(excitation_joints(ranges, 90.0, seed=5).reference(37.3)[0], again[0])
