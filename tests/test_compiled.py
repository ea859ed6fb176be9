"""The compiled numerics (numba): small dense linear algebra against scipy/numpy, the cache
fallback, and no compilation after an estimator is constructed (warm before the first step)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm as scipy_expm
from scipy.linalg.lapack import dpotrf

from sea_daemon.core import jit as _jit
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.core.linalg import cho_solve, cholesky, expm, is_pd, lu_solve


@pytest.fixture(scope="module")
def cfg():
    return load_config(default_config_path())


def _rand(rng, n, norm1):
    A = rng.standard_normal((n, n))
    return A * (norm1 / np.abs(A).sum(axis=0).max())


@pytest.mark.parametrize("norm1", [1e-8, 1e-2, 0.2, 0.9, 2.0, 5.0, 20.0])
def test_expm_matches_scipy(norm1):
    # every Padé degree (3, 5, 7, 9) and scaling and squaring (13 with s > 0)
    rng = np.random.default_rng(1)
    out = np.empty((7, 7))
    for n in (1, 3, 7):
        for _ in range(5):
            A = _rand(rng, n, norm1)
            o = out[:n, :n].copy()
            expm(A, o)
            ref = scipy_expm(A)
            # both are Higham's scaling and squaring; they differ by rounding (amplified by the
            # squarings for large norms)
            tol = 1e-14 if norm1 <= 2.0 else 1e-11
            assert np.abs(o - ref).max() <= tol * np.abs(ref).max()


def test_expm_on_the_filters_local_linearisation_matrix(cfg):
    # the matrix the AKF exponentiates every step (‖·‖₁ ≈ 37 at 100 Hz): [[A, f, G], 0]·dt
    from sea_daemon.core.estimators import AKF
    a = AKF(cfg)
    a.reset(np.zeros(1), np.zeros(1), np.zeros(1))
    for k in range(1, 30):
        a.update([0.01 * k], [0.009 * k], [0.5])
    ref = scipy_expm(a._aug)
    out = np.empty_like(a._aug)
    expm(a._aug.copy(), out)
    assert np.abs(out - ref).max() <= 1e-12 * np.abs(ref).max()
    assert np.allclose(a.F_k, ref[:5, :5], rtol=1e-12, atol=1e-15)


def test_cholesky_and_solve_match_lapack():
    rng = np.random.default_rng(2)
    B = rng.standard_normal((5, 5))
    S = B @ B.T + 0.1 * np.eye(5)
    L = np.zeros((5, 5))
    assert cholesky(S, L) == 0
    assert np.allclose(L, np.linalg.cholesky(S), rtol=1e-13, atol=1e-15)
    X = rng.standard_normal((5, 3))
    Y = X.copy()
    cho_solve(L, Y)
    assert np.allclose(Y, np.linalg.solve(S, X), rtol=1e-10)
    # not positive definite: the same pivot as LAPACK dpotrf
    S2 = S.copy()
    S2[3, 3] = -1.0
    assert is_pd(S2) == dpotrf(S2, lower=1)[1] == 4
    S2[0, 0] = np.nan
    assert is_pd(S2) == 1


def test_lu_solve_matches_numpy():
    rng = np.random.default_rng(3)
    M = rng.standard_normal((6, 6))
    X = rng.standard_normal((6, 2))
    Y = X.copy()
    assert lu_solve(M.copy(), Y) == 0
    assert np.allclose(Y, np.linalg.solve(M, X), rtol=1e-10)
    assert lu_solve(np.zeros((2, 2)), np.ones((2, 1))) == 1


def test_no_writable_cache_falls_back_to_in_memory_compilation(monkeypatch):
    from numba.core.caching import NullCache
    # no locator finds a writable directory: numba raises "cannot cache function ...: no
    # locator available for file ..."
    monkeypatch.setattr(_jit._KernelCacheImpl, "_locator_classes", [])

    def f(x):
        return 2.0 * x

    g = _jit.njit(f)
    assert g(3.0) == 6.0
    h = _jit.njit(fast=True)(f)
    assert h(1.5) == 3.0
    assert isinstance(g._cache, NullCache) and isinstance(h._cache, NullCache)


def test_kernels_are_cached_with_the_kernel_sources_stamp():
    from sea_daemon.core.linalg import cholesky
    assert isinstance(cholesky._cache, _jit._KernelCache)


def _dispatchers():
    import sea_daemon.core.bounds.akf_bound as ab
    import sea_daemon.core.bounds.bound_core as bc
    import sea_daemon.core.estimators.akf_core as a
    import sea_daemon.core.estimators.gp_hook as gh
    import sea_daemon.core.estimators.gpakf_core as ga
    import sea_daemon.core.estimators.health as h
    import sea_daemon.core.gp.gp_core as g
    import sea_daemon.core.gp.pack as gpk
    import sea_daemon.core.kinematics as k
    import sea_daemon.core.linalg as s
    from numba.core.registry import CPUDispatcher
    return {f"{m.__name__}.{n}": v for m in (a, h, g, gpk, k, s, ab, bc, gh, ga) for n, v in vars(m).items()
            if isinstance(v, CPUDispatcher)}


def test_gpakf_is_compiled_at_construction_not_in_its_steps(cfg):
    """A learning GP-AKF (predictions, updates, hyperparameter slices, a split) compiles
    nothing after construction: the daemon is warm before its first loop cycle."""
    from dataclasses import replace
    from sea_daemon.core.estimators.gpakf import GPAKF
    c = replace(cfg, learning=replace(cfg.learning, max_points=12))
    est = GPAKF(c)
    before = {k: len(d.signatures) for k, d in _dispatchers().items()}
    for k in ("estimators.akf_core.filter_step", "gp.gp_core.predict_with_grad", "gp.gp_core.add_point",
              "gp.gp_core.lml_grad", "gp.gp_core.cholesky_packed", "estimators.health.box_clip",
              "kinematics.fir_push"):
        assert before["sea_daemon.core." + k] > 0, k
    est.reset([0.0], [0.0], [0.0])
    t = np.arange(1, 200) * 0.01
    for k, tk in enumerate(t):
        est.update([0.3 * np.sin(2 * tk)], [0.29 * np.sin(2 * tk)], [np.cos(3 * tk)])
    g = est.gp.gps[0]
    assert g.n_leaves > 1 and g.n_hyper_steps > 0
    after = {k: len(d.signatures) for k, d in _dispatchers().items()}
    assert after == before


def test_frozen_gpakf_with_its_bound_compiles_nothing_in_its_steps(cfg):
    """The daemon's estimator — a GP-AKF with learning frozen and the Theorem-1 bound — runs its
    samples through the compiled calls made at construction (gpakf_core, bound_core): no new
    signature in its steps, also for a measurement given as lists."""
    from dataclasses import replace
    from sea_daemon.core.bounds.akf_bound import theorem_bound
    from sea_daemon.core.estimators.gpakf import GPAKF
    c = replace(cfg, learning=replace(cfg.learning, max_points=40))
    est = GPAKF(c)
    t = np.arange(1, 400) * 0.01
    q, th, u = 0.3 * np.sin(2 * t), 0.29 * np.sin(2 * t), np.cos(3 * t)
    est.reset([0.0], [0.0], [0.0])
    for k in range(200):
        est.update([q[k]], [th[k]], [u[k]])
    est.learning = False
    est.bound = theorem_bound(est)
    est.reset([q[200]], [th[200]], [u[200]])
    before = {k: len(d.signatures) for k, d in _dispatchers().items()}
    for k in ("estimators.gpakf_core.frozen_sample", "estimators.gpakf_core.frozen_finish",
              "bounds.bound_core.bound_step", "bounds.bound_core.generators_check"):
        assert before["sea_daemon.core." + k] > 0, k
    for k in range(201, len(t)):
        e = est.update([q[k]], [th[k]], [u[k]]) if k % 2 else est.update(q[k:k + 1], th[k:k + 1], u[k:k + 1])
    assert est._fz_args and np.isfinite(e.tau_h_act_bound).all()
    after = {k: len(d.signatures) for k, d in _dispatchers().items()}
    assert after == before


def test_warm_up_knows_every_module_with_compiled_kernels():
    """jit.warm_up imports KERNEL_MODULES: every module of the core that compiles or warms a kernel."""
    import pathlib
    root = pathlib.Path(_jit.__file__).parent
    found = {"sea_daemon.core." + ".".join(p.relative_to(root).with_suffix("").parts)
             for p in root.rglob("*.py")
             if any(ln.startswith(("@njit", "@warmer")) for ln in p.read_text(encoding="utf-8").splitlines())}
    assert found == set(_jit.KERNEL_MODULES)
    _jit.warm_up()
    _jit.warm_up()                         # idempotent
    assert _jit._n_warm == len(_jit._WARMERS)


def test_warm_modules_runs_the_example_calls_of_the_named_modules_only(monkeypatch):
    """A part of warm_up (CI compiles the parts in two processes at once): only the warmers the
    named modules registered run; a name outside KERNEL_MODULES is refused."""
    import importlib
    for name in _jit.KERNEL_MODULES:                 # registered before the list is replaced
        importlib.import_module(name)
    ran = []

    def example(module):
        def fn():
            ran.append(module)
        fn.__module__ = module
        return fn
    monkeypatch.setattr(_jit, "_WARMERS", [example("sea_daemon.core.linalg"), example("sea_daemon.core.control"),
                                           example("sea_daemon.core.kinematics")])
    _jit.warm_modules({"sea_daemon.core.control", "sea_daemon.core.kinematics"})
    assert ran == ["sea_daemon.core.control", "sea_daemon.core.kinematics"]
    with pytest.raises(ValueError, match="not modules of KERNEL_MODULES"):
        _jit.warm_modules({"sea_daemon.core.nothing"})


def test_the_filter_step_arrays_are_named_views_of_one_buffer(cfg):
    """akf_core.views lays every array of the step out in the buffer, without gaps or overlap,
    and the AKF's named attributes are those views."""
    from sea_daemon.core.estimators import akf_core
    from sea_daemon.core.estimators.akf import AKF
    for n in (1, 2):
        d, m = 5 * n, 4 * n
        size = akf_core.buffer_size(d, m, n)
        buf = np.zeros(size)
        vs = akf_core.views(buf, d, m, n)
        assert len(vs) == len(akf_core.STEP_FIELDS)
        assert sum(v.size for v in vs) == size
        for k, v in enumerate(vs):
            v[...] = k + 1
        counts = np.bincount(buf.astype(int), minlength=len(vs) + 1)
        assert counts[0] == 0 and all(counts[k + 1] == vs[k].size for k in range(len(vs)))
    akf = AKF(cfg)
    akf.P[2, 3] = 7.0
    assert np.shares_memory(akf.P, akf._buf) and 7.0 in akf._buf
