"""Data generation and model inference for the load-side residual (Sec. IV-A).

* :func:`training_pairs` — training data ``{(z_k, f_k)}`` with ``z = [q, q̇, q̈]`` and
  ``f(z) = τ_m − (τ_l(z) + J θ̈_m + D_m θ̇_m)`` (``eq:loadsidewmotor`` under
  ``ass:passive_human``: τ_h,act = 0 during training), from causal kinematics, through
  :meth:`sea_daemon.core.model.SEAModel.residual_from_kinematics`.
* :func:`training_pairs_from_log` — the same from a measured log (docs/interfaces.md §1): encoder
  offsets removed, kinematics by the causal differentiator the estimator uses
  (:class:`sea_daemon.core.kinematics.CausalDifferentiator`, Sec. V-A) or, offline, zero-phase
  smoothing, and a declared torque delay applied.
* :class:`ResidualGP` — one LoG-GP per joint (an independent GP per target dimension, Sec.
  IV-A), exposing the GP-AKF's residual hook ``predict(z) -> (μ (n,), ∂μ/∂z (n, 3n), σ² (n,))``
  (``alg:torqueresidualAKF`` line 5, ``eq:moejac``) and ``update(z, f)``; it records which
  directions of motion its training pairs covered (:attr:`ResidualGP.directions`).

Pure: no I/O, no clock, no threads.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.config import LearningConfig, ModelConfig
from sea_daemon.errors import InputError, ModelFileError
from sea_daemon.core.gp.loggp import LoGGP
from sea_daemon.core.config import KinematicsConfig
from sea_daemon.core.kinematics import CausalDifferentiator, smooth_derivatives


def _cols(name: str, a, N: int | None, n: int) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 1 and n == 1:
        a = a[:, None]
    if a.ndim != 2 or a.shape[1] != n or (N is not None and a.shape[0] != N):
        raise InputError(f"{name} must have shape (N, {n}){'' if N is None else f' with N = {N}'}, "
                         f"got {a.shape}")
    return a


def training_pairs(model, q, dq, ddq, theta_m, dtheta_m, ddtheta_m, tau_m):
    """Training inputs ``Z`` (N, 3n) and targets ``F`` (N, n) from kinematics and motor torque.

    All arguments are (N, n) arrays (or (N,) for one joint), joint side, SI: load angle ``q``
    and its causal derivatives, motor angle ``θ_m`` and its derivatives, and the motor torque
    that acted on the motor side at each sample (apply any declared delay before calling).
    """
    n = model.n
    q = _cols("q", q, None, n)
    N = q.shape[0]
    dq, ddq = _cols("dq", dq, N, n), _cols("ddq", ddq, N, n)
    th, dth, ddth = (_cols("theta_m", theta_m, N, n), _cols("dtheta_m", dtheta_m, N, n),
                     _cols("ddtheta_m", ddtheta_m, N, n))
    tau = _cols("tau_m", tau_m, N, n)
    # z = [q, q̇, q̈] (Sec. IV-A)
    Z = np.hstack([q, dq, ddq])
    F = np.empty((N, n))
    for k in range(N):
        # eq:loadsidewmotor with ass:passive_human (τ_h,act = 0)
        F[k] = model.residual_from_kinematics(q[k], dq[k], ddq[k], th[k], dth[k], ddth[k], tau[k])
    return Z, F


def training_pairs_from_log(model, log, kinematics=None, causal: bool = True, skip: int | None = None):
    """``(Z, F)`` from a passive-human log (ass:passive_human) for ``model`` (an SEAModel).

    ``kinematics``: a :class:`~sea_daemon.core.config.KinematicsConfig` (default: its defaults).
    ``causal``: differentiate online as the estimator does (the GP then sees the same
    kinematics in training and in estimation); ``False``: offline zero-phase smoothing.
    ``skip``: initial samples dropped while the causal filter fills (default: its length).
    """

    kc = kinematics or KinematicsConfig()
    n = model.n
    q, th = model.correct_measurement(np.asarray(log.q, dtype=float), np.asarray(log.theta_m, dtype=float))
    q, th = _cols("q", q, None, n), _cols("theta_m", th, None, n)
    t = np.asarray(log.t, dtype=float)
    N = t.shape[0]
    if causal:
        diff = CausalDifferentiator(log.dt, kc.window, 2 * n, kc.method, kc.degree)
        kin = np.empty((N, 3, 2 * n))
        for k in range(N):
            a, v, acc = diff.update(np.concatenate([q[k], th[k]]))
            kin[k, 0], kin[k, 1], kin[k, 2] = a, v, acc
        qa, dq, ddq = kin[:, 0, :n], kin[:, 1, :n], kin[:, 2, :n]
        tha, dth, ddth = kin[:, 0, n:], kin[:, 1, n:], kin[:, 2, n:]
        skip = diff.L if skip is None else int(skip)
    else:
        qa, dq, ddq = (np.asarray(a).reshape(N, n) for a in smooth_derivatives(t, q))
        tha, dth, ddth = (np.asarray(a).reshape(N, n) for a in smooth_derivatives(t, th))
        skip = 0 if skip is None else int(skip)
    tau = _cols("tau_m", log.tau_m, N, n).copy()
    for j in range(n):
        if model.delay[j] > 0:
            # a declared delay: the motor side felt τ_m(t − delay)
            tau[:, j] = np.interp(t - model.delay[j], t, tau[:, j])
    Z, F = training_pairs(model, qa, dq, ddq, tha, dth, ddth, tau)
    return Z[skip:], F[skip:]


#: [rad/s] a training pair moves joint j up (down) when q̇_j > DIRECTION_SPEED (< −DIRECTION_SPEED)
DIRECTION_SPEED = 0.03
#: training pairs moving one way a direction needs to count as covered (0.5 s of pairs at 100 Hz)
DIRECTION_MIN_PAIRS = 50


class ResidualGP:
    """One :class:`LoGGP` per joint on the common input ``z = [q, q̇, q̈]`` (3n).

    ``ResidualGP(n, learning)`` with a :class:`~sea_daemon.core.config.LearningConfig`; keyword
    ``overrides`` are passed to every :class:`LoGGP` (e.g. ``hyper_every``).  Joint ``i`` uses
    seed ``learning.seed + i``.

    ``directions`` (n, 2) int: per joint, the training pairs moving down (q̇_j < −
    :data:`DIRECTION_SPEED`) and up (q̇_j > :data:`DIRECTION_SPEED`), counted by every
    :meth:`update` and :meth:`note_direction`; None for a model saved without the record (it
    counts nothing and :meth:`off_direction` is always False).  A direction is covered with at
    least :data:`DIRECTION_MIN_PAIRS` pairs: friction changes sign with q̇, and a GP that
    learned one way only would carry that friction across q̇ = 0 with the wrong sign, so where
    a joint moves the way its pairs did not cover while they covered the other
    (:meth:`off_direction`), the GP-AKF's hooks use the physical model alone.  A joint covered
    neither way (pairs at rest only) learned no sign of friction: its GP stays as weighted
    by its variance.
    """

    def __init__(self, n: int, learning: LearningConfig | None = None, **overrides):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise InputError(f"joints must be an integer >= 1, got {n!r}")
        self.n = int(n)
        lc = learning or LearningConfig()
        ls = lc.lengthscales
        if len(ls) == 3 and self.n > 1:              # one triple [q, q̇, q̈] for every joint
            ls = tuple(np.repeat(np.asarray(ls, dtype=float), self.n))
        if len(ls) != 3 * self.n:
            raise InputError(f"learning.lengthscales must have 3 or {3 * self.n} entries, got {len(ls)}")
        opts = dict(max_points=lc.max_points, max_leaves=lc.max_leaves, overlap=lc.overlap,
                    lengthscales=list(ls), sigma_f=lc.sigma_f, sigma_n=lc.sigma_n,
                    hyperopt=lc.hyperopt, extrapolation_scale=lc.extrapolation_scale,
                    clip_leaf_mean=lc.clip_leaf_mean, split_in_lengthscales=lc.split_in_lengthscales)
        opts.update(overrides)
        self.gps = [LoGGP(3 * self.n, seed=lc.seed + i, **opts) for i in range(self.n)]
        self._init_directions(np.zeros((self.n, 2), dtype=np.int64))

    def _init_directions(self, counts, speed: float = DIRECTION_SPEED, least: int = DIRECTION_MIN_PAIRS) -> None:
        self.directions = counts
        self.direction_speed = speed
        self.direction_min_pairs = least
        self._covered = np.ones((self.n, 2), dtype=bool)
        self._gated = np.zeros((self.n, 2), dtype=bool)
        self.gated = False
        if counts is not None:
            self._judge()

    def _judge(self) -> None:
        """Covered: at least ``direction_min_pairs`` pairs; gated: not covered while the other way
        is (the GP learned one way only: what it learned has the sign of that way)."""
        self._covered[:] = self.directions >= self.direction_min_pairs
        self._gated[:] = ~self._covered & self._covered[:, ::-1]
        self.gated = bool(self._gated.any())

    def note_direction(self, z) -> None:
        """Count the training pair at ``z`` in :attr:`directions` (nothing without the record)."""
        c = self.directions
        if c is None:
            return
        n, s = self.n, self.direction_speed
        for j in range(n):
            v = z[n + j]
            if v > s:
                c[j, 1] += 1
                if c[j, 1] == self.direction_min_pairs:
                    self._judge()
            elif v < -s:
                c[j, 0] += 1
                if c[j, 0] == self.direction_min_pairs:
                    self._judge()

    def off_direction(self, z) -> bool:
        """Whether some joint moves at ``z`` (q̇ beyond :data:`DIRECTION_SPEED`) in a direction
        the training pairs did not cover while they covered the other (allocation-free; False
        without the record)."""
        if not self.gated:
            return False
        n, s, g = self.n, self.direction_speed, self._gated
        for j in range(n):
            v = z[n + j]
            if (v > s and g[j, 1]) or (v < -s and g[j, 0]):
                return True
        return False

    def directions_record(self) -> dict | None:
        """The record as plain values (the model file's ``directions``; None without it)."""
        if self.directions is None:
            return None
        return {"speed": float(self.direction_speed), "min_pairs": int(self.direction_min_pairs),
                "pairs_down_up": self.directions.tolist(), "covered_down_up": self._covered.tolist()}

    def _load_directions(self, rec) -> None:
        """:meth:`directions_record` back (None: a model saved without it, no record)."""
        if rec is None:
            self._init_directions(None)
            return
        c = np.asarray(rec["pairs_down_up"], dtype=np.int64)
        if c.shape != (self.n, 2) or np.any(c < 0):
            raise ValueError(f"directions: pairs_down_up must be ({self.n}, 2) counts >= 0, got {c.tolist()}")
        speed, least = float(rec["speed"]), int(rec["min_pairs"])
        if not (np.isfinite(speed) and speed >= 0.0 and least >= 1):
            raise ValueError(f"directions: speed {speed} (>= 0) and min_pairs {least} (>= 1) expected")
        self._init_directions(c, speed, least)

    @classmethod
    def from_config(cls, cfg: ModelConfig, **overrides) -> "ResidualGP":
        return cls(cfg.joints, cfg.learning, **overrides)

    def _z(self, z) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        if z.shape != (3 * self.n,):
            raise InputError(f"z must have shape ({3 * self.n},) = [q, dq, ddq], got {z.shape}")
        return z

    def predict(self, z):
        """``(μ (n,), ∂μ/∂z (n, 3n), σ² (n,))`` at ``z`` (alg:torqueresidualAKF line 5)."""
        z = self._z(z)
        n = self.n
        mu = np.empty(n)
        var = np.empty(n)
        jac = np.empty((n, 3 * n))
        for i, gp in enumerate(self.gps):
            # eq:GPmean, eq:GPvariance, eq:moejac (merged over the leaves z reaches)
            mu[i], var[i], jac[i] = gp.predict_with_grad(z)
        return mu, jac, var

    def update(self, z, f) -> None:
        """Add one training pair: ``z`` (3n,), ``f`` (n,) (one target per joint's GP)."""
        z = self._z(z)
        f = np.atleast_1d(np.asarray(f, dtype=float))
        if f.shape != (self.n,):
            raise InputError(f"f must have shape ({self.n},), got {f.shape}")
        for i, gp in enumerate(self.gps):
            gp.update(z, f[i])
        self.note_direction(z)

    def train(self, Z, F) -> None:
        """Stream a batch of pairs ``Z`` (N, 3n), ``F`` (N, n) through :meth:`update`."""
        Z = _cols("Z", Z, None, 3 * self.n)
        F = _cols("F", F, Z.shape[0], self.n)
        for z, f in zip(Z, F):
            self.update(z, f)

    @property
    def n_points(self) -> int:
        return self.gps[0].n_points

    def to_dict(self) -> dict:
        """JSON-serialisable state (no numpy, no pickle)."""
        d = {"format": "sea-daemon-residual-gp", "version": 1, "joints": self.n,
             "gps": [gp.to_dict() for gp in self.gps]}
        if self.directions is not None:
            d["directions"] = self.directions_record()
        return d

    def to_arrays(self) -> tuple[dict[str, np.ndarray], dict]:
        """``(arrays, meta)`` for :func:`sea_daemon.io.modelfile.save_model` (joint i's arrays are
        prefixed ``gp{i}_``).  Inverse: :meth:`from_arrays`."""
        arrays, metas = {}, []
        for i, gp in enumerate(self.gps):
            a, m = gp.to_arrays(prefix=f"gp{i}_")
            arrays.update(a)
            metas.append(m)
        meta = {"format": "sea-daemon-residual-gp", "version": 1, "joints": self.n, "gps": metas}
        if self.directions is not None:
            meta["directions"] = self.directions_record()
        return arrays, {"residual_gp": meta}

    @classmethod
    def from_arrays(cls, arrays: dict, meta: dict) -> "ResidualGP":
        try:
            m = meta["residual_gp"]
            if m.get("format") != "sea-daemon-residual-gp" or m.get("version") != 1:
                raise ModelFileError(f"not a residual-GP model of version 1: format {m.get('format')!r}")
            self = cls.__new__(cls)
            self.n = int(m["joints"])
            self.gps = [LoGGP.from_arrays(arrays, g, prefix=f"gp{i}_") for i, g in enumerate(m["gps"])]
            self._load_directions(m.get("directions"))
        except (KeyError, TypeError, ValueError) as e:
            raise ModelFileError(f"residual-GP model is malformed: {e}") from None
        if len(self.gps) != self.n or any(g.input_dim != 3 * self.n for g in self.gps):
            raise ModelFileError("residual-GP model: number or input size of the GPs does not match joints")
        return self

    @classmethod
    def from_dict(cls, d: dict) -> "ResidualGP":
        try:
            if d.get("format") != "sea-daemon-residual-gp" or d.get("version") != 1:
                raise ModelFileError(f"not a residual-GP model of version 1: format {d.get('format')!r}")
            self = cls.__new__(cls)
            self.n = int(d["joints"])
            self.gps = [LoGGP.from_dict(g) for g in d["gps"]]
            self._load_directions(d.get("directions"))
            if len(self.gps) != self.n or any(g.input_dim != 3 * self.n for g in self.gps):
                raise ModelFileError("residual-GP model: number or input size of the GPs does not match joints")
            return self
        except (KeyError, TypeError, ValueError) as e:
            raise ModelFileError(f"residual-GP model is malformed: {e}") from None
