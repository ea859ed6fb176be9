"""The Theorem-1 bound of a URDF model (configs/exo_2dof.yaml): the rigid body's linearisation-error
box over the projection W·C of the set on w = (q, q̇, τ), and the compiled bound step for it."""
import dataclasses

import numpy as np
import pytest

from sea_daemon.core.bounds import rigid_box
from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.model import SEAModel
from sea_daemon.core.model_core import RigidTables
from sea_daemon.io.configfile import load_config
from tests._paths import repo_root
from tests.test_rigid_filter import estimate, trained_gp


@pytest.fixture(scope="module")
def cfg():
    return load_config(repo_root() / "configs" / "exo_2dof.yaml")


def test_rigid_box_holds_the_linearisation_error_over_the_projected_set(cfg):
    """ε(x) = f_nom(x) − f_nom(x̂) − F_nom (x − x̂) of the URDF model is a function of w = W x: it is 0
    along directions W does not see and sits in the θ̈_s rows; its box over the projected set
    (zonotope ⊕ E(0, χ²_6 P)) holds |ε| at random points of that set (seeded)."""
    model = SEAModel.from_config(cfg)
    rng = np.random.default_rng(7)
    x0, u = np.array([0.6, 1.1, 0.002, -0.001, 0.8, -0.5, 0.01, 0.02, 1.5, -0.7]), np.array([12.0, 3.0])
    A0 = np.empty((10, 10))
    RigidTables(model, np.zeros((10, 2))).f_and_F(x0, u, A0, np.empty(10))     # the filter's F_nom at x̂
    W = rigid_box.rigid_map(model)
    null = np.linalg.svd(W)[2][6:]                        # directions W does not see
    eps = lambda x: model.f_nom(x, u) - model.f_nom(x0, u) - A0 @ (x - x0)
    for v in null:
        assert np.max(np.abs(eps(x0 + 0.5 * v))) < 1e-9
    G = np.diag([0.0, 0.0, 0.0, 0.0, 0.03, 0.02, 0.0, 0.0, 0.5, 0.3])[:, [4, 5, 8, 9]]
    L = rng.normal(size=(10, 10)) * 0.01
    P = L @ L.T
    s = chi2_quantile(0.975, 6)
    rb = rigid_box.RigidBox(model, np.eye(6)[:2], 0.25)
    b = np.zeros(10)
    rb.box(x0, G, P, s, b)
    assert np.all(b[[0, 1, 2, 3, 4, 5, 8, 9]] == 0) and np.all(b[6:8] > 0)
    Lp = np.linalg.cholesky(P + 1e-15 * np.eye(10))
    worst = np.zeros(10)
    for _ in range(400):
        xi = rng.uniform(-1, 1, G.shape[1])
        g = rng.normal(size=10)
        g *= np.sqrt(s) * rng.uniform() ** 0.1 / np.linalg.norm(g)       # inside E(0, s P), often near its edge
        worst = np.maximum(worst, np.abs(eps(x0 + G @ xi + Lp @ g)))
    assert np.all(worst[6:8] <= b[6:8]) and np.max(worst[[0, 1, 2, 3, 4, 5, 8, 9]]) < 1e-9, (worst, b)


def test_compiled_bound_step_of_a_urdf_model_is_the_python_step(cfg):
    """A GP-AKF of the 2-DoF arm with frozen LoG-GPs runs its Theorem-1 bound on the compiled path
    (bound_core.bound_step with the rigid body's box) and publishes the Python step's ρ_k (to
    rounding), the box and the GP error included."""
    rigid = cfg.model.rigid.scaled(mass={"human_upper_arm": 1.25})
    true_cfg = dataclasses.replace(cfg, model=cfg.model.with_rigid(rigid))
    gp, test = trained_gp(cfg, true_cfg, 4.0, 1.5)
    out = {}
    for compiled in (True, False):
        est = make_estimator("gp-akf", cfg, residual=gp.gp, learning=False)
        est.bound.compiled = compiled
        _, B = estimate(est, test)
        if compiled:
            assert est.bound._compiled_pack() is not None           # the compiled path ran
        out[compiled] = (B, est.bound.lin_err_.copy(), est.bound.eta_.copy())
    np.testing.assert_allclose(out[True][0], out[False][0], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(out[True][1], out[False][1], rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(out[True][2], out[False][2], rtol=1e-7)
    assert np.all(out[True][1][6:8] > 0) and np.all(out[True][0][50:] > 0)


def test_bench_latency_times_the_two_joint_gpakf_and_its_bound(capsys):
    """`bench latency --config configs/exo_2dof.yaml` times the 2-joint GP-AKF with frozen LoG-GPs
    without and with its Theorem-1 bound (the compiled step of a URDF model)."""
    from sea_daemon.apps import cli
    code = cli.main(["bench", "latency", "--config", str(repo_root() / "configs" / "exo_2dof.yaml"), "--seconds", "1.5",
                     "--repeat", "1", "--estimators", "gp-akf-frozen,gp-akf-bound"])
    out = capsys.readouterr().out
    assert code == 0
    assert "2 joint(s)" in out
    assert "gp-akf-frozen: per step median" in out and "gp-akf-bound: per step median" in out
    assert "Theorem-1 bound on" in out
