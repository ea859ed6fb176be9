"""Theorem-1 bound attached to a running (GP-)AKF: ``tau_h_act_bound`` becomes ρ_k.

:func:`attach_theorem_bound` wraps an :class:`~sea_daemon.estimators.akf.AKF` instance (plain
AKF or GP-AKF: an AKF with a residual) without changing its class: after every filter step
it propagates the set of means with :class:`SetMembershipBound`, using what the AKF keeps
per step — ``A_k`` (continuous Jacobian at x̂_{k−1}), ``F_k``, ``Gamma_mu`` (∫e^{As}ds I_μ M⁻¹),
``K_k``, ``H``, ``P`` — and overwrites ``est.tau_h_act_bound`` with ρ_k.

Per step (k−1 → k), with u the applied input and ẑ's measured q̈ held:
* C_{k−1} = E(x̂_{k−1}, X̂_{k−1}) ⊕ E(0, s_d P_{k−1})   (outer ellipsoid, trace-minimal)
* the GP-enhanced drift f(x) = f_nom(x, u) − I_μ M⁻¹ μ(z(x)) (eq:fwdynwtorqueresidual1) on the
  point set of C_{k−1}; continuous-time linearisation error ε_c = f(x) − f(x̂) − A_k (x − x̂)
  per dimension (max over the points, inflated by ``margin``), mapped by Φ = ∫₀^dt e^{A s} ds
* GP error (eq:Dmuhat): η_j = √β_j max_points σ_j(z(x)) + γ_j per joint — σ is taken over
  the whole set C_{k−1} (not just at ẑ), because the true z is only known to lie in it;
  mapped by Γ_μ
* X̂_k⁻ = F X̂ Fᵀ ⊕ Γ_μ box(η) ⊕ Φ box(b);  X̂_k = (I − K H) X̂⁻ (I − K H)ᵀ;  ρ_k.

Without a residual (plain AKF) there is no GP term and the whole δ goes to the Gaussian part.
With one, δ_GP (default δ/2) is the failure probability the caller used for the GP
constants (:func:`gp_constants`); ρ then holds with probability ≥ 1 − δ.
States whose z leaves the GP constants' input box have no GP guarantee: such steps are
counted in ``bound.gp_box_violations_`` (and ρ is still published).
"""
from __future__ import annotations

import numpy as np

from .gp_bound import BoundConstants, error_bound, input_box, loggp_leaves
from .setmember import SetMembershipBound, input_matrix


class AKFTheoremBound:
    """The Theorem-1 companion of one AKF instance (see module docstring)."""

    def __init__(self, akf, *, gp_constants: list[BoundConstants] | str | None = None,
                 gp_box: tuple[np.ndarray, np.ndarray] | None = None, delta: float | None = None,
                 delta_gp: float | None = None, n_dirs: int = 2, margin: float = 0.25,
                 projection: str = "state", seed: int = 0):
        self.akf = akf
        n, d = akf.n, akf.d
        delta = akf.delta if delta is None else float(delta)
        has_gp = akf.residual is not None
        if delta_gp is None:
            delta_gp = 0.5 * delta if has_gp else 0.0
        if has_gp and gp_constants is None:
            raise ValueError("a GP-AKF needs gp_constants (a list, or 'auto' for a ResidualGP; "
                             "see sea_daemon.bounds.akf_bound.gp_constants)")
        self._auto = has_gp and isinstance(gp_constants, str)
        if self._auto and gp_constants != "auto":
            raise ValueError(f"gp_constants must be a list of BoundConstants or 'auto', got {gp_constants!r}")
        self.gp_constants = (list(gp_constants) if (has_gp and not self._auto) else None)
        self.gp_box = gp_box
        self.sm = SetMembershipBound(d, np.arange(4 * n, 5 * n), delta, delta_gp=delta_gp if has_gp else 0.0,
                                     n_dirs=n_dirs, margin=margin, seed=seed, projection=projection)
        self._I = np.eye(d)
        self._step = akf.step
        self._reset = akf.reset
        self.gp_box_violations_ = 0
        self.eta_ = np.zeros(n)
        self.lin_err_ = np.zeros(d)

    # ------------------------------------------------------------------ hooks

    def refresh_gp_constants(self) -> None:
        """Recompute the GP constants and input box from the residual's current leaves
        (``gp_constants='auto'``; call after the GP learned more data)."""
        self.gp_constants, self.gp_box = gp_constants(self.akf.residual, self.sm.delta_gp)

    def reset(self, *args, **kwargs):
        est = self._reset(*args, **kwargs)
        if self._auto:
            # 'auto': the constants of the GP as trained when estimation starts
            self.refresh_gp_constants()
        self.sm.reset()
        self.gp_box_violations_ = 0
        if getattr(self.akf, "_ready", True):
            est.tau_h_act_bound[:] = self.sm.rho(self.akf.P)
        return est

    def _drift(self, x: np.ndarray, u: np.ndarray, ddq: np.ndarray):
        """f(x) of eq:fwdynwtorqueresidual1 and σ(z(x)) (zeros without a residual)."""
        akf = self.akf
        n = akf.n
        f = akf.model.f_nom(x, u)
        if akf.residual is None:
            return f, None, None
        z = np.concatenate([x[:n] + x[n:2 * n], x[2 * n:3 * n] + x[3 * n:4 * n], ddq])
        mu, _, var = akf.residual.predict(z)
        return f - akf.G_mu @ np.asarray(mu, dtype=float), np.sqrt(np.maximum(np.asarray(var, float), 0.0)), z

    def step(self, y, u, dt):
        akf = self.akf
        n = akf.n
        x0 = akf.x.copy()
        P0 = akf.P.copy()
        ddq = akf.z[2 * n:].copy()
        u = np.array(u, dtype=float)
        est = self._step(y, u, dt)
        A = akf.A_k
        sm = self.sm
        # C_{k−1} and its point set
        C = sm.confidence_set(x0, P0)
        pts = sm.sample_points(C)
        f0, s0, _ = self._drift(x0, u, ddq)
        b = np.zeros(akf.d)
        smax = None if s0 is None else s0.copy()
        out_of_box = False
        for x in pts:
            fx, sx, z = self._drift(x, u, ddq)
            lin = A @ (x - x0)
            r = fx - f0 - lin
            # rounding floor, so an exactly linear drift gives exactly 0
            tol = 1e-12 * (np.abs(fx) + np.abs(f0) + np.abs(lin))
            np.maximum(b, np.where(np.abs(r) <= tol, 0.0, np.abs(r)), out=b)
            if sx is not None:
                np.maximum(smax, sx, out=smax)
                if self.gp_box is not None and (np.any(z < self.gp_box[0]) or np.any(z > self.gp_box[1])):
                    out_of_box = True
        self.gp_box_violations_ += int(out_of_box)
        b *= 1.0 + sm.margin
        self.lin_err_ = b
        Phi = input_matrix(A, self._I, dt) if np.any(b) else None
        eta = None
        if self.gp_constants is not None:
            # eq:gpmeanbounds → lem:interval_bound: η_j = √β_j σ_j + γ_j
            eta = np.array([c.eta(s) for c, s in zip(self.gp_constants, smax)])
            self.eta_ = eta
        # eq:predwLinErrsetandGPerrset, then the filter step on the set
        sm.predict(akf.F_k, Gamma=akf.Gamma_mu, eta=eta, lin_err_box=b if np.any(b) else None, Phi=Phi)
        sm.update(akf.K_k, akf.H)
        est.tau_h_act_bound[:] = sm.rho(akf.P)
        return est


