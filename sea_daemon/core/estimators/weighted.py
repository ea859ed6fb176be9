"""The residual GP as the GP-AKF uses it once physics comes first: it can do no harm.

With the physical model (nominal + the effects ``diagnose`` found) as the prior mean, the GP
models only what the physics leaves.  :class:`WeightedResidual` is the GP-AKF's residual
hook (``predict(z) -> (μ, ∂μ/∂z, σ²)``, alg:torqueresidualAKF line 5) that lets the GP's mean
and Jacobian into the filter only as far as its variance allows:

    w(z) = clip(1 − σ²(z) / s²(z), 0, 1)^p                           (variance reduction)
    s²(z) = min(σ_f²(z), s_0²)
    μ_w = w μ,   ∂μ_w/∂z = w Σ ω_i ∂μ_i/∂z,   σ²_Q = σ² (+ σ_on²)    (eq:fwdynwtorqueresidual1,
                                                                        eq:linearization, eq:GPvarfwd)

Σ ω_i ∂μ_i/∂z is the Jacobian the GP-AKF's own hook takes (the experts' Jacobian, eq:moejac
per leaf merged with the routing weights, docs/learning.md): the same
:meth:`~sea_daemon.core.gp.loggp.LoGGP.predict_grad_into` call, so the calibrated model's filter
linearises the GP as the plain GP-AKF does; the routing ramp between two leaves that disagree
(μ_i ∂ω_i/∂z) stays out of F_k, their disagreement being in σ² already.

σ_f²(z) is the prior variance of the leaves z reaches; s_0² (``var_ref``) is what the physics
alone costs on the calibration data: the leftover's mean square less the GP's noise variance
σ_on² (its latent part).  The GP's mean is trusted as far as its uncertainty at z is below the
error of predicting 0 there.  σ_f² alone is no such measure: the maximum-likelihood fit puts it
up to its bound, 2 × the leftover's RMS (4 × its mean square), when the leftover has
long-range structure, and then a GP that explains a fifth of its held-out leftover still
reports w ≈ 0.9 on its data.  On the data σ² ≪ s², w ≈ 1: the GP acts fully.  Off the data
σ² → σ_f² ≥ s², w → 0: the residual returns to zero, i.e. to the physical model, smoothly, and
its Jacobian with it (a GP's mean already reverts to the prior mean 0, but only over a length
scale, and its Jacobian can be steep on the way; w makes the return happen where the GP itself
says it does not know).  ∂w/∂z is left out of the
linearisation (w varies on the length scale; the Theorem-1 bound samples the GP mean itself at
the set's points, so its linearisation error covers it).

Stability net: the weighted Jacobian's q̇ and q columns are clipped so that the GP cannot make
the linearised load side faster than the sample rate resolves, |∂μ/∂q̇| ≤ c M/dt and
|∂μ/∂q| ≤ c M/dt² (c = 0.5; eq:linearization enters A through −I_μ M⁻¹ F_GP): a steep
residual never turns e^{A dt} explosive.

Velocity gate: when the calibration kept no standstill pairs (|q̇| < v_gate, static friction is
set-valued there), the weight ramps to 0 below v_gate/2 — the GP's interpolation across q̇ = 0
(and its slope there) stays out of a still arm's filter.

Direction gate: where a joint moves in a direction the GP's training pairs did not cover while
they covered the other (:meth:`~sea_daemon.core.learning.ResidualGP.off_direction`: friction
changes sign with q̇, and a GP that learned one way would carry its friction across q̇ = 0 with
the wrong sign), the weight
is 0 for every joint: the physical model alone, its variance still in Q.  ``n_off_direction``
counts those calls.  The Theorem-1 bound samples the GP's own mean at the set's points, so there
it carries |μ(z)| + √β σ(z) as the model error of predicting 0 (docs/bounds.md).

Inputs are clipped to the training box ± margin as the plain hook does
(:class:`~sea_daemon.core.estimators.health.InputBox`).
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.estimators.health import InputBox


class WeightedResidual:
    """GP-AKF residual hook over a :class:`~sea_daemon.core.learning.ResidualGP` with variance
    weighting (module docstring).  ``power`` p of the weight; ``noise_in_Q``: σ² + σ_on² in Q;
    ``M`` (n×n) and ``dt`` for the Jacobian clip (None: no clip); ``var_ref`` s_0² [N² m²], the
    leftover's latent mean square on the calibration data (0: the weight's reference is σ_f²
    alone)."""

    def __init__(self, gp, margin: float = 0.1, noise_in_Q: bool = True, power: float = 1.0,
                 M: np.ndarray | None = None, dt: float | None = None, clip: float = 0.5,
                 v_gate: float = 0.0, var_ref: float = 0.0):
        self.gp = gp
        if not (math.isfinite(var_ref) and var_ref >= 0.0):
            raise ValueError(f"var_ref {var_ref}: expected a finite value >= 0")
        self.var_ref = float(var_ref)
        # the GP's data exclude the sticking phases (|q̇| < v_gate, sea_daemon.apps.calibration.residual_gp.smooth_pairs):
        # below v_gate/2 it has nothing to say, so its weight ramps to 0 there (the physics holds)
        self.v_gate = float(v_gate)
        self.noise_in_Q = bool(noise_in_Q)
        self.power = float(power)
        n = self.n = gp.n
        self.mu = np.zeros(n)
        self.jac = np.zeros((n, 3 * n))
        self.var = np.zeros(n)
        self.w = np.ones(n)
        self.box = InputBox.of_residual(gp, margin)
        # calls where some joint moved in a direction the GP has no data for (direction gate)
        self.n_off_direction = 0
        self.off = False
        self._off_direction = getattr(gp, "off_direction", None)     # a residual of one's own may lack it
        self._cap = None
        if M is not None and dt is not None:
            m = np.abs(np.diag(np.asarray(M, dtype=float)))
            cap = np.zeros((n, 3 * n))
            for i in range(n):
                cap[i, :n] = clip * m[i] / dt ** 2          # ∂μ/∂q
                cap[i, n:2 * n] = clip * m[i] / dt          # ∂μ/∂q̇
                cap[i, 2 * n:] = clip * m[i]                # ∂μ/∂q̈ (an inertia error of c M)
            self._cap = cap

    def prior_variance(self, g, z) -> float:
        """σ_f² of the leaves z reaches, merged with the routing weights."""
        nodes, ws, _ = g.route_one(np.ascontiguousarray(z, dtype=float), False)
        return float(sum(w * g.leaf(node).sigma_f ** 2 for node, w in zip(nodes, ws.tolist())))

    def predict(self, z):
        # direction gate (module docstring): at the UNCLIPPED q̇, the way the joint really moves
        off = self.off = self._off_direction is not None and self._off_direction(z)
        self.n_off_direction += off
        zc = self.box.clip(z)
        clipped = self.box.any_clipped
        for i, g in enumerate(self.gp.gps):
            # eq:GPmean, eq:GPvariance (merged over the leaves z reaches), latent σ², and the
            # GP-AKF's Jacobian: the experts' Σ ω_i ∂μ_i/∂z (eq:moejac per leaf), without the
            # routing ramp's μ_i ∂ω_i/∂z (the leaves' disagreement is in σ², not in F_k)
            mu, var = g.predict_grad_into(zc, self.jac[i], noise=False, weights_grad=False)
            # variance at the UNCLIPPED input: off the box the GP knows nothing
            if clipped:
                var = g.predict(np.ascontiguousarray(np.clip(z, -1e6, 1e6), dtype=float))[1]
            # σ_f² (prior) and σ_on² of the leaves zc reaches, one routing for both
            s2 = sn2 = 0.0
            nodes, ws, _ = g.route_one(zc, False)
            for node, wr in zip(nodes, ws.tolist()):
                leaf = g.leaf(node)
                s2 += wr * leaf.sigma_f * leaf.sigma_f
                sn2 += wr * leaf.sigma_n * leaf.sigma_n
            if self.var_ref > 0.0 and self.var_ref < s2:
                # the reference: what predicting 0 (the physics) costs on the calibration data
                s2 = self.var_ref
            r = 1.0 - var / s2 if s2 > 0 else 0.0
            w = 0.0 if off else min(max(r, 0.0), 1.0) ** self.power
            if self.v_gate > 0.0:
                # velocity gate: 0 at |q̇| ≤ v_gate/2, 1 at |q̇| ≥ v_gate (the GP has no standstill data)
                v = abs(float(zc[self.n + i]))
                w *= min(max(2.0 * v / self.v_gate - 1.0, 0.0), 1.0)
            self.w[i] = w
            self.mu[i] = w * mu
            jac = self.jac[i]
            cap = self._cap[i] if self._cap is not None else None
            for k in range(jac.shape[0]):
                v = w * jac[k]
                if clipped and self.box.clipped[k]:
                    v = 0.0
                elif cap is not None:
                    c = cap[k]
                    v = c if v > c else (-c if v < -c else v)
                jac[k] = v
            self.var[i] = var + sn2 if self.noise_in_Q else var
        return self.mu, self.jac, self.var
