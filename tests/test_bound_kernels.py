"""The bound worker's per-sample kernels computed in batches give what they gave point by point:
the frozen LoG-GPs' predictions at the bound's points (`pack.gp_points`, leaf by leaf for all the
points that reach it) and the rigid body's q̈ at the points of its box (`RigidBody.forward_columns`,
one batched ABA call)."""
import numpy as np
import pytest

from sea_daemon.core.bounds import rigid_box
from sea_daemon.core.bounds.ellipsoid import chi2_quantile
from sea_daemon.core.bounds.setmember import unit_directions
from sea_daemon.core.gp.loggp import LoGGP
from sea_daemon.core.gp.pack import GPPack, gp_points
from sea_daemon.core.model import SEAModel
from sea_daemon.io.configfile import load_config
from tests._paths import repo_root


def _gps(seed: int):
    """Two LoG-GPs on z ∈ R⁴ with many overlapping leaves of up to 40 points, clip_leaf_mean on."""
    rng = np.random.default_rng(seed)
    gps = []
    for _ in range(2):
        g = LoGGP(4, max_points=40, overlap=0.2, lengthscales=[0.5, 0.7, 1.0, 0.8], clip_leaf_mean=True)
        for _ in range(400):
            z = rng.uniform(-2.0, 2.0, 4)
            g.update(z, np.sin(z[0]) + 0.3 * z[1] * z[2] + 0.01 * rng.standard_normal())
        gps.append(g)
    return gps, rng


@pytest.mark.parametrize("local", [False, True])
def test_gp_points_of_many_rows_are_their_predictions_row_by_row(local):
    """27 rows (leaves reached by several rows at once, four at a time and the rest one by one; rows
    outside the data, clipped) give bit for bit what each row gives alone, and the LoG-GPs' own
    predict_many to rounding."""
    gps, rng = _gps(3)
    r = [{k: 0.01 * (1 + k % 3) for k in g.leaves()} for g in gps] if local else None
    pack = GPPack(gps, r).arrays()
    Z = rng.uniform(-2.5, 2.5, (27, 4))
    Z[:12] = Z[0] + 0.05 * rng.standard_normal((12, 4))      # many rows in the same leaves
    out = [np.empty((27, 2)) for _ in range(3)]
    gp_points(Z, local, 0.5 if local else 0.0, pack, *out)
    one = [np.empty((27, 2)) for _ in range(3)]
    for q in range(27):
        row = [np.empty((1, 2)) for _ in range(3)]
        gp_points(Z[q:q + 1], local, 0.5 if local else 0.0, pack, *row)
        for a, b in zip(one, row):
            a[q] = b[0]
    for a, b in zip(out, one):
        assert np.array_equal(a, b)
    if not local:
        for j, g in enumerate(gps):
            mu, var = g.predict_many(Z)
            assert np.allclose(out[0][:, j], mu, rtol=1e-12, atol=1e-12)
            assert np.allclose(out[1][:, j], np.sqrt(var), rtol=1e-12, atol=1e-12)


@pytest.fixture(scope="module")
def model():
    return SEAModel.from_config(load_config(repo_root() / "configs" / "exo_2dof.yaml"))


def test_forward_columns_is_the_aba_at_each_column(model):
    """RigidBody.forward_columns (one batched call) is RigidBody.forward at every column, to rounding."""
    body = model.rigid
    rng = np.random.default_rng(11)
    Q, DQ, TAU = rng.uniform(-1.5, 1.5, (2, 33)), rng.normal(size=(2, 33)), 10.0 * rng.normal(size=(2, 33))
    out = np.empty((2, 33), order="F")
    got = body.forward_columns(Q, DQ, TAU, out)
    assert got is out
    ref = np.array([body.forward(Q[:, i], DQ[:, i], TAU[:, i]) for i in range(33)]).T
    assert np.allclose(out, ref, rtol=1e-13, atol=1e-12 * np.max(np.abs(ref)))


def test_rigid_box_with_the_batched_aba_is_the_box_point_by_point(model):
    """The rigid body's box from the batched ABA equals the box from Pinocchio's ABA at each point
    (forward_many) to rounding of q̈."""
    rng = np.random.default_rng(5)
    x0 = np.array([0.6, 1.1, 0.002, -0.001, 0.8, -0.5, 0.01, 0.02, 1.5, -0.7])
    G = 0.05 * rng.normal(size=(10, 30))
    L = rng.normal(size=(10, 10)) * 0.01
    P = L @ L.T
    s = chi2_quantile(0.975, 6)
    rb = rigid_box.RigidBox(model, unit_directions(6, 2, 0), 0.25)
    b = np.zeros(10)
    rb.box(x0, G, P, s, b)
    Wp = rigid_box.rigid_points(G, x0, P, rb.W, s, rb.U)
    ddq = model.rigid.forward_many(Wp[:, :2], Wp[:, 2:4], Wp[:, 4:])
    _, dq_q, dq_v, Minv = model.rigid.forward_derivatives(Wp[0, :2], Wp[0, 2:4], Wp[0, 4:])
    ref = np.zeros(10)
    rigid_box.rigid_error_box(Wp, ddq, np.hstack([dq_q, dq_v, Minv]), 0.25, ref)
    assert np.all(b[6:8] > 0)
    assert np.allclose(b, ref, rtol=0.0, atol=1e-11 * np.max(np.abs(ddq)))
