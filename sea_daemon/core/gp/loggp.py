"""Locally growing random tree of Gaussian processes (LoG-GP; Lederer et al., ICML 2021).

The face of docs/interfaces.md §5 (imported from :mod:`sea_daemon.loggp`)::

    from sea_daemon.loggp import LoGGP
    gp = LoGGP(input_dim=3, max_points=100)
    gp.update(x, y)          # x: (input_dim,) array, y: float
    mu, var = gp.predict(x)  # floats

Method (as in the LoG-GP paper and its reference implementation ``lgrt4gps``):

* Every leaf is an exact GP (:class:`sea_daemon.core.gp.exact.IncrementalGP`) holding at most
  ``N̄ = max_points`` points; adding a point costs O(N̄²) (one new Cholesky row).
* A full leaf that receives a point splits: dimension ``j`` of the widest spread of its
  ``N̄ + 1`` points (with ``split_in_lengthscales``: the widest in units of the leaf's length
  scales, width_j / l_j), split value ``s`` the centre of that spread, overlap width
  ``o = overlap · width``.  The probability of the *left* child (smaller values) is the linear
  ramp ``p(x) = clip(½ − (x_j − s)/o, 0, 1)``: 1 below ``s − o/2``, 0 above ``s + o/2``.  Each
  point goes to exactly one child, drawn with ``p`` (seeded, deterministic).  Children inherit
  the parent's hyperparameters.
* Prediction merges every leaf the input reaches with non-zero probability, weighted by the
  product ``ω`` of the branch probabilities on its path (mixture of experts):
  ``μ = Σ ω_i μ_i``, ``σ² = Σ ω_i (σ_i² + μ_i²) − μ²``.  Because the ramp is continuous, so
  are the merged mean and variance.  The Jacobian is the exact derivative of that mixture,
  ``∂μ/∂x = Σ (ω_i ∂μ_i/∂x + μ_i ∂ω_i/∂x)`` with ``∂μ_i/∂x`` from ``eq:moejac`` /
  ``eq:kernelderivative``; outside overlaps (the common case) it is exactly ``eq:moejac``.

Memory bound (``max_leaves``): once the tree has ``max_leaves`` leaves, full leaves stop
splitting.  A full leaf that receives a point forgets its oldest ``evict`` points (FIFO,
default ``max(1, N̄ // 10)``) and refactorises once (O(N̄³)/evict amortised per update =
O(N̄²)); the new point is then appended in O(N̄²).  So memory is O(max_leaves · N̄²) and the
model keeps tracking slowly changing dynamics.  A leaf whose points are all identical cannot
split and uses the same rule; so does, with ``split_in_lengthscales``, a leaf whose points span
less than :data:`MIN_SPLIT_SPREAD` of its length scales in every dimension (saturated).

Online hyperparameters: see :mod:`sea_daemon.core.gp.hyper` (``hyperopt=True``): every
``hyper_every`` updates one bounded slice runs — one Adam step of the log marginal likelihood
of the leaf that just received data (phase 1, in that update), then the rebuild of that leaf's
factor with the new values, swapped in at once (phase 2, in the next update).  Each phase costs
O(N̄³) for one leaf, independent of the tree size, and a call that splits or evicts runs no
phase (at most one O(N̄³) piece of work per call).  Deterministic under ``seed``.  For
adaptation in another process see :meth:`LoGGP.hyper_request` / :meth:`LoGGP.hyper_apply`.

Cost: an update is O(depth + N̄²); a prediction O(depth + m N̄²) for the m leaves it reaches.
The depth grows logarithmically with the data, and m grows like (1 + overlap)^depth: with a
small overlap (0.01, the default, as ``lgrt4gps``) m stays ≈ 1.1–1.3 up to 10⁶ points (flat
cost), with 0.02 1.1 → 1.5; with 0.1, m went from 1.5 to 3.7 between 10³ and 10⁶ points
on the bench trajectory (better averaging, gentler weight ramps, costlier predictions).  No I/O, no clock, no threads.
"""
from __future__ import annotations

