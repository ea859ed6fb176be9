"""Ellipsoid algebra: exact affine maps, Minkowski-sum outer approximations, box → ellipsoid."""
import numpy as np
import pytest

from sea_daemon.core.bounds.ellipsoid import (
    Ellipsoid, box_shape, interval_ellipsoid, minkowski_half_width, minkowski_shape, minkowski_sum,
    segments_shapes)


def rand_psd(rng, d, rank=None):
    r = d if rank is None else rank
    A = rng.standard_normal((d, r)) * rng.uniform(0.1, 3.0, size=r)
    return A @ A.T


def test_affine_map_is_exact():
    rng = np.random.default_rng(0)
    for _ in range(20):
        d, m = 4, int(rng.integers(2, 6))
        E = Ellipsoid(rng.standard_normal(d), rand_psd(rng, d))
        A, b = rng.standard_normal((m, d)), rng.standard_normal(m)
        F = E.affine(A, b)
        # images of points of E lie in F, images of boundary points lie on F's boundary (when A is injective)
        pts = E.sample(500, rng)
        assert np.all(F.contains(pts @ A.T + b, tol=1e-8))
        # support functions: h_F(e) = h_E(Aᵀe) + eᵀb for every e (exact, not just outer)
        for e in rng.standard_normal((30, m)):
            assert F.support(e) == pytest.approx(E.support(A.T @ e) + e @ b, rel=1e-10, abs=1e-10)
        if m >= d:
            bnd = E.sample(200, rng, boundary=True) @ A.T + b
            Zi = np.linalg.pinv(F.X)
            q = np.einsum("ij,jk,ik->i", bnd - F.c, Zi, bnd - F.c)
            assert np.allclose(q, 1.0, atol=1e-6)


def test_minkowski_outer_contains_random_sums():
    rng = np.random.default_rng(1)
    for trial in range(30):
        d = int(rng.integers(1, 6))
        k = int(rng.integers(2, 5))
        # mix full-rank and degenerate shapes (segments, flat discs, points)
        ells = []
        for i in range(k):
            rank = d if rng.uniform() < 0.5 else int(rng.integers(0, d + 1))
            X = rand_psd(rng, d, rank) if rank > 0 else np.zeros((d, d))
            ells.append(Ellipsoid(rng.standard_normal(d), X))
        S = minkowski_sum(ells)
        pts = sum(E.sample(2000, rng) for E in ells)
        assert np.all(S.contains(pts, tol=1e-8)), trial
        bnd = sum(E.sample(2000, rng, boundary=True) for E in ells)
        assert np.all(S.contains(bnd, tol=1e-8)), trial
        # support function of the outer ellipsoid dominates the exact sum's in every direction
        for e in rng.standard_normal((50, d)):
            exact = sum(E.support(e) for E in ells)
            assert S.support(e) >= exact - 1e-9 * (1 + abs(exact))


def test_two_ellipsoid_formula_and_trace_minimality():
    rng = np.random.default_rng(2)
    X1, X2 = rand_psd(rng, 3), rand_psd(rng, 3)
    p = np.sqrt(np.trace(X1) / np.trace(X2))
    X = minkowski_shape([X1, X2])
    assert np.allclose(X, (1 + 1 / p) * X1 + (1 + p) * X2)
    # trace-minimal in the family X(p) = (1 + 1/p) X1 + (1 + p) X2
    for q in np.geomspace(p / 10, p * 10, 41):
        assert np.trace(X) <= np.trace((1 + 1 / q) * X1 + (1 + q) * X2) + 1e-12
    # n-ary trace equals (Σ sqrt tr X_i)²
    X3 = rand_psd(rng, 3)
    Xn = minkowski_shape([X1, X2, X3])
    assert np.trace(Xn) == pytest.approx(sum(np.sqrt(np.trace(Y)) for Y in (X1, X2, X3)) ** 2)
    # and is no larger than the nested pairwise sum
    assert np.trace(Xn) <= np.trace(minkowski_shape([minkowski_shape([X1, X2]), X3])) + 1e-12