def attach_theorem_bound(akf, **kwargs) -> AKFTheoremBound:
    """Make ``akf.update``/``akf.step``/``akf.reset`` publish the Theorem-1 ρ_k as
    ``tau_h_act_bound`` (instance attributes shadow the class methods; the AKF code is
    unchanged).  Returns the :class:`AKFTheoremBound` (also at ``akf.theorem_bound``)."""
    tb = AKFTheoremBound(akf, **kwargs)
    akf.step = tb.step
    akf.reset = tb.reset
    akf.theorem_bound = tb
    return akf.theorem_bound


def attach_default_bound(akf) -> AKFTheoremBound | None:
    """What :func:`sea_daemon.estimators.make_estimator` attaches: the Theorem-1 bound for a
    plain AKF, and for a GP-AKF whose residual is a ResidualGP (one LoG-GP per joint, constants
    computed at every reset).  An unknown residual type has no GP error constants, so the
    AKF keeps its own bound and None is returned."""
    if akf.residual is None:
        return attach_theorem_bound(akf)
    if hasattr(akf.residual, "gps"):
        return attach_theorem_bound(akf, gp_constants="auto")
    return None


def gp_constants(residual, delta_gp: float, *, L_f=None, lipschitz_share: float = 0.1,
                 n_leaves: int | None = None, box_margin: float = 0.1, sigma_ref: float | None = None):
    """GP error constants per joint for a :class:`sea_daemon.learning.ResidualGP` (one LoG-GP per joint).

    δ_GP is split over the n joints' GPs (union bound); within each, a share
    ``lipschitz_share`` goes to LUH19 Thm 3.2 (unless ``L_f`` is given) and the rest to the
    union over the leaves (``n_leaves``, default the LoG-GP's ``max_leaves`` cap, so the
    constants stay valid while the tree grows).  The input box is the box of all training
    points widened by ``box_margin`` of its range.  Returns (constants list, (lo, hi)).
    """
    gps = residual.gps
    n = len(gps)
    per_joint = delta_gp / n
    Z = np.vstack([np.asarray(gp.leaf(node).X_[:gp.leaf(node).n_]) for gp in gps for node in gp.leaves()
                   if gp.leaf(node).n_ > 0])
    lo, hi = input_box(Z, box_margin)
    consts = []
    for gp in gps:
        leaves = loggp_leaves(gp)
        L = n_leaves if n_leaves is not None else max(len(leaves), int(getattr(gp, "max_leaves", 0) or 0))
        kw = dict(L_f=L_f) if L_f is not None else dict(delta_lipschitz=lipschitz_share * per_joint)
        consts.append(error_bound(leaves, lo, hi, per_joint, n_leaves=L, sigma_ref=sigma_ref, **kw))
    return consts, (lo, hi)