import math
import random
from typing import Any

import numpy as np

from sea_daemon.errors import InputError
from sea_daemon.core.gp.exact import IncrementalGP
from sea_daemon.core.gp.hyper import AdamHyper
from sea_daemon.core.gp.loggp_state import LoGGPState
from sea_daemon.core.gp.routing import Tree, TreeMirror, route



#: with ``split_in_lengthscales``: a full leaf whose points span less than this many of its length
#: scales in every dimension does not split (its kernel sees one location: correlation
#: exp(−0.1²/2) ≥ 0.995 across it); it forgets its oldest points, as a leaf of a full tree does
MIN_SPLIT_SPREAD = 0.1


class LoGGP(LoGGPState):
    """Locally growing random tree of GPs (docs/interfaces.md §5).

    Parameters
    ----------
    input_dim: ρ, the input dimension (3 per joint for ``z = [q, q̇, q̈]``).
    max_points: N̄, the maximum number of points per leaf (paper: 100).
    max_leaves: memory bound on the number of leaves (``None``: unbounded).
    overlap: relative width of a split's overlapping region, in [0, 0.9] (default 0.01, as
        ``lgrt4gps``: the cost of a prediction stays flat as the tree deepens).
    lengthscales, sigma_f, sigma_n: initial hyperparameters of every leaf (eq:SE, σ_on).
    hyperopt: adapt the hyperparameters online (bounded slices, see :mod:`sea_daemon.core.gp.hyper`).
    hyper_every: updates between two hyperparameter slices.
    hyper_lr: Adam step size in log space.
    hyper_min_points: a leaf needs this many points before it is adapted.
    hyper_points: in-loop slices use the LML gradient of a leaf's oldest ``hyper_points``
        points only (``None``: all); 50 of 100 cuts the cost of phase 1 several-fold.
    evict: points a full leaf forgets at once when it may not split (default ``N̄ // 10``).
    extrapolation_scale: c of the extrapolation term ``c · e(z)`` that the local error scale of
        the GP error bound adds (:meth:`extrapolation_many`,
        :class:`sea_daemon.core.bounds.gp_bound.LocalScale`); 0 (default): off.  The predictions
        themselves do not change.
    clip_leaf_mean: every leaf evaluates its mean (and ∂μ/∂x) at the input clipped into the box
        of its own training inputs and its variance at the input itself
        (:class:`~sea_daemon.core.gp.exact.IncrementalGP` ``clip_mean``): a leaf never extrapolates its
        mean beyond its data, while its σ still grows there (docs/learning.md, "Novelty").
    split_in_lengthscales: a full leaf splits the dimension of the widest spread measured in its
        length scales (width_j / l_j) instead of in raw units.  In raw units a dimension with a
        large numeric span but a long length scale (q̈ in rad/s² beside q in rad) takes every
        split, and the tree's routing then makes the mean key on it where the kernel does not.
        A leaf whose widest spread is below :data:`MIN_SPLIT_SPREAD` length scales is saturated
        (one location to its kernel: more points there only average the noise) and does not
        split; it forgets its oldest points instead.
    seed: seed of the random split assignment.
    """

    def __init__(self, input_dim: int, max_points: int = 100, *, max_leaves: int | None = 2000,
                 overlap: float = 0.01, lengthscales=1.0, sigma_f: float = 1.0,
                 sigma_n: float = 0.05, hyperopt: bool = False, hyper_every: int = 10,
                 hyper_lr: float = 0.05, hyper_min_points: int = 10, hyper_points: int | None = None,
                 evict: int | None = None, extrapolation_scale: float = 0.0, clip_leaf_mean: bool = False,
                 seed: int = 0, jitter: float = 1e-10, split_in_lengthscales: bool = False):
        def _int(name, v, lo):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise InputError(f"{name} must be an integer >= {lo}, got {v!r}")
            return int(v)

        self.input_dim = _int("input_dim", input_dim, 1)
        self.max_points = _int("max_points", max_points, 2)
        self.max_leaves = None if max_leaves is None else _int("max_leaves", max_leaves, 1)
        if isinstance(overlap, bool) or not isinstance(overlap, (int, float)) \
                or not 0.0 <= float(overlap) <= 0.9:
            raise InputError(f"overlap must be in [0, 0.9], got {overlap!r}")
        self.overlap = float(overlap)
        self.hyperopt = bool(hyperopt)
        self.hyper_every = _int("hyper_every", hyper_every, 1)
        self.hyper_min_points = _int("hyper_min_points", hyper_min_points, 2)
        self.hyper_points = None if hyper_points is None else _int("hyper_points", hyper_points, 2)
        self.evict = max(1, self.max_points // 10) if evict is None else _int("evict", evict, 1)
        self.evict = min(self.evict, self.max_points)
        self.seed = _int("seed", seed, 0)
        self.jitter = float(jitter)
        if isinstance(extrapolation_scale, bool) or not isinstance(extrapolation_scale, (int, float)) \
                or not 0.0 <= float(extrapolation_scale) <= 10.0:
            raise InputError(f"extrapolation_scale must be in [0, 10], got {extrapolation_scale!r}")
        self.extrapolation_scale = float(extrapolation_scale)
        self.clip_leaf_mean = bool(clip_leaf_mean)
        self.split_in_lengthscales = bool(split_in_lengthscales)
        # validates the hyperparameters (raises InputError naming the value)
        proto = IncrementalGP(self.input_dim, sigma_f, lengthscales, sigma_n, capacity=1)
        self._theta0 = proto.log_theta
        self.hyper = AdamHyper(self.input_dim, lr=hyper_lr)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all data (hyperparameters back to their initial values)."""
        self._rng = random.Random(self.seed)
        # tree as parallel lists; node 0 is the root; dim −1 marks a leaf
        self._dim: list[int] = [-1]
        self._lo: list[float] = [0.0]
        self._hi: list[float] = [0.0]
        self._left: list[int] = [-1]
        self._right: list[int] = [-1]
        self._gp: list[IncrementalGP | None] = [self._new_leaf(self._theta0)]
        self._adam: dict[int, Any] = {}
        self.n_leaves = 1
        self.n_points = 0
        self.n_updates = 0
        self.n_evicted = 0
        self.n_hyper_steps = 0
        self.last_leaf = 0
        self.hyper_proposal: tuple[int, np.ndarray] | None = None    # phase 1's (leaf, θ), for phase 2
        self._hyper_due = False

    def _new_leaf(self, log_theta: np.ndarray, capacity: int = 16) -> IncrementalGP:
        d = self.input_dim
        return IncrementalGP(d, math.exp(log_theta[0]), np.exp(log_theta[1:d + 1]),
                             math.exp(log_theta[d + 1]), capacity=min(capacity, self.max_points),
                             max_capacity=self.max_points, jitter=self.jitter,
                             clip_mean=self.clip_leaf_mean)

    def _check_x(self, x) -> tuple[np.ndarray, list[float]]:
        x = np.asarray(x, dtype=float)
        if x.shape != (self.input_dim,):
            raise InputError(f"x must have shape ({self.input_dim},), got {x.shape}")
        xl = x.tolist()
        for v in xl:
            if not math.isfinite(v):
                raise InputError(f"x must be finite, got {xl}")
        return x, xl

    # ------------------------------------------------------------------ learning
    def update(self, x, y: float) -> None:
        """Add one training pair ``(x, y)``; O(depth + N̄²) (a split or eviction: O(N̄³) once)."""
        x, xl = self._check_x(x)
        y = float(y)
        if not math.isfinite(y):
            raise InputError(f"y must be finite, got {y}")
        dim, lo, hi, left, right = self._dim, self._lo, self._hi, self._left, self._right
        node = 0
        j = dim[0]
        while j >= 0:
            xj = xl[j]
            if xj <= lo[node]:
                node = left[node]
            elif xj >= hi[node]:
                node = right[node]
            else:
                # overlap: left with probability p = (hi − x_j)/o (linear ramp)
                p = (hi[node] - xj) / (hi[node] - lo[node])
                node = left[node] if self._rng.random() < p else right[node]
            j = dim[node]
        gp = self._gp[node]
        heavy = True                             # a split or an eviction: O(N̄³) in this call
        if gp.n_ < self.max_points:
            gp.add(x, y)
            heavy = False
        elif (self.max_leaves is None or self.n_leaves < self.max_leaves) \
                and (child := self._split(node, x, y)) >= 0:
            node = child                         # the leaf the new point went to
        else:
            # memory bound: forget the oldest points, then append (FIFO)
            gp.remove_oldest(self.evict)
            self.n_evicted += self.evict
            self.n_points -= self.evict
            gp.add(x, y)
        self.n_points += 1
        self.n_updates += 1
        self.last_leaf = node
        if self.hyperopt:
            if self.n_updates % self.hyper_every == 0:
                self._hyper_due = True
            # at most one O(N̄³) piece of work per call: a hyperparameter phase waits for a
            # call without a split or an eviction
            if heavy:
                return
            if self.hyper_proposal is not None:
                # phase 2 of a slice: swap the proposed hyperparameters in (rebuild)
                pnode, theta = self.hyper_proposal
                self.hyper_proposal = None
                g = self._gp[pnode]
                if g is not None:              # (a leaf that split meanwhile keeps its values)
                    self.hyper.apply(g, theta)
            elif self._hyper_due:
                # phase 1: gradient + Adam step on the leaf that just received data
                self._hyper_due = False
                self._propose(node)

    def _split(self, node: int, x: np.ndarray, y: float) -> int:
        """Split the full leaf ``node`` with the new point (LoG-GP).

        Returns the child leaf that received the new point, or −1 if the leaf cannot split
        (all its points coincide).
        """
        gp = self._gp[node]
        n = gp.n_
        X = np.empty((n + 1, self.input_dim))
        X[:n] = gp.X_[:n]
        X[n] = x
        Y = np.empty(n + 1)
        Y[:n] = gp.y_[:n]
        Y[n] = y
        mi, ma = X.min(axis=0), X.max(axis=0)
        width = ma - mi
        # the dimension of the widest spread, in the leaf's length scales if so configured
        if self.split_in_lengthscales:
            spread = width / gp.lengthscales
            j = int(np.argmax(spread))
            # a saturated leaf: all its points within MIN_SPLIT_SPREAD length scales are one
            # location to its kernel (eq:SE: correlation ≥ 0.995); a split would key the routing
            # on differences the kernel cannot see (input noise), each child learning the same
            # value from half the data.  It forgets its oldest points instead (as below).
            if not spread[j] >= MIN_SPLIT_SPREAD:
                return -1
        else:
            j = int(np.argmax(width))
        if not width[j] > 0.0:
            return -1
        s = 0.5 * (ma[j] + mi[j])
        o = self.overlap * width[j]
        lo, hi = s - 0.5 * o, s + 0.5 * o
        xj = X[:, j]
        go_left = xj <= lo
        # points inside the overlap go left with probability p = (hi − x_j)/o (in index order)
        rnd = self._rng.random
        for i in np.flatnonzero((xj > lo) & (xj < hi)).tolist():
            go_left[i] = rnd() < (hi - xj[i]) / (hi - lo)
        # one kernel matrix of all N̄ + 1 points; the children's are its sub-matrices
        Kall = gp.kernel_matrix(X)
        cap = min(self.max_points, n // 2 + 16)
        children = []
        for mask in (go_left, ~go_left):
            idx = np.flatnonzero(mask)
            leaf = gp.spawn(X[idx], Y[idx], Kall[idx][:, idx], capacity=cap)
            children.append(len(self._gp))
            self._gp.append(leaf)
            self._dim.append(-1)
            self._lo.append(0.0)
            self._hi.append(0.0)
            self._left.append(-1)
            self._right.append(-1)
        self._dim[node], self._lo[node], self._hi[node] = j, lo, hi
        self._left[node], self._right[node] = children
        self._tree_written((node, *children), added=2)
        self._gp[node] = None
        st = self._adam.pop(node, None)
        if st is not None:
            for c in children:
                self._adam[c] = self.hyper.copy_state(st)
        self.n_leaves += 1
        return children[0] if go_left[n] else children[1]

    def _propose(self, node: int) -> float | None:
        gp = self._gp[node]
        if gp is None or gp.n_ < self.hyper_min_points:
            return None
        st = self._adam.get(node)
        if st is None:
            st = self._adam[node] = self.hyper.new_state()
        lml, theta = self.hyper.propose(gp, st, self.hyper_points)
        if theta is not None:
            self.hyper_proposal = (node, theta)
        self.n_hyper_steps += 1
        return lml

    def hyper_slice(self, leaf: int | None = None) -> float | None:
        """One bounded hyperparameter slice on ``leaf`` (default: the last updated one).

        One Adam ascent step on that leaf's log marginal likelihood, then its factor is
        rebuilt with the new values and swapped in (both phases in this call; ``update`` runs
        the two phases on consecutive calls instead).  Cost O(N̄³) with N̄ = ``max_points``,
        independent of the tree size.  Returns the leaf's LML before the step (None if skipped).
        """
        if self.hyper_proposal is not None:
            pnode, theta = self.hyper_proposal
            self.hyper_proposal = None
            if self._gp[pnode] is not None:
                self.hyper.apply(self._gp[pnode], theta)
        node = self.last_leaf if leaf is None else leaf
        gp = self._gp[node] if 0 <= node < len(self._gp) else None
        if gp is None or gp.n_ < self.hyper_min_points:
            return None
        st = self._adam.get(node)
        if st is None:
            st = self._adam[node] = self.hyper.new_state()
        lml = self.hyper.step(gp, st, self.hyper_points)
        self.n_hyper_steps += 1
        return lml

    def hyper_request(self, leaf: int | None = None) -> dict | None:
        """JSON-able snapshot of one leaf (default: the last updated) for off-loop adaptation
        with :func:`sea_daemon.core.gp.hyper.adam_steps`; None if the leaf has too few points."""
        node = self.last_leaf if leaf is None else int(leaf)
        gp = self._gp[node] if 0 <= node < len(self._gp) else None
        if gp is None or gp.n_ < self.hyper_min_points:
            return None
        st = self._adam.get(node)
        n = gp.n_
        return {"node": node, "input_dim": self.input_dim, "X": gp.X_[:n].ravel().tolist(),
                "y": gp.y_[:n].tolist(), "center": gp.center_.tolist(),
                "log_theta": gp.log_theta.tolist(), "jitter": gp.jitter,
                "adam": None if st is None else st.tolist()}

    def hyper_apply(self, result: dict) -> bool:
        """Swap in a result of :func:`~sea_daemon.core.gp.hyper.adam_steps` (one O(N̄³) rebuild).

        Applied only if that node is still a leaf (a leaf that split meanwhile keeps the values
        it passed on to its children).  Returns whether it was applied.
        """
        node = int(result["node"])
        gp = self._gp[node] if 0 <= node < len(self._gp) else None
        if gp is None:
            return False
        theta = np.clip(np.asarray(result["log_theta"], dtype=float), self.hyper.lo, self.hyper.hi)
        if not self.hyper.apply(gp, theta):
            return False
        self._adam[node] = np.asarray(result["adam"], dtype=float)
        self.n_hyper_steps += len(result.get("lml", [1]))
        return True

    def optimize_hyperparameters(self, steps: int = 20) -> None:
        """Off-line: ``steps`` Adam slices on every leaf (e.g. at the end of calibration)."""
        for _ in range(int(steps)):
            for node in self.leaves():
                self.hyper_slice(node)

    # ------------------------------------------------------------------ prediction
    def route(self, x, grad: bool = False) -> list[tuple[int, float, np.ndarray]]:
        """Leaves reached by ``x``: ``[(node, ω, ∂ω/∂x)]`` in routing order (∂ω/∂x zeros
        without ``grad``)."""
        x, _ = self._check_x(x)
        nodes, ws, dws = self.route_one(x, grad)
        return list(zip(nodes, ws.tolist(), dws))

    def route_one(self, x: np.ndarray, grad: bool = False):
        """Leaves reached by one input ``x`` (:func:`~sea_daemon.core.gp.routing.route`):
        ``(nodes as a list, ω, ∂ω/∂x)`` in routing order.  ``x`` must be a finite, C-contiguous
        float array of shape (input_dim,); it is not checked here (:meth:`route` checks it)."""
        t = self._tree_arrays()
        _, nodes, ws, dws = route(x.reshape(1, -1), t.links, t.span, grad)
        return nodes.tolist(), ws, dws

    def predict(self, x) -> tuple[float, float]:
        """Merged posterior mean and variance at ``x`` (floats)."""
        x, _ = self._check_x(x)
        nodes, ws, _ = self.route_one(x, False)
        gps = self._gp
        if len(nodes) == 1:
            return gps[nodes[0]].predict(x)
        mu = m2 = 0.0
        for node, w in zip(nodes, ws.tolist()):
            m, v = gps[node].predict(x)
            mu += w * m
            m2 += w * (v + m * m)
        var = m2 - mu * mu
        return mu, (var if var > 0.0 else 0.0)

    def leaf_predictions(self, Z) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every (row of ``Z``, leaf it reaches) pair of a batch of inputs ``Z`` (m, input_dim),
        in each row's routing order: (row index, node, ω, leaf μ, leaf σ²), arrays of equal
        length.  Each row is routed once; each leaf reached predicts all its rows in one
        compiled call (:meth:`sea_daemon.core.gp.exact.IncrementalGP.predict_many`)."""
        Z = np.ascontiguousarray(Z, dtype=float)
        if Z.ndim != 2 or Z.shape[1] != self.input_dim:
            raise InputError(f"Z must have shape (m, {self.input_dim}), got {Z.shape}")
        if not np.all(np.isfinite(Z)):
            raise InputError(f"Z must be finite, got {Z.tolist()}")
        t = self._tree_arrays()
        idx, nodes, ws, _ = route(Z, t.links, t.span, False)
        if len(idx) == len(Z) and nodes.min() == nodes.max():
            # every row reaches the same one leaf (the common case)
            m, v = self._gp[int(nodes[0])].predict_many(Z)
            return idx, nodes, ws, m, v
        m, v = np.empty(len(idx)), np.empty(len(idx))
        for node in np.unique(nodes):
            sel = nodes == node
            m[sel], v[sel] = self._gp[node].predict_many(Z[idx[sel]])
        return idx, nodes, ws, m, v

    def _tree_arrays(self) -> Tree:
        """The tree's parallel lists as arrays for the compiled routing (:class:`TreeMirror`:
        built once per tree, a reset or a load replaces it; a split writes its three nodes,
        :meth:`_tree_written`), so no step copies the whole tree."""
        m = self.__dict__.get("_tree_cache")
        if m is None or not m.mirrors(self._dim):
            m = self._tree_cache = TreeMirror(self._dim, self._left, self._right, self._lo, self._hi)
        return m.tree

    def _tree_written(self, nodes, added: int) -> None:
        """After a split: write ``nodes`` (the split node and its ``added`` new children) into
        the mirror; one that missed a change is dropped (rebuilt when next needed)."""
        m = self.__dict__.get("_tree_cache")
        if m is not None and m.lists[0] is self._dim and not m.written(nodes, added):
            self._tree_cache = None

    def predict_many(self, Z) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict` at every row of ``Z`` (m, input_dim): (μ (m,), σ² (m,)), the same
        numbers (one routing per row, one compiled call per leaf reached)."""
        idx, _, w, m, v = self.leaf_predictions(Z)
        rows = int(np.asarray(Z).shape[0])
        # μ = Σ ω_i μ_i, σ² = Σ ω_i (σ_i² + μ_i²) − μ², accumulated in routing order
        # (bincount adds each row's terms in order, from 0)
        mu = np.bincount(idx, w * m, rows)
        m2 = np.bincount(idx, w * (v + m * m), rows)
        var = np.maximum(m2 - mu * mu, 0.0)
        # a row that reaches one leaf: that leaf's prediction as is (as predict)
        one = np.bincount(idx, minlength=rows) == 1
        first = np.searchsorted(idx, np.flatnonzero(one))
        mu[one], var[one] = m[first], v[first]
        return mu, var

    def extrapolation_many(self, Z) -> np.ndarray:
        """Merged first-order extrapolation ``e(z) = Σ_i ω_i e_i(z)`` at every row of ``Z``
        (m, input_dim), e_i of the leaves reached (:meth:`IncrementalGP.extrapolation_many`:
        the leaf mean's local slope times the distance to the leaf's nearest training input),
        merged with the prediction weights as the local scale merges its terms."""
        Z = np.ascontiguousarray(Z, dtype=float)
        idx, nodes, w, _, _ = self.leaf_predictions(Z)
        return self.extrapolation_rows(Z, idx, nodes, w)

    def extrapolation_rows(self, Z: np.ndarray, idx: np.ndarray, nodes: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Σ_i ω_i e_i(z) per row of ``Z`` from a routing (row index, node, ω) of
        :meth:`leaf_predictions`."""
        ex = np.empty(len(idx))
        for node in np.unique(nodes).tolist():
            sel = nodes == node
            ex[sel] = self._gp[node].extrapolation_many(Z[idx[sel]])
        return np.bincount(idx, w * ex, Z.shape[0])

    def predict_with_grad(self, x, var_grad: bool = False):
        """``(μ, σ², ∂μ/∂x)`` (and ``∂σ²/∂x`` with ``var_grad``) of the merged prediction."""
        x, _ = self._check_x(x)
        return self._predict_with_grad(x, var_grad, None)

    def predict_grad_into(self, x: np.ndarray, out: np.ndarray, noise: bool = False,
                          weights_grad: bool = True) -> tuple[float, float]:
        """``(μ, σ²)``, with ``∂μ/∂x`` written into ``out``: the GP-AKF's per-step call.

        ``noise``: σ² + :meth:`noise_variance` (the predictive variance of a new target), from
        the same routing.  ``weights_grad=False``: ``out`` is the experts' Jacobian
        Σ ω_i ∂μ_i/∂x (eq:moejac of each leaf, merged with the weights), without the routing
        ramp's μ_i ∂ω_i/∂x (the GP-AKF's linearisation, docs/learning.md).  ``x`` must be a
        finite, C-contiguous float array of shape (input_dim,) (the caller has validated it,
        e.g. clipped it into the input box); it is not checked here.
        """
        r = self._predict_with_grad(x, False, out, noise, weights_grad)
        return r[0], r[1]

    def _predict_with_grad(self, x: np.ndarray, var_grad: bool, out, noise: bool = False,
                           weights_grad: bool = True):
        # without weights_grad the routing's ∂ω/∂x are zeros (route_one without grad)
        nodes, ws, dws = self.route_one(x, weights_grad or var_grad)
        gps = self._gp
        if noise:
            # σ² + Σ ω_i σ_on,i² (noise_variance)
            r = list(self._predict_with_grad_route(x, nodes, ws, dws, var_grad, out))
            r[1] += sum(w * gps[node].sigma_n ** 2 for node, w in zip(nodes, ws.tolist()))
            return tuple(r)
        return self._predict_with_grad_route(x, nodes, ws, dws, var_grad, out)

    def _predict_with_grad_route(self, x: np.ndarray, nodes: list, ws, dws, var_grad: bool, out):
        gps = self._gp
        if len(nodes) == 1:
            return gps[nodes[0]].predict_with_grad(x, var_grad, out=out)
        d = self.input_dim
        mu = m2 = 0.0
        acc = [0.0] * d
        acc2 = [0.0] * d
        for node, w, dw in zip(nodes, ws.tolist(), dws.tolist()):
            r = gps[node].predict_with_grad(x, var_grad)
            m, v, dm = r[0], r[1], r[2].tolist()
            mu += w * m
            m2 += w * (v + m * m)
            # ∂(ω μ_i) = ω ∂μ_i + μ_i ∂ω
            for j in range(d):
                acc[j] += w * dm[j] + m * dw[j]
            if var_grad:
                # ∂(ω (σ_i² + μ_i²)) = ∂ω (σ_i² + μ_i²) + ω (∂σ_i² + 2 μ_i ∂μ_i)
                dv = r[3].tolist()
                for j in range(d):
                    acc2[j] += dw[j] * (v + m * m) + w * (dv[j] + 2.0 * m * dm[j])
        var = m2 - mu * mu
        if var < 0.0:
            var = 0.0
        dmu = np.empty(d) if out is None else out
        dmu[:] = acc
        if not var_grad:
            return mu, var, dmu
        return mu, var, dmu, np.asarray(acc2) - 2.0 * mu * dmu

    def noise_variance(self, x) -> float:
        """σ_on² of the leaves ``x`` reaches, merged with the prediction weights: Σ ω_i σ_on,i².

        ``predict``'s σ² is the latent variance of f (eq:GPvariance); σ² + noise_variance(x) is
        the predictive variance of a new target y = f(x) + ε at x.
        """
        x, _ = self._check_x(x)
        gps = self._gp
        nodes, ws, _ = self.route_one(x, False)
        return float(sum(w * gps[node].sigma_n ** 2 for node, w in zip(nodes, ws.tolist())))

    # ------------------------------------------------------------------ introspection
    def leaves(self) -> list[int]:
        """Node ids of the leaves, in creation order."""
        return [i for i, g in enumerate(self._gp) if g is not None]

    def leaf(self, node: int) -> IncrementalGP:
        g = self._gp[node]
        if g is None:
            raise InputError(f"node {node} is not a leaf")
        return g

    @property
    def n_nodes(self) -> int:
        """Number of nodes of the tree (split nodes and leaves; node ids are 0 … n_nodes − 1)."""
        return len(self._dim)

    @property
    def tree(self) -> Tree:
        """The tree as arrays (:class:`~sea_daemon.core.gp.routing.Tree`), one column per node:
        ``links`` (3, n_nodes) rows dim, left, right (a leaf: dim = left = right = −1) and
        ``span`` (2, n_nodes) rows lo, hi of each split's overlap (0 at a leaf).  Read-only
        views, valid until the next :meth:`update` that splits (or a reset or load)."""
        t, n = self._tree_arrays(), len(self._dim)
        links, span = t.links[:, :n], t.span[:, :n]
        links.flags.writeable = False
        span.flags.writeable = False
        return Tree(links, span)

    @property
    def depth(self) -> int:
        """Depth of the deepest leaf (root = 0)."""
        best, stack = 0, [(0, 0)]
        while stack:
            node, dep = stack.pop()
            if self._dim[node] < 0:
                best = max(best, dep)
            else:
                stack.append((self._left[node], dep + 1))
                stack.append((self._right[node], dep + 1))
        return best

    def memory_bytes(self) -> int:
        """Bytes in the leaves' arrays plus an estimate of the tree's Python lists."""
        return sum(g.nbytes() for g in self._gp if g is not None) + 8 * 6 * len(self._dim)