def test_weighted_minkowski_still_contains():
    rng = np.random.default_rng(3)
    W = np.diag([1e4, 1.0, 1e-4])
    ells = [Ellipsoid(np.zeros(3), rand_psd(rng, 3)) for _ in range(3)]
    S = minkowski_sum(ells, weight=W)
    pts = sum(E.sample(3000, rng, boundary=True) for E in ells)
    assert np.all(S.contains(pts, tol=1e-8))


def test_point_and_single_ellipsoid_sums_are_exact():
    rng = np.random.default_rng(4)
    E = Ellipsoid(rng.standard_normal(3), rand_psd(rng, 3))
    P = Ellipsoid.point(rng.standard_normal(3))
    S = minkowski_sum([E, P])
    assert np.allclose(S.X, E.X) and np.allclose(S.c, E.c + P.c)
    Z = minkowski_sum([P, P])
    assert not np.any(Z.X)


def test_half_width_and_exact_sum_half_width():
    rng = np.random.default_rng(5)
    ells = [Ellipsoid(np.zeros(4), rand_psd(rng, 4)) for _ in range(3)]
    e = np.eye(4)[3]
    hw = minkowski_half_width(ells, e)
    assert hw == pytest.approx(sum(np.sqrt(E.X[3, 3]) for E in ells))
    # the outer ellipsoid's half-width is never smaller than the exact one
    assert minkowski_sum(ells).half_width(e) >= hw - 1e-12
    # exact: the maximum over samples approaches hw from below
    pts = sum(E.sample(20000, rng, boundary=True) for E in ells)
    assert pts[:, 3].max() <= hw + 1e-12


def test_interval_to_ellipsoid_contains_box_corners_and_is_tight():
    rng = np.random.default_rng(6)
    eta = np.array([0.3, 2.0, 0.0, 1.1])
    E = interval_ellipsoid(np.ones(4), eta)
    corners = np.array(np.meshgrid(*[[-1, 1]] * 4)).reshape(4, -1).T * eta + 1.0
    assert np.all(E.contains(corners, tol=1e-9))
    # corners lie on the boundary (tight): scaling them out by 1 % leaves the ellipsoid
    assert not np.any(E.contains(1.0 + 1.01 * (corners - 1.0)))
    # agrees with the n-ary Minkowski sum of the n degenerate 1-D ellipsoids (eq:GPboundsellipse)
    segs = [Ellipsoid(np.zeros(4), S) for S in segments_shapes(np.eye(4), eta)]
    assert np.allclose(minkowski_sum(segs).X, box_shape(eta))
    # interior of the box
    pts = rng.uniform(-1, 1, size=(5000, 4)) * eta + 1.0
    assert np.all(E.contains(pts, tol=1e-9))


def test_segments_through_matrix_contain_image_of_box():
    rng = np.random.default_rng(7)
    G = rng.standard_normal((5, 2))
    eta = np.array([0.5, 2.0])
    E = Ellipsoid(np.zeros(5), minkowski_shape(segments_shapes(G, eta)))
    pts = (rng.uniform(-1, 1, size=(5000, 2)) * eta) @ G.T
    assert np.all(E.contains(pts, tol=1e-8))


def test_containment_test_and_degenerate_membership():
    A = Ellipsoid(np.zeros(2), np.diag([4.0, 1.0]))
    B = Ellipsoid(np.zeros(2), np.diag([1.0, 1.0]))
    assert A.contains_ellipsoid(B) and not B.contains_ellipsoid(A)
    C = Ellipsoid(np.array([1.5, 0.0]), np.diag([0.25, 0.0]))   # a segment
    assert C.contains(np.array([1.7, 0.0])) and not C.contains(np.array([1.7, 1e-3]))
    assert A.contains_ellipsoid(C) and not A.contains_ellipsoid(Ellipsoid(np.array([1.8, 0.0]), C.X))
    with pytest.raises(ValueError):
        Ellipsoid(np.zeros(2), np.zeros((3, 3)))
