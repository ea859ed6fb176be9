"""Persistence of the LoG-GP (:class:`~sea_daemon.core.gp.loggp.LoGGP`): its whole state as a
JSON-able dict or as numeric arrays plus JSON metadata (no numpy objects, no pickle), and back.

The factors are not stored: every leaf's Cholesky factor is rebuilt from its data on load, so
a loaded model predicts exactly as the saved one (tests/test_loggp.py).  Malformed input raises
:class:`~sea_daemon.errors.ModelFileError`: a loaded tree is checked before any use
(:func:`check_tree`: a proper binary tree on its nodes, so every walk from the root ends within
``n_nodes`` steps), and so are the leaves (one per leaf node, data of the tree's input size,
within ``max_points``).
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.gp.exact import IncrementalGP
from sea_daemon.errors import InputError, ModelFileError

_FORMAT = "sea-daemon-loggp"
_VERSION = 1
#: the most points a loaded leaf may hold and the most leaves a loaded tree may have (the upper
#: ends of ``learning.max_points`` and ``learning.max_leaves``, core.config.LearningConfig): a
#: leaf's factor is rebuilt on load in O(N̄³)
MAX_LEAF_POINTS = 1000
MAX_LEAVES = 100_000


def _index(v) -> int:
    """``v`` as a node index or split dimension: an integer (not a bool); ValueError otherwise."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        raise ValueError(f"{v!r} is not an integer")
    return int(v)


def check_tree(dim: list, lo: list, hi: list, left: list, right: list, input_dim: int) -> list:
    """Check a loaded LoG-GP tree (node 0 the root; a leaf has ``dim = left = right = −1``) and
    return its leaf nodes; raise ModelFileError naming the first fault.

    A split node's ``dim`` lies in 0 … input_dim − 1, its overlap ``lo <= hi`` is finite and its
    two children are other nodes in 1 … n_nodes − 1; walking from the root reaches every node
    exactly once (no loop, no shared child, no unreachable node).  So the tree is acyclic, its
    depth is below n_nodes, and every routing walk ends within n_nodes steps.
    """
    n = len(dim)
    if n < 1 or any(len(a) != n for a in (lo, hi, left, right)):
        raise ModelFileError(f"LoG-GP tree: lists of unequal or zero length "
                             f"({[len(a) for a in (dim, lo, hi, left, right)]})")
    seen = bytearray(n)
    seen[0] = 1
    stack, leaves = [0], []
    while stack:
        i = stack.pop()
        try:
            d, a, b = _index(dim[i]), _index(left[i]), _index(right[i])
            span = (float(lo[i]), float(hi[i]))
        except (TypeError, ValueError, OverflowError) as e:
            raise ModelFileError(f"LoG-GP tree: node {i}: {e}") from None
        if d == -1:
            if a != -1 or b != -1:
                raise ModelFileError(f"LoG-GP tree: leaf node {i} has children {a}, {b} (allowed: -1, -1)")
            leaves.append(i)
            continue
        if not 0 <= d < input_dim:
            raise ModelFileError(f"LoG-GP tree: node {i} splits dimension {d}; allowed -1 (a leaf) or "
                                 f"0..{input_dim - 1}")
        if not (math.isfinite(span[0]) and math.isfinite(span[1]) and span[0] <= span[1]):
            raise ModelFileError(f"LoG-GP tree: node {i} has the overlap [{span[0]}, {span[1]}]; "
                                 "allowed finite lo <= hi")
        for c in (a, b):
            if not 1 <= c < n:
                raise ModelFileError(f"LoG-GP tree: node {i} has child {c}; allowed 1..{n - 1}")
            if seen[c]:
                raise ModelFileError(f"LoG-GP tree: node {c} is reached twice (a loop or a shared child, "
                                     f"at node {i})")
            seen[c] = 1
            stack.append(c)
    if not all(seen):
        raise ModelFileError(f"LoG-GP tree: node {seen.index(0)} is not reachable from the root")
    return leaves


