"""Persistence of the LoG-GP (:class:`~sea_daemon.core.gp.loggp.LoGGP`): its whole state as a
JSON-able dict or as numeric arrays plus JSON metadata (no numpy objects, no pickle), and back.

The factors are not stored: every leaf's Cholesky factor is rebuilt from its data on load, so
a loaded model predicts exactly as the saved one (tests/test_loggp.py).  Malformed input raises
:class:`~sea_daemon.errors.ModelFileError`.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.gp.exact import IncrementalGP
from sea_daemon.errors import InputError, ModelFileError

_FORMAT = "sea-daemon-loggp"
_VERSION = 1


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
        """Inverse of :meth:`to_dict` (raises ModelFileError on a malformed dict)."""
        try:
            if d.get("format") != _FORMAT or d.get("version") != _VERSION:
                raise ModelFileError(f"not a LoG-GP model of version {_VERSION}: "
                                     f"format {d.get('format')!r}, version {d.get('version')!r}")
            self = cls(**d["options"])
            t = d["tree"]
            self._dim, self._lo, self._hi = list(t["dim"]), list(t["lo"]), list(t["hi"])
            self._left, self._right = list(t["left"]), list(t["right"])
            self._gp = [None] * len(self._dim)
            self._adam = {}
            for leaf in d["leaves"]:
                node = int(leaf["node"])
                g = IncrementalGP.from_dict(leaf["gp"])
                g.max_capacity = self.max_points
                g.clip_mean = self.clip_leaf_mean
                self._gp[node] = g
                if leaf.get("adam") is not None:
                    self._adam[node] = self.hyper.state_from_dict(leaf["adam"])
            if any((self._dim[i] < 0) != (self._gp[i] is not None) for i in range(len(self._dim))):
                raise ModelFileError("LoG-GP model: leaves and tree do not match")
            self.n_leaves = len(d["leaves"])
            c = d["counters"]
            self.n_points, self.n_updates = int(c["n_points"]), int(c["n_updates"])
            self.n_evicted, self.n_hyper_steps = int(c["n_evicted"]), int(c["n_hyper_steps"])
            self.last_leaf = int(c["last_leaf"])
            self._hyper_due = bool(c.get("hyper_due", False))
            pend = d.get("pending")
            self.hyper_proposal = None if pend is None else (int(pend[0]), np.asarray(pend[1], dtype=float))
            rs = d["rng_state"]
            self._rng.setstate((rs[0], tuple(rs[1]), rs[2]))
            return self
        except ModelFileError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, InputError) as e:
            raise ModelFileError(f"LoG-GP model is malformed: {e}") from None

