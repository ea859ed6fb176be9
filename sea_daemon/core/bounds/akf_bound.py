"""Theorem-1 bound of a (GP-)AKF: its ``tau_h_act_bound`` becomes ρ_k.

:class:`AKFTheoremBound` is the bound component (:class:`~sea_daemon.core.estimators.base.Bound`)
of one :class:`~sea_daemon.core.estimators.akf.AKF` (plain AKF or GP-AKF: an AKF with a
residual), given at its construction (``AKF(cfg, bound=theorem_bound)``; :func:`theorem_bound`
is the default the estimator factory uses).  The AKF hands it every filter step's
:class:`~sea_daemon.core.estimators.record.StepRecord`: it propagates the set of means with
:class:`SetMembershipBound`, using the record's x̂_{k−1}, P_{k−1}, u, ẑ_{k−1}, μ(ẑ), ∂μ/∂z,
``A_k``, ``F_k``, ``Gamma_mu`` (∫e^{As}ds I_μ M⁻¹), ``K_k``, ``P``, ``Sigma_nom`` and the filter's
constants (``H``, R, the model, δ), and overwrites ``est.tau_h_act_bound`` with ρ_k.

Per step (k−1 → k), with u the applied input and ẑ's measured q̈ held:
* C_{k−1} = E(x̂_{k−1}, X̂_{k−1}) ⊕ E(0, s_d P_{k−1})   (outer ellipsoid, trace-minimal)
* continuous-time linearisation error ε_c = f(x) − f(x̂) − A_k (x − x̂) of the GP-enhanced
  drift f(x) = f_nom(x, u) − I_μ M⁻¹ μ(z(x)) (eq:fwdynwtorqueresidual1), per dimension, as the
  sum of two parts, mapped by Φ = ∫₀^dt e^{A s} ds:
  - nominal model: without declared effects its only non-linearity is gravity, bounded
    analytically and rigorously (Lagrange remainder, :meth:`AKFTheoremBound._gravity_box`);
    with declared effects, sampled over the point set of C_{k−1} (+ ``margin``);
  - GP mean: |μ(z) − μ̄(z)| (μ̄ the filter's linear model at ẑ) sampled over the points of the
    projection of C_{k−1} on (q, q̇) (+ ``margin``)
* GP error (eq:Dmuhat): √β_j s_j(z) + γ_j at the same points — s = σ (LUH19) or the local scale
  √(σ² + s_loc²) (conformal / configured β, gp_bound.LocalScale) at unclipped z (not just at
  ẑ), because the true z is only known to lie in the set.  The GP error and the GP mean's
  linearisation error are one torque error f − μ̄ at the true z, entering through Γ_μ:
  η_j = max over the points of their sum (docs/bounds.md §4).  ``gp_beta`` (default
  ``estimator.gp_beta``): 'lederer' or a number
* without declared effects ε and η depend on x only through q and (q, q̇): the set they are
  bounded over is T·C_{k−1} with s = χ²_m(1 − δ_N), m = n (no GP) or 2n, not s_d = χ²_5n
* declared human-torque rate r = ``estimator.tau_h_act_rate`` (docs/bounds.md §6),
  |dτ_h,act/dt| ≤ r: one more bounded input, Γ_τ box(r), Γ_τ = ∫₀^dt e^{As} ds E_τ; the integrated
  walk's (``tau_h_act_model``) |d²τ_h,act/dt²| ≤ a = ``tau_h_act_accel`` instead, E_τ̇ (its τ̇ rows)
* X̂_k⁻ = F X̂ Fᵀ ⊕ Γ_μ box(η) ⊕ Γ_τ box(r) ⊕ Φ box(b);  X̂_k = (I − K H) X̂⁻ (I − K H)ᵀ;  ρ_k.
* the range form (zonotope sets): the declared Coulomb/Stribeck friction and the GP mean
  linearised at zero slope instead of the filter's — the set propagated with the filter's
  transition minus their slopes, F_B = F − Σ Φc s_g ℓᵀ + Γ_μ J T, their errors bounded by the
  range over the set (friction: interval arithmetic; GP mean: max |μ(z) − μ(ẑ)| at the points)
  plus the slope times the Gaussian part's extent (:mod:`.friction_range`, which also keeps a
  share of the friction's slope where that damps the set, and :meth:`_gp_range_candidate`);
  per step the form with the narrower τ_h,act half-width after (I − KH) is kept.
* the Gaussian part: P_g (:mod:`.gaussian_part`), the filter's P without the GP's variance and a declared input's walk.

Plain AKF: no GP term, δ_N = δ, a declared ``estimator.model_error`` e enters as Γ_μ box(e). GP-AKF: δ_GP
(default δ/2) for the GP constants (:func:`~.calibration.gp_constants`), ρ holding with probability ≥ 1 − δ;
steps whose z leaves their input box: ``gp_box_violations_``.
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.errors import EstimatorFault
from sea_daemon.core.linalg import discretize, zoh
from sea_daemon.core.model_core import sampled_box
from sea_daemon.core.bounds.ellipsoid import Ellipsoid, chi2_quantile
from sea_daemon.core.bounds.calibration import box_level, gp_constant_levels, levels_of, residual_gps
from sea_daemon.core.bounds.gp_bound import BoundConstants, LocalScale
from sea_daemon.core.bounds.setmember import (
    GENERATORS_PER_JOINT, REDUCE_PERIOD_S, SetMembershipBound, ellipsoid_points, unit_directions)
from sea_daemon.core.bounds import bound_core, rigid_box
from sea_daemon.core.bounds.friction_range import FrictionRange
from sea_daemon.core.gp.pack import GPPack, empty_pack
from sea_daemon.core.bounds.bound_core import generators_check, gravity_remainder
from sea_daemon.core.bounds.gaussian_part import GaussianPart


class AKFTheoremBound:
    """The Theorem-1 bound component of one AKF instance (see module docstring)."""

    def __init__(self, akf, *, gp_constants: list[BoundConstants] | str | None = None,
                 gp_box: tuple[np.ndarray, np.ndarray] | None = None, delta: float | None = None,
                 delta_gp: float | None = None, n_dirs: int = 2, margin: float = 0.25,
                 projection: str = "scalar", sets: str = "zonotope", seed: int = 0,
                 gp_beta: str | float | None = None, tau_h_act_rate: float | None = None,
                 compiled: bool = True, filter_gaussian: bool | None = None):
        self.akf = akf
        # the compiled step (bound_core.bound_step) where it applies, else the Python step below
        self.compiled = bool(compiled)
        self._pack = None                 # gp.pack.GPPack of the frozen LoG-GPs
        self._pack_at = -1                # n_learned when the pack was made
        self._args = None                 # the compiled step's arguments that stay (_call_compiled)
        self._caps = self._sqrt_caps = None   # the AKF's caps of bounded P and their square roots
        est_cfg = getattr(getattr(akf, "cfg", None), "estimator", None)
        # 'lederer' (LUH19, eq:gpmeanbounds) or a configured β (η = β √(σ² + σ_n²)); default:
        # the configuration's estimator.gp_beta
        if gp_beta is None:
            gp_beta = getattr(est_cfg, "gp_beta", "lederer")
        if not (gp_beta == "lederer" or (isinstance(gp_beta, (int, float)) and gp_beta > 0)):
            raise ValueError(f"gp_beta must be 'lederer' or a number > 0, got {gp_beta!r}")
        self.gp_beta = gp_beta
        n, d = akf.n, akf.d
        key = "tau_h_act_accel" if akf.layout.integrated else "tau_h_act_rate"   # the τ_h,act model's declared input
        self._init_rate(getattr(est_cfg, key, 0.0) if tau_h_act_rate is None else tau_h_act_rate)
        delta = akf.delta if delta is None else float(delta)
        has_gp = akf.residual is not None
        if delta_gp is None:
            delta_gp = 0.5 * delta if has_gp else 0.0
        self._init_gp_constants(gp_constants, has_gp)
        self.gp_box, self.box_level_ = gp_box, 0     # box_level_: the nested box of the last step (calibration)
        self._levels = levels_of(self.gp_constants, gp_box) if self.gp_constants else None
        self._init_model_error(est_cfg, has_gp)        # declared model error (plain AKF)
        # P_g (docs/bounds.md §3): no GP variance, no walk with a rate; the filter's P with a configured β
        filt = (has_gp and self.gp_beta != "lederer") if filter_gaussian is None else filter_gaussian
        drop = not filt and self.tau_h_act_rate > 0
        self.gauss = GaussianPart(akf, not filt and (has_gp or drop), drop)
        self.sm = SetMembershipBound(d, akf.layout.tau_idx, delta, delta_gp=delta_gp if has_gp else 0.0,
                                     n_dirs=n_dirs, margin=margin, seed=seed, projection=projection,
                                     sets=sets, max_generators=GENERATORS_PER_JOINT * n)
        # order reduction at most every REDUCE_PERIOD_S (setmember): 5 at 100 Hz, 50 at 1 kHz
        self.sm.reduce_every = max(1, int(round(REDUCE_PERIOD_S / float(akf.dt))))
        self._init_geometry(has_gp, n_dirs, seed)
        self.gp_box_violations_ = 0
        self._rho, self._b = np.zeros(n), np.zeros(d)
        # the compiled step's other bounded inputs, contiguous: Γ_τ, or [Γ_μ e | Γ_τ r] (those declared)
        self._Gam_tau_c = np.zeros((d, n * (int(self._me_on) + int(self.tau_h_act_rate > 0))))
        self._empty = empty_pack()
        self._cfast = ((self._fast or self._rigid) and sets == "zonotope" and projection == "scalar"
                       and (not has_gp or residual_gps(akf) is not None))
        # declared Coulomb/Stribeck friction: the bounded-range alternative of the linearisation
        # error (friction_range.FrictionRange; docs/bounds.md §4 "The range form")
        self.friction = FrictionRange(akf.model, None if akf.model.rigid is not None else akf.tables, sets,
                                      d - 5 * n)
        self.friction.choose_every = self.sm.reduce_every      # its slope rule chosen every 50 ms
        self.range_steps_ = 0           # steps whose set of means took the range candidate
        self.eta_, self.gp_lin_err_ = np.zeros(n), np.zeros(n)   # GP error alone, GP mean's linearisation error alone (N m)
        self.lin_err_ = np.zeros(d)              # nominal model's linearisation-error box (ẋ units)
        # the Python step's X⁻ inputs as taken (F, Γ, η, b, Φ), for terms.TermShadow (docs/bounds.md)
        self.prior_inputs_ = None

    def _init_rate(self, tau_h_act_rate) -> None:
        """The declared input of the τ_h,act model and its work arrays: the walk's |dτ_h,act/dt| ≤ r [N m/s] (τ_h,act
        rows) or the integrated walk's |d²τ_h,act/dt²| ≤ a [N m/s²] (τ̇_h,act rows); :attr:`tau_h_act_rate` holds it."""
        n, d = self.akf.n, self.akf.d
        if not (isinstance(tau_h_act_rate, (int, float)) and math.isfinite(tau_h_act_rate) and tau_h_act_rate >= 0):
            raise ValueError(f"tau_h_act_rate must be a finite number >= 0 [N m/s], got {tau_h_act_rate!r}")
        self.tau_h_act_rate = float(tau_h_act_rate)
        self._E_tau = np.zeros((d, n))
        self._E_tau[self.akf.layout.rate_idx, np.arange(n)] = 1.0
        self._aug_tau = np.zeros((d + n, d + n))         # zoh work matrix
        self._Ezoh_tau = np.zeros((d + n, d + n))        # e^{[[A, E_τ], [0, 0]] dt}
        self._Gam_tau = self._Ezoh_tau[:d, d:]           # Γ_τ of the step (a view)
        self._Gam_all, self._eta_all = np.zeros((d, 2 * n)), np.zeros(2 * n)     # [Γ_μ | Γ_τ], [η | r]
        self._rate = np.full(n, self.tau_h_act_rate)     # r per joint (plain AKF: the only bounded input)

    def _init_model_error(self, est_cfg, has_gp: bool) -> None:
        """A plain AKF's declared model error ``estimator.model_error`` [N m], Γ_μ box(e) (docs/bounds.md
        §7); ``model_error_term``: whether this bound holds the estimator's model error (Estimate.valid)."""
        e = 0.0 if has_gp else float(getattr(est_cfg, "model_error", 0.0) or 0.0)
        self.model_error = np.full(self.akf.n, e)
        self._me_on = e > 0
        self.model_error_term = has_gp or self._me_on
        self.at_cap_ = False                # this step held the set of means at the caps (_saturate)

    def _init_gp_constants(self, gp_constants, has_gp: bool) -> None:
        """The GP constants: a list, or 'auto' (computed from the residual's LoG-GPs)."""
        if has_gp and gp_constants is None:
            raise ValueError("a GP-AKF needs gp_constants (a list, or 'auto' for a ResidualGP; "
                             "see sea_daemon.core.bounds.calibration.gp_constants)")
        self._auto = has_gp and isinstance(gp_constants, str)
        self.refresh_every = 200          # 'auto': recompute after this many new training points
        self._learned_at = self._growth = 0
        if self._auto and gp_constants != "auto":
            raise ValueError(f"gp_constants must be a list of BoundConstants or 'auto', got {gp_constants!r}")
        self.gp_constants = (list(gp_constants) if (has_gp and not self._auto) else None)
        self._scales = None
        self._update_scales()

    def _init_geometry(self, has_gp: bool, n_dirs: int, seed: int) -> None:
        """The model's and the sets' constants: which errors depend on which coordinates."""
        n, d = self.akf.n, self.akf.d
        m = self.akf.model
        self._I = np.eye(d)
        # only gravity is non-linear in a nominal model without declared effects (and no URDF body)
        self._fast = m.rigid is None and not (m.load_effects or m.motor_effects or m.spring_effects or m.backlash)
        # the linearisation and GP errors need x_{k−1} in the set only in the coordinates they depend
        # on: without declared effects q and (q, q̇) = T x, so s_z = χ²_m (m = n or 2n), not χ²_5n
        # (docs/bounds.md §4, "Which set"); with declared effects f_nom depends on all of x: s_d.
        # (a URDF's rigid body without declared effects: both over W·C, W x = (q, q̇, τ), χ²_3n; rigid_box)
        self._rbox = rigid_box.RigidBox.of(m, self.sm, n_dirs, seed)
        self._rigid = self._rbox is not None
        self._s_z = (chi2_quantile(1.0 - self.sm.delta_noise, 2 * n if has_gp else n) if self._fast
                     else self._rbox.s_z if self._rigid else self.sm.s_state)
        # (q, q̇) = T x: the part of the GP input z = [q, q̇, q̈] that depends on the state
        self._T = np.asarray(self.akf.dz_dx, dtype=float)[:2 * n]
        self._E_q = np.hstack([np.eye(n), np.eye(n), np.zeros((n, d - 2 * n))])   # q = θ_m + θ_s
        self._grid = np.linspace(-1.0, 1.0, 65)
        self._grid_step = 2.0 / 64
        self._Uz = unit_directions(2 * n, n_dirs, seed)
        self._M, self._minv = ((m.M, m.Minv) if self._rigid    # a rigid body's: set in place per step (SEAModel.at)
                               else (np.ascontiguousarray(m.M, dtype=float), np.ascontiguousarray(m.Minv, dtype=float)))
        self._g = np.abs(np.asarray(m.gravity, dtype=float)) * np.ones(n)

    # ------------------------------------------------------------------ hooks

    def refresh_gp_constants(self) -> None:
        """The GP constants and input box of the residual's current leaves (after it learned more)."""
        self._growth = self.refresh_every if getattr(self.akf, "learning", False) else 0   # union_leaves
        self.gp_constants, self.gp_box, self._levels = gp_constant_levels(residual_gps(self.akf), self.sm.delta_gp, beta=self.gp_beta, growth=self._growth)
        self._learned_at = self._n_learned()
        self._update_scales()
        self._pack = None

    def _update_scales(self) -> None:
        """The local scales s(z) (:class:`LocalScale`) when the constants use them."""
        self._scales = None
        if self.gp_constants and any(c.scale == "local" for c in self.gp_constants):
            gps = residual_gps(self.akf)
            if gps is None:
                raise ValueError("GP constants with a local scale need a residual backed by LoG-GPs")
            self._scales = [LocalScale(g) for g in gps]

    def _n_learned(self) -> int:
        """Training pairs learned so far (the GP-AKF's counter, else the LoG-GPs' points)."""
        n = getattr(self.akf, "n_learned", None)
        if n is not None:
            return int(n)
        return int(sum(g.n_points for g in residual_gps(self.akf) or []))

    def reset(self, est, record) -> None:
        """After the AKF's reset: the set of means back to a point, ρ_0 (GP constants of the GP
        as trained when estimation starts, with 'auto')."""
        if self._auto:
            # 'auto': the constants of the GP as trained when estimation starts
            self.refresh_gp_constants()
        self.sm.reset()
        self.friction.reset()
        self.gp_box_violations_ = 0
        self.saturated_ = self.range_steps_ = 0
        self.at_cap_ = False
        self.gauss.reset(record.P)
        if record.ready:
            est.tau_h_act_bound[:] = self.sm.rho(record.P)

    # ------------------------------------------------------------------ linearisation error

    def _gravity_box(self, x0: np.ndarray, P0: np.ndarray) -> np.ndarray:
        """Rigorous bound of the gravity term's linearisation error (no sampling): C(q) = g ⊙ sin q
        enters θ̈_s as −M⁻¹ C(q); with |q_j − q̂_j| ≤ r_j (the half-width along e_θm,j + e_θs,j of
        X̂ ⊕ E(0, s_z P)), max |sin(q̂+Δ) − sin q̂ − cos q̂ Δ| over |Δ| ≤ r_j (bound_core.gravity_remainder)
        times |M⁻¹| (elementwise) in the θ̈_s rows."""
        akf = self.akf
        n = akf.n
        model = akf.model
        b = np.zeros(akf.d)
        g = np.abs(np.asarray(model.gravity, dtype=float)) * np.ones(n)
        if not np.any(g):
            return b
        qh = x0[:n] + x0[n:2 * n]
        r = self.sm.half_widths(self._E_q, P0, s=self._s_z)   # along e_θm,j + e_θs,j
        v = np.empty(n)
        gravity_remainder(qh, r, g, self._grid, self._grid_step, v)
        b[3 * n:4 * n] = np.abs(model.Minv) @ v
        return b

    def _sampled_nominal_box(self, x0, u, C: Ellipsoid, A_nom: np.ndarray) -> np.ndarray:
        """max over the point set of C of |f_nom(x) − f_nom(x̂) − F_nom (x − x̂)| (declared effects)."""
        tables = self.akf.tables
        if tables is not None:
            # the same, compiled over all the points at once (model_core)
            return tables.lin_error_box(self.sm.sample_points(C), u, x0, A_nom)
        return sampled_box(self.akf.model.f_nom, self.sm.sample_points(C), u, x0, A_nom)

    def _gp_box(self, zhat: np.ndarray, x0: np.ndarray, P0: np.ndarray):
        """GP part, per point of the projection of C on (q, q̇) — the GP input z = [q, q̇, q̈]
        depends on x only through them (q̈ is measured): the GP mean's linearisation error
        |μ(z) − μ(ẑ) − ∂μ/∂z (z − ẑ)|, σ(z) (or s(z)) and the extrapolation term x(z).  Returns
        (E, S, X, out-of-box flag), E, S and X of shape (points, n), in N m."""
        akf = self.akf
        n = akf.n
        res = akf.residual
        mu0, J0, var0 = res.predict(zhat)
        # copies: a residual hook may return preallocated arrays overwritten by the next call
        mu0 = np.array(mu0, dtype=float)
        J0 = np.array(np.asarray(J0, dtype=float)[:, :2 * n])
        Cz = self.sm.confidence_set(x0, P0, T=self._T, s=self._s_z)  # outer ellipsoid of T·C_{k−1}
        local = self._scales is not None
        # σ (or s) is maximised over the points at the UNCLIPPED z, the centre ẑ included: the
        # filter's hook clips z to the training box, where σ can be far smaller than at z
        out, self.box_level_ = False, 0
        gps = residual_gps(akf)
        pts = ellipsoid_points(Cz, self._Uz)     # pts[0] = ẑ: μ(ẑ) − μ(clip ẑ) is part of the error there
        Z = np.empty((len(pts), zhat.size))      # z = [p, q̈̂] per point
        Z[:, :2 * n] = pts
        Z[:, 2 * n:] = zhat[2 * n:]
        MU = np.empty((len(pts), n))
        S = np.empty((len(pts), n))
        X = np.zeros((len(pts), n))              # extrapolation term c e(z), added to η (gp_bound.LocalScale)
        if local:
            # mean, variance, local scale and extrapolation term of all points: one routing per
            # point, one compiled call per leaf reached
            for j, sc in enumerate(self._scales):
                MU[:, j], _, S[:, j], X[:, j] = sc.predict_many_ext(Z)
        elif gps is not None:
            # mean and variance only (no Jacobian needed here): cheaper than the hook
            for j, g in enumerate(gps):
                MU[:, j], S[:, j] = g.predict_many(Z)
        else:
            for i, z in enumerate(Z):
                m_, _, v_ = res.predict(z)
                MU[i], S[i] = m_, v_
        if not local:
            S = np.sqrt(np.maximum(S, 0.0))
        # per point: |μ(z) − μ(ẑ_clip) − ∂μ/∂z (z − ẑ)| and σ (or s); |μ(z) − μ(ẑ_clip)| for the
        # range form (_gp_range_candidate)
        E = np.abs(MU - mu0 - (pts - zhat[:2 * n]) @ J0.T)
        self._E0 = np.abs(MU - mu0)
        self._J0 = J0
        if self.gp_box is not None:
            # the smallest nested box holding the whole projected set (its bounding box) and the measured q̈
            hw = Cz.axis_half_widths()
            zl, zh = Z[0].copy(), Z[0].copy()      # [box of the projected set, measured q̈]
            zl[:2 * n] -= hw
            zh[:2 * n] += hw
            self.box_level_, out = box_level(self._levels, zl, zh)
        return E, S, X, out

    def _phi(self, A, b, dt, Gamma_mu):
        """Φ = ∫₀^dt e^{As} ds on the columns where b ≠ 0.  The θ̈_s columns are Γ_μ M (the AKF
        already has Γ_μ = Φ I_μ M⁻¹); any other column costs one expm."""
        if not np.any(b):
            return None
        akf = self.akf
        n = akf.n
        nz = np.flatnonzero(b)
        if np.all((nz >= 3 * n) & (nz < 4 * n)):
            Phi = np.zeros((akf.d, akf.d))
            Phi[:, 3 * n:4 * n] = Gamma_mu @ akf.model.M
            return Phi
        return discretize(A, self._I, dt)[1]

    def _compiled_pack(self):
        """The GP pack for the compiled step, or None when the Python step must run (not the
        compiled case, or a GP that is learning).  A plain AKF: an empty tuple."""
        if not (self.compiled and self._cfast):
            return None
        akf = self.akf
        if akf.residual is None:
            return ()
        if getattr(akf, "learning", False):
            return None
        n_l = self._n_learned()
        if self._pack is not None and self._pack_at == n_l:
            return self._pack_args        # the pack of the frozen GP (its constants checked when made)
        if not all(type(c) is BoundConstants for c in self.gp_constants or ()):
            return None                   # constants of one's own (an eta() of its own): the Python step
        if self._pack is None or self._pack_at != n_l:
            gps = residual_gps(akf)
            local_r = [sc.r_ for sc in self._scales] if self._scales is not None else None
            self._pack = GPPack(gps, local_r)
            self._pack_at = n_l
            self._sqrt_beta, self._gamma = self._levels.sqrt_beta, self._levels.gamma     # (levels, n)
            self._pack_args = self._pack.arrays()
            self._args = None
        return self._pack_args

    def _step_compiled(self, est, record, gp) -> None:
        """The same step in one compiled call (:mod:`.bound_core`)."""
        akf = self.akf
        sm = self.sm
        n = akf.n
        has_gp = akf.residual is not None
        self.at_cap_ = False
        if self._me_on:                    # Γ_μ e: the declared model error (rate 1 in RateTerm)
            np.multiply(record.Gamma_mu, self.model_error, out=self._Gam_tau_c[:, :n])
        if self.tau_h_act_rate > 0:
            zoh(record.A_k, self._E_tau, float(record.dt), self._aug_tau, self._Ezoh_tau)
            if self._me_on:
                np.multiply(self._Gam_tau, self.tau_h_act_rate, out=self._Gam_tau_c[:, n:])
            else:
                self._Gam_tau_c[:] = self._Gam_tau
        box = self.gp_box
        lo, hi = (self._levels.lo, self._levels.hi) if box is not None else (self._g[None], self._g[None])
        P0, P = self.gauss.step(record)
        if self._rigid:                    # M(q̂_{k−1}) and the rigid body's box, before the compiled step
            self._rbox.at(record.x_prev, sm.G_, P0, self._b)
        try:
            G, out, took_range = self._call_compiled(record, sm, n, has_gp, box, lo, hi, gp)
        except (np.linalg.LinAlgError, ZeroDivisionError, ValueError) as e:
            # a set of means grown to inf/NaN inside the step (e.g. the eigendecomposition of its
            # projection): the typed estimator fault, as the Python step raises it
            raise EstimatorFault(f"Theorem-1 bound, step {est.k}: the set of means diverged ({e})") from None
        caps = akf.P_max
        if caps is not self._caps:
            self._caps = caps
            self._sqrt_caps = np.sqrt(caps) if caps is not None else np.full(akf.d, np.inf)
        check = generators_check(G, self._sqrt_caps)
        if check == 1:
            raise EstimatorFault(f"Theorem-1 bound, step {est.k}: the set of means diverged (linearisation "
                                 f"error {np.max(self._b):.3g}); the model's non-linearity is too strong for "
                                 f"the confidence set")
        sm.G_ = G
        self.gp_box_violations_ += int(out)
        self.range_steps_ += int(took_range)
        self.lin_err_ = self._b
        est.tau_h_act_bound[:] = self._rho
        if check:                          # a half-width at its cap: the exact test, maybe saturation
            self._saturate(est, P)

    def _call_compiled(self, rec, sm, n, has_gp, box, lo, hi, gp):
        """:func:`bound_core.bound_step` with this bound's arrays (its named arguments that stay the
        same from step to step kept, made again when the pack, the box, an output array or the
        record changed)."""
        a = self._args
        if (a is None or a[0] is not gp or a[1] is not box or a[2] is not self.eta_ or a[3] is not self.gp_lin_err_
                or a[4] is not rec):
            g = self.gauss
            P0, P = (g.P_prev, g.P) if g.own else (rec.P_prev, rec.P)
            st = bound_core.FilterStep(rec.x_prev, P0, rec.z, rec.mu, rec.dmu_dz, rec.F_k, rec.K_k,
                                       rec.Gamma_mu, P)
            c = bound_core.SetConstants(self.akf.H, self._M, self._minv, self._g, self._s_z, sm.margin, self._T,
                                        self._E_q, self._grid, self._grid_step, self._Uz, sm.delta_noise / n, sm.z_tau,
                                        self._rigid)
            gpt = bound_core.GPTerms(has_gp, self._scales is not None, self._pack.c_ext if has_gp else 0.0,
                                     self._sqrt_beta if has_gp else self._g[None], self._gamma if has_gp else self._g[None],
                                     lo, hi, box is not None)
            rt = bound_core.RateTerm(self._Gam_tau_c, 1.0 if self._me_on else self.tau_h_act_rate,
                                     self._me_on or self.tau_h_act_rate > 0)
            out = bound_core.BoundOutputs(self._rho, self.eta_, self.gp_lin_err_, self._b)
            a = self._args = (gp, box, self.eta_, self.gp_lin_err_, rec,
                              (st, c, gpt, rt, gp if has_gp else self._empty, out))
        st, c, gpt, rt, pack, out = a[5]
        return bound_core.bound_step(sm.G_, sm.generator_limit(), st, c, gpt, rt, pack, out)

    def step(self, est, record) -> None:
        """After the AKF's step k (its :class:`~sea_daemon.core.estimators.record.StepRecord`:
        from x̂_{k−1}, P_{k−1} with the input u held over dt): propagate the set of means and
        publish ρ_k."""
        gp = self._compiled_pack()
        if gp is not None:
            self._step_compiled(est, record, gp)
            return
        akf = self.akf
        P0, P = self.gauss.step(record)
        x0, u, dt, zhat = record.x_prev, record.u, record.dt, record.z   # ẑ_{k−1}: the GP's input
        akf.model.at(x0)                          # a URDF model's M(q̂_{k−1}) (Γ_μ = Φ I_μ M⁻¹)
        sm = self.sm
        gp_range = None
        if not np.all(np.isfinite(sm.means_half_widths())):
            raise EstimatorFault(f"Theorem-1 bound, step {est.k}: the set of means is not finite")
        if self._auto and self._n_learned() >= self._learned_at + max(self._growth, 1):
            # the GP keeps learning (GP-AKF with learning on): constants of the current data
            self.refresh_gp_constants()
        # eq:linerrsetdx / eq:linearerrellipsoid, split by source
        b, fric = self._nominal_error(record, P0)
        eta = self.model_error if self._me_on else None   # a plain AKF's declared model error, through Γ_μ
        if akf.residual is not None:
            E, S, X, out = self._gp_box(zhat, x0, P0)
            self.gp_box_violations_ += int(out)
            # eq:gpmeanbounds → lem:interval_bound: GP error η_j(z) = √β_j σ_j(z) + γ_j per point,
            # plus the extrapolation term x_j(z) off the data (docs/bounds.md §2d; 0 unless
            # learning.extrapolation_scale)
            k = self.box_level_                  # the constants of the nested box the step's set is in
            H = (np.column_stack([c.eta(S[:, j]) for j, c in enumerate(self.gp_constants)]) if k == 0 else
                 self._levels.sqrt_beta[k] * S + self._levels.gamma[k]) + X
            # The GP error f_j(z) − μ_j(z) and the GP mean's linearisation error
            # μ_j(z) − μ_j(ẑ) − ∂μ_j/∂z (z − ẑ) are parts of ONE torque error at the same (true) z,
            # f_j(z) − [μ_j(ẑ) + ∂μ_j/∂z (z − ẑ)], which enters the state through Γ_μ (= Φ I_μ M⁻¹,
            # eq:Dmuhat): bound it per joint by the max over the points of the SUM (not the sum
            # of the two maxima, which may sit at different points), the sampled part + margin
            Lm = (1.0 + sm.margin) * E
            eta = np.max(H + Lm, axis=0)
            if sm.sets == "zonotope":
                gp_range = self._gp_range_candidate(H, P0, record.Gamma_mu)
            self.eta_ = np.max(H, axis=0)          # the GP error alone (diagnostic)
            self.gp_lin_err_ = np.max(Lm, axis=0)  # the GP mean's linearisation error alone
        self.lin_err_ = b
        Phi = self._phi(record.A_k, b, dt, record.Gamma_mu)
        Gam = record.Gamma_mu
        if self.tau_h_act_rate > 0:
            # docs/bounds.md §6: τ̇_h,act ∈ [−r, r] (integrated: τ̈_h,act ∈ [−a, a]) beyond the walk, held over
            # the step: Γ_τ = ∫₀^dt e^{A s} ds E_τ (E_τ̇), one more bounded input
            zoh(record.A_k, self._E_tau, float(dt), self._aug_tau, self._Ezoh_tau)
            n = akf.n
            if eta is None:
                Gam, eta = self._Gam_tau, self._rate
            else:
                self._Gam_all[:, :n] = record.Gamma_mu
                self._Gam_all[:, n:] = self._Gam_tau
                self._eta_all[:n] = eta
                self._eta_all[n:] = self.tau_h_act_rate
                Gam, eta = self._Gam_all, self._eta_all
        # eq:predwLinErrsetandGPerrset, then the filter step on the set
        if fric is None and gp_range is None:
            self.prior_inputs_ = (record.F_k, Gam, eta, b if np.any(b) else None, Phi)
            sm.predict(record.F_k, Gamma=Gam, eta=eta, lin_err_box=self.prior_inputs_[3], Phi=Phi)
        else:
            self._predict_best_of_two(record, Gam, eta, b, Phi, fric, gp_range)
        self.friction.cut(sm, record, akf.H)             # the measurement's strips (declared friction)
        sm.update(record.K_k, akf.H)
        if not np.all(np.isfinite(sm.means_half_widths())):
            raise EstimatorFault(f"Theorem-1 bound, step {est.k}: the set of means diverged (linearisation "
                                 f"error {np.max(b):.3g}); the model's non-linearity is too strong for "
                                 f"the confidence set")
        est.tau_h_act_bound[:] = sm.rho(P)
        self._saturate(est, P)

    def _nominal_error(self, record, P0: np.ndarray):
        """(b, the friction's range candidate or None): the nominal model's linearisation-error
        box over C_{k−1} — gravity analytically, declared effects sampled (with declared
        friction, both forms of :meth:`FrictionRange.candidate` from one pass)."""
        akf, sm = self.akf, self.sm
        x0, u, dt = record.x_prev, record.u, record.dt
        if self._fast:
            return self._gravity_box(x0, P0), None    # analytic, rigorous (exact half-width of C_{k−1})
        if self._rigid:                                # the rigid body's box over W·C_{k−1} (rigid_box)
            return self._rbox.box(x0, sm.G_, P0, self._s_z, np.zeros(akf.d)), None
        C = sm.confidence_set(x0, P0)                  # C_{k−1} (outer ellipsoid, for the point set)
        A_nom = record.A_k.copy()
        if akf.residual is not None:                   # undo −I_μ M⁻¹ F_GP to get F_nom
            _, J, _ = akf.residual.predict(record.z)
            A_nom += akf.G_mu @ (np.asarray(J, float) @ akf.dz_dx)
        if self.friction.groups:
            loop = (record.F_k, self._I - record.K_k @ akf.H)
            fric = self.friction.candidate(x0, u, P0, sm.sample_points(C), A_nom, dt, record.A_k,
                                           record.Gamma_mu, sm, self._phi, loop)
            return fric[5], fric
        return (1.0 + sm.margin) * self._sampled_nominal_box(x0, u, C, A_nom), None

    def _gp_range_candidate(self, H: np.ndarray, P0: np.ndarray, Gamma_mu: np.ndarray):
        """The GP part of the range form: the GP mean linearised at zero slope.

        The filter's drift carries −I_μM⁻¹[μ(ẑ) + J T(x − x̂)] (eq:linearization, J = ∂μ/∂z at ẑ,
        T x = (q, q̇)); the true one −I_μM⁻¹ f(z).  With x − x̂ = a + g as in
        :meth:`FrictionRange.candidate`, Γ_μ = Φ I_μM⁻¹ (eq:Dmuhat):

            a⁺ = F a − Γ_μ [f(z) − μ(ẑ) − J T(a + g)]
               = (F + Γ_μ J T) a − Γ_μ [(f − μ)(z) + μ(z) − μ(ẑ) − J T g],

        so the set of means may be propagated with F + Γ_μ J T and the torque error
        η_B = max over the points of [√β s + γ + c e + (1 + margin)|μ(z) − μ(ẑ)|] + √(s_z J T P Tᵀ Jᵀ)
        (J T g on the χ² set of (q, q̇), the event the GP points already use) instead of the
        filter's slope and the GP mean's linearisation error.  Returns (F_B − F, η_B)."""
        J0 = self._J0
        Lm0 = (1.0 + self.sm.margin) * self._E0
        JT = J0 @ self._T                          # (n, d)
        eta_b = np.max(H + Lm0, axis=0) + np.sqrt(np.maximum(self._s_z * np.sum((JT @ P0) * JT, axis=1), 0.0))
        return Gamma_mu @ JT, eta_b

    def _predict_best_of_two(self, rec, Gam, eta, b, Phi, fric, gp_range) -> None:
        """X⁻ from the filter-slope step (F, Γ box(η), Φ box(b)) or the range form (FrictionRange.candidate,
        :meth:`_gp_range_candidate`), whichever has the narrower τ_h,act half-width after (I − KH);
        both contain the set of means, so the choice keeps the guarantee whatever the rule."""
        sm = self.sm
        n = self.akf.n
        limit = sm.generator_limit()
        GA = sm.prior_generators(rec.F_k, Gamma=Gam, eta=eta, lin_err_box=b if np.any(b) else None, Phi=Phi,
                                 limit=limit)
        FB = np.array(rec.F_k, dtype=float)
        GamB, etB, bB, PhiB = Gam, eta, b, Phi
        if gp_range is not None:
            dF, eta_gp = gp_range
            FB += dF
            etB = np.array(eta, dtype=float)
            etB[:n] = eta_gp                      # [η | r]: the GP columns come first
        if fric is not None:
            dF, GamF, w, bB, PhiB, _ = fric
            FB += dF
            if Gam is None or etB is None:
                GamB, etB = GamF, w
            else:
                GamB, etB = np.hstack([Gam, GamF]), np.concatenate([etB, w])
        GB = sm.prior_generators(FB, Gamma=GamB, eta=etB, lin_err_box=bB if np.any(bB) else None, Phi=PhiB,
                                 limit=limit)
        tau = sm.tau_idx
        R = -(rec.K_k[tau] @ self.akf.H)          # the τ rows of I − K H
        R[np.arange(tau.size), tau] += 1.0
        hA = np.abs(R @ GA).sum()
        hB = np.abs(R @ GB).sum()
        if hB < hA:
            sm.Gprior_, sm.lin_err_, self.lin_err_ = GB, bB, bB
            self.range_steps_ += 1
            self.prior_inputs_ = (FB, GamB, etB, bB if np.any(bB) else None, PhiB)
        else:
            sm.Gprior_, sm.lin_err_ = GA, b
            self.prior_inputs_ = (rec.F_k, Gam, eta, b if np.any(b) else None, Phi)

    def _saturate(self, est, P) -> None:
        """A set of means beyond the physical caps of bounded P (``AKF.P_max``) carries no
        guarantee any more (its linearisation error grew faster than the filter contracts it,
        e.g. a steep friction at standstill): it is held at the caps — finite, counted in
        :attr:`saturated_` — instead of growing to overflow."""
        caps = getattr(self.akf, "P_max", None)
        self.at_cap_ = caps is not None and self.sm.saturate(np.sqrt(caps))
        if self.at_cap_:
            self.saturated_ += 1
            est.tau_h_act_bound[:] = self.sm.rho(P)


def theorem_bound(akf) -> AKFTheoremBound | None:
    """The default bound component (``AKF(cfg, bound=theorem_bound)``, what
    :func:`~sea_daemon.core.estimators.factory.make_estimator` gives): the Theorem-1 bound for a
    plain AKF, and for a GP-AKF whose residual is backed by LoG-GPs (constants computed at
    every reset, and refreshed while it keeps learning).  An unknown residual type has no GP
    error constants: None, and the AKF keeps its own bound."""
    if akf.residual is None:
        return AKFTheoremBound(akf)
    if residual_gps(akf) is not None:
        return AKFTheoremBound(akf, gp_constants="auto")
    return None