class LoGGPState:
    """The save/load half of :class:`~sea_daemon.core.gp.loggp.LoGGP` (a mixin of its attributes)."""

    def to_dict(self) -> dict:
        """JSON-serialisable state (no numpy, no pickle); factors are rebuilt on load."""
        leaves = []
        for node in self.leaves():
            g = self._gp[node]
            st = self._adam.get(node)
            leaves.append({"node": node, "gp": g.to_dict(),
                           "adam": None if st is None else self.hyper.state_to_dict(st)})
        state = self._rng.getstate()
        return {"format": _FORMAT, "version": _VERSION,
                "options": {"input_dim": self.input_dim, "max_points": self.max_points,
                            "max_leaves": self.max_leaves, "overlap": self.overlap,
                            "lengthscales": np.exp(self._theta0[1:self.input_dim + 1]).tolist(),
                            "sigma_f": math.exp(self._theta0[0]),
                            "sigma_n": math.exp(self._theta0[-1]),
                            "hyperopt": self.hyperopt, "hyper_every": self.hyper_every,
                            "hyper_lr": self.hyper.lr, "hyper_min_points": self.hyper_min_points,
                            "hyper_points": self.hyper_points,
                            "evict": self.evict, "seed": self.seed, "jitter": self.jitter,
                            "extrapolation_scale": self.extrapolation_scale,
                            "clip_leaf_mean": self.clip_leaf_mean,
                            "split_in_lengthscales": self.split_in_lengthscales},
                "tree": {"dim": list(self._dim), "lo": list(self._lo), "hi": list(self._hi),
                         "left": list(self._left), "right": list(self._right)},
                "leaves": leaves,
                "counters": {"n_points": self.n_points, "n_updates": self.n_updates,
                             "n_evicted": self.n_evicted, "n_hyper_steps": self.n_hyper_steps,
                             "last_leaf": self.last_leaf, "hyper_due": self._hyper_due},
                "pending": None if self.hyper_proposal is None else
                [self.hyper_proposal[0], self.hyper_proposal[1].tolist()],
                "rng_state": [state[0], list(state[1]), state[2]]}

    def to_arrays(self, prefix: str = "") -> tuple[dict[str, np.ndarray], dict]:
        """``(arrays, meta)`` for :func:`sea_daemon.io.modelfile.save_model`: numeric arrays
        (tree, leaf data, hyperparameters) named with ``prefix``, and a JSON-able ``meta``
        (options, counters, random state).  Inverse: :meth:`from_arrays`."""
        d = self.to_dict()
        leaves = d.pop("leaves")
        tree = d.pop("tree")
        p = self.input_dim + 2
        L = len(leaves)
        ns = [len(lf["gp"]["y"]) for lf in leaves]
        X = np.empty((sum(ns), self.input_dim))
        y = np.empty(sum(ns))
        theta = np.empty((L, p))
        center = np.full((L, self.input_dim), np.nan)
        adam = np.full((L, 1 + 2 * p), np.nan)
        off = 0
        for i, lf in enumerate(leaves):
            g = self._gp[lf["node"]]
            n = g.n_
            X[off:off + n], y[off:off + n] = g.X_[:n], g.y_[:n]
            off += n
            theta[i, 0], theta[i, 1:p - 1], theta[i, p - 1] = g.sigma_f, g.lengthscales, g.sigma_n
            if g.center_ is not None:
                center[i] = g.center_
            if lf["adam"] is not None:
                adam[i] = lf["adam"]
        arrays = {"tree_dim": np.asarray(tree["dim"], dtype=np.int64),
                  "tree_lo": np.asarray(tree["lo"], dtype=float),
                  "tree_hi": np.asarray(tree["hi"], dtype=float),
                  "tree_left": np.asarray(tree["left"], dtype=np.int64),
                  "tree_right": np.asarray(tree["right"], dtype=np.int64),
                  "leaf_node": np.asarray([lf["node"] for lf in leaves], dtype=np.int64),
                  "leaf_n": np.asarray(ns, dtype=np.int64), "leaf_hyp": theta,
                  "leaf_center": center, "leaf_adam": adam, "X": X, "y": y}
        return {prefix + k: v for k, v in arrays.items()}, d

    @classmethod
    def from_arrays(cls, arrays: dict, meta: dict, prefix: str = "") -> "LoGGPState":
        """Inverse of :meth:`to_arrays` (raises ModelFileError on malformed input)."""
        try:
            a = {k[len(prefix):]: np.asarray(v) for k, v in arrays.items() if k.startswith(prefix)}
            d = dict(meta)
            d["tree"] = {k: a["tree_" + k].tolist() for k in ("dim", "lo", "hi", "left", "right")}
            dim_in = int(d["options"]["input_dim"])
            leaves, off = [], 0
            opts = d["options"]
            for i, node in enumerate(a["leaf_node"].tolist()):
                n = int(a["leaf_n"][i])
                t = a["leaf_hyp"][i]                 # [σ_f, l_1 … l_ρ, σ_on]
                c = a["leaf_center"][i]
                ad = a["leaf_adam"][i]
                leaves.append({"node": node, "adam": None if np.isnan(ad).all() else ad.tolist(),
                               "gp": {"input_dim": dim_in, "sigma_f": float(t[0]),
                                      "lengthscales": t[1:dim_in + 1].tolist(),
                                      "sigma_n": float(t[dim_in + 1]),
                                      "jitter": opts.get("jitter", 1e-10),
                                      "max_capacity": opts["max_points"],
                                      "center": None if np.isnan(c).any() else c.tolist(),
                                      "X": a["X"][off:off + n].tolist(), "y": a["y"][off:off + n].tolist()}})
                off += n
            d["leaves"] = leaves
        except (KeyError, IndexError, TypeError, ValueError) as e:
            raise ModelFileError(f"LoG-GP model arrays are malformed: {e}") from None
        return cls.from_dict(d)

    @classmethod
    def from_dict(cls, d: dict) -> "LoGGPState":
        """Inverse of :meth:`to_dict` (raises ModelFileError on a malformed dict: a tree that is
        not a proper tree (:func:`check_tree`), leaves that do not match it, values that are not
        finite)."""
        try:
            if d.get("format") != _FORMAT or d.get("version") != _VERSION:
                raise ModelFileError(f"not a LoG-GP model of version {_VERSION}: "
                                     f"format {d.get('format')!r}, version {d.get('version')!r}")
            self = cls(**d["options"])
            tree_leaves = self._restore_tree(d["tree"])
            self._restore_leaves(d["leaves"], tree_leaves)
            self._restore_counters(d, tree_leaves)
            return self
        except ModelFileError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, OverflowError, InputError) as e:
            raise ModelFileError(f"LoG-GP model is malformed: {e}") from None

    def _restore_tree(self, t: dict) -> set:
        """The tree's lists from ``t``, checked (:func:`check_tree`); the set of its leaf nodes."""
        lists = [list(t[k]) for k in ("dim", "lo", "hi", "left", "right")]
        if len(lists[0]) > 2 * MAX_LEAVES:
            raise ModelFileError(f"LoG-GP model: {len(lists[0])} tree nodes, allowed <= {2 * MAX_LEAVES}")
        tree_leaves = set(check_tree(*lists, self.input_dim))
        most = min(MAX_LEAVES, self.max_leaves or MAX_LEAVES)
        if len(tree_leaves) > most:
            raise ModelFileError(f"LoG-GP model: {len(tree_leaves)} leaves, allowed <= {most}")
        self._dim, self._left, self._right = ([int(v) for v in lists[k]] for k in (0, 3, 4))
        self._lo, self._hi = ([float(v) for v in lists[k]] for k in (1, 2))
        return tree_leaves

    def _restore_leaves(self, leaves: list, tree_leaves: set) -> None:
        """Every leaf's GP (one per leaf node of the tree, finite data within ``max_points``)."""
        self._gp = [None] * len(self._dim)
        self._adam = {}
        for leaf in leaves:
            node = _index(leaf["node"])
            if node not in tree_leaves or self._gp[node] is not None:
                raise ModelFileError(f"LoG-GP model: leaf data for node {node}, which is not a leaf "
                                     "of the tree or has data twice")
            most, n = min(self.max_points, MAX_LEAF_POINTS), len(leaf["gp"]["y"])
            if n > most or leaf["gp"]["input_dim"] != self.input_dim:      # before its O(N³) factor
                raise ModelFileError(f"LoG-GP model: leaf {node} holds {n} points of {leaf['gp']['input_dim']!r} "
                                     f"inputs; allowed <= {most} points of {self.input_dim}")
            g = IncrementalGP.from_dict(leaf["gp"])
            if not (np.all(np.isfinite(g.X_[:g.n_])) and np.all(np.isfinite(g.y_[:g.n_]))):
                raise ModelFileError(f"LoG-GP model: leaf {node} holds a value that is not finite")
            g.max_capacity = self.max_points
            g.clip_mean = self.clip_leaf_mean
            self._gp[node] = g
            if leaf.get("adam") is not None:
                self._adam[node] = self.hyper.state_from_dict(leaf["adam"])
        if len(leaves) != len(tree_leaves):
            raise ModelFileError(f"LoG-GP model: {len(leaves)} leaves of data, the tree has {len(tree_leaves)}")
        self.n_leaves = len(leaves)

    def _restore_counters(self, d: dict, tree_leaves: set) -> None:
        """Counters, the pending hyperparameter step and the random state."""
        c = d["counters"]
        self.n_points, self.n_updates = int(c["n_points"]), int(c["n_updates"])
        self.n_evicted, self.n_hyper_steps = int(c["n_evicted"]), int(c["n_hyper_steps"])
        self.last_leaf = _index(c["last_leaf"])
        if self.last_leaf not in tree_leaves:
            self.last_leaf = min(tree_leaves)
        self._hyper_due = bool(c.get("hyper_due", False))
        pend = d.get("pending")
        self.hyper_proposal = None if pend is None else (_index(pend[0]), np.asarray(pend[1], dtype=float))
        if pend is not None and (self.hyper_proposal[0] not in tree_leaves
                                 or self.hyper_proposal[1].shape != self._theta0.shape):
            raise ModelFileError("LoG-GP model: the pending hyperparameter step names no leaf of the tree")
        rs = d["rng_state"]
        self._rng.setstate((rs[0], tuple(rs[1]), rs[2]))
