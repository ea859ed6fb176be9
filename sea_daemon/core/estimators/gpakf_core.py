"""One sample of the frozen GP-AKF in compiled calls (:meth:`GPAKF.update`'s fast path).

With learning off, the GP a LoG-GP pack (:class:`~sea_daemon.core.estimators.gpakf._ResidualHook`
frozen), the nominal model without declared effects or encoder offsets, no declared input
delay and the nominal step, a sample of :meth:`AKF.update` is a fixed sequence of compiled
kernels with a few lines of numpy between them.  :func:`frozen_sample` runs that sequence in
one call, the same kernels with the same operations in the same order (the estimates are
bit-identical to the Python path, ``tests/test_gpakf.py``):

1. ẑ_{k−1} = [q̂, q̂̇, q̈] at the previous posterior (Alg. 2 line 5), the input u_{k−1} from the
   input history;
2. the measurement y = [θ_m, θ_s, θ̇_m, θ̇_s] through the causal differentiator
   (:func:`~sea_daemon.core.kinematics.fir_push`, :meth:`AKF.measure`), this step's Σ_nom
   (:meth:`AKF.fill_sigma_nom`, :func:`~sea_daemon.core.estimators.akf_core.input_noise`);
3. F_nom, f_nom (:func:`~sea_daemon.core.estimators.akf_core.nominal_affine`), x̂_{k−1} and
   P_{k−1} kept for the bound, the residual hook (:func:`~sea_daemon.core.estimators.gp_hook.hook_predict`:
   μ, σ² and the experts' Jacobian Σ ω_i ∂μ_i/∂z) with σ² held over the configuration's step, :func:`~sea_daemon.core.estimators.akf_core.filter_step`;
4. the largest predicted variance against its cap, bounded P
   (:func:`~sea_daemon.core.estimators.akf_core.cap_covariance`), the Cholesky attempt of P
   (:func:`~sea_daemon.core.linalg.is_pd`);

With a URDF's rigid body (:class:`~sea_daemon.core.model_core.RigidTables`) step 3's F_nom, f_nom
need Pinocchio's ABA derivatives at x̂_{k−1}, which are no compiled code: the sample is then
:func:`rigid_head` (steps 1-2 and what the forward dynamics takes), the caller's
``RigidBody.forward_derivatives``, :func:`rigid_body` (F_nom, f_nom, G_μ, the residual) and
:func:`sample_tail` (the rest of steps 3-4), the same kernels in the same order as
``AKF.step``'s ``RigidTables.f_and_F``.  The residual hook's direction gate
(:func:`direction_gate`, ResidualGP.off_direction) runs in the compiled call too.

And, once the caller's checks passed, :func:`frozen_finish`: the published estimate
(:func:`~sea_daemon.core.estimators.akf_core.fill_estimate`) and the input pushed into the
history.  What raises (the typed faults with their messages), the NIS monitor, the bound and the
start-up gate stay with the caller, between the two calls, as in :meth:`AKF.step`.  Pure numerics: no I/O, no
clock, no threads.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core import dynamics
from sea_daemon.core.jit import njit, warmer
from sea_daemon.core.gp.pack import GPPack, warm_up_loggp
from sea_daemon.core.estimators import akf_core
from sea_daemon.core.estimators.gp_hook import hook_predict
from sea_daemon.core.kinematics import fir_push
from sea_daemon.core.linalg import is_pd

#: :func:`frozen_sample`'s integer outputs (``iout``): filter status, kinematics ring head,
#: input-history head, variances capped, Cholesky info of P, GP input clipped (0/1), direction
#: gate off (0/1)
I_STATUS, I_KIN_HEAD, I_HHEAD, I_CAPPED, I_PD, I_CLIPPED, I_OFF = range(7)
#: its float outputs (``fout``): NIS, largest predicted variance over its cap
F_NIS, F_PMAX = range(2)


@njit
def frozen_sample(q, theta_m, dt, buf, d, m, n, ang, kin_buf, kin_C, kin_out, ddq, z, hu, s_mode, S_base, B_u,
                  tau_m_var, Gamma_u, A_lin, B_lin, MinvG, gp_var_scale, box_lo, box_hi, box_z, box_clipped,
                  noise_in_Q, hook_mu, hook_jac, hook_var, pack, sn2, keep_prev, x_prev, P_prev, P_max, diverged,
                  iout, fout, gate, gated, speed):
    """Steps 1-4 of one sample (module docstring) up to the Cholesky attempt of P, on the AKF's
    own arrays, in place; :func:`frozen_finish` completes it once the caller's checks passed.
    ``iout[I_KIN_HEAD]`` and ``iout[I_HHEAD]`` hold the ring heads on entry; the kinematics'
    gets the new one.  ``gate``, ``gated``, ``speed``: the direction gate (:func:`direction_gate`)."""
    sample_head(q, theta_m, dt, buf, d, m, n, ang, kin_buf, kin_C, kin_out, ddq, z, s_mode, S_base, B_u,
                tau_m_var, Gamma_u, iout)
    (A, xdot, mu, dmu, dz_dx, sigma2, G_mu, Sigma_nom, R, y, x, P, F, Gam, Q, x_prior, P_prior, S, K,
     innovation, aug, E, Bx, L, rhs, IKH, work, KR) = akf_core.views(buf, d, m, n)
    # Alg. 1 line 3 / eq:nonlindyn, eq:linearization (no declared effects)
    akf_core.nominal_affine(x, hu[iout[I_HHEAD]], A_lin, B_lin, MinvG, A, xdot)
    sample_residual(buf, d, m, n, z, box_lo, box_hi, box_z, box_clipped, noise_in_Q, hook_mu, hook_jac, hook_var,
                    pack, sn2, keep_prev, x_prev, P_prev, iout, gate, gated, speed)
    sample_tail(buf, d, m, n, dt, gp_var_scale, hook_mu, hook_jac, hook_var, P_max, diverged, iout, fout)


@njit
def sample_head(q, theta_m, dt, buf, d, m, n, ang, kin_buf, kin_C, kin_out, ddq, z, s_mode, S_base, B_u,
                tau_m_var, Gamma_u, iout):
    """Steps 1-2: ẑ_{k−1}, the measurement through the causal differentiator, this step's Σ_nom."""
    (A, xdot, mu, dmu, dz_dx, sigma2, G_mu, Sigma_nom, R, y, x, P, F, Gam, Q, x_prior, P_prior, S, K,
     innovation, aug, E, Bx, L, rhs, IKH, work, KR) = akf_core.views(buf, d, m, n)
    # Alg. 2 line 5: ẑ_{k−1} = [q̂, q̂̇, q̈] at the previous posterior (q̈ of the previous sample)
    for j in range(n):
        z[j] = x[j] + x[n + j]
        z[n + j] = x[2 * n + j] + x[3 * n + j]
        z[2 * n + j] = ddq[j]
    # AKF.measure: the angles as read (no offsets), the causal kinematics
    for j in range(n):
        ang[j] = q[j]
        ang[n + j] = theta_m[j]
    iout[I_KIN_HEAD] = fir_push(kin_buf, iout[I_KIN_HEAD], kin_C, ang, kin_out)
    for j in range(n):
        y[j] = kin_out[0, n + j]
        # θ_s = q − θ_m (eq:spring_torque)
        y[n + j] = kin_out[0, j] - kin_out[0, n + j]
        y[2 * n + j] = kin_out[1, n + j]
        y[3 * n + j] = kin_out[1, j] - kin_out[1, n + j]
        ddq[j] = kin_out[2, j]
    # AKF.fill_sigma_nom: Σ_nom,k of this step (s_mode 1: Σ_nom·dt/T; 2: and the motor-torque
    # error held over the step, Γ_u from the last step's Jacobian A_k)
    if s_mode == 2:
        akf_core.input_noise(A, B_u, dt, tau_m_var, S_base, Gamma_u, Sigma_nom)
    elif s_mode == 1:
        for i in range(d):
            for c in range(d):
                Sigma_nom[i, c] = S_base[i, c]


@njit
def direction_gate(z, n, gated, speed) -> bool:
    """Whether some joint moves at ``z`` (|q̇_j| beyond ``speed``) in a direction ``gated`` (n, 2:
    down, up) marks as not covered by the GP's training pairs (ResidualGP.off_direction)."""
    for j in range(n):
        v = z[n + j]
        if (v > speed and gated[j, 1]) or (v < -speed and gated[j, 0]):
            return True
    return False


@njit
def sample_residual(buf, d, m, n, z, box_lo, box_hi, box_z, box_clipped, noise_in_Q, hook_mu, hook_jac, hook_var,
                    pack, sn2, keep_prev, x_prev, P_prev, iout, gate, gated, speed):
    """Step 3 after F_nom, f_nom: x̂_{k−1} and P_{k−1} kept for the bound, the residual hook at ẑ_{k−1}
    (:func:`hook_predict`) and, with ``gate``, the direction gate (μ and ∂μ/∂z 0 where it is off:
    ``iout[I_OFF]``), as _ResidualHook.predict."""
    (A, xdot, mu, dmu, dz_dx, sigma2, G_mu, Sigma_nom, R, y, x, P, F, Gam, Q, x_prior, P_prior, S, K,
     innovation, aug, E, Bx, L, rhs, IKH, work, KR) = akf_core.views(buf, d, m, n)
    if keep_prev:
        for i in range(d):
            x_prev[i] = x[i]
            for c in range(d):
                P_prev[i, c] = P[i, c]
    # Alg. 2 lines 4-6: μ, σ² = GP.PREDICT(ẑ_{k−1}) (the frozen hook)
    clipped = hook_predict(z, box_lo, box_hi, box_z, box_clipped, noise_in_Q, hook_mu, hook_jac, hook_var, *pack,
                           sn2)
    iout[I_CLIPPED] = 1 if clipped else 0
    off = gate and direction_gate(z, n, gated, speed)
    iout[I_OFF] = 1 if off else 0
    if off:
        for j in range(n):
            hook_mu[j] = 0.0
            for c in range(3 * n):
                hook_jac[j, c] = 0.0


@njit
def sample_tail(buf, d, m, n, dt, gp_var_scale, hook_mu, hook_jac, hook_var, P_max, diverged, iout, fout):
    """Steps 3-4 from the residual on: μ, σ², ∂μ/∂z into the step, the filter step, the largest
    predicted variance against its cap, bounded P and the Cholesky attempt of P."""
    (A, xdot, mu, dmu, dz_dx, sigma2, G_mu, Sigma_nom, R, y, x, P, F, Gam, Q, x_prior, P_prior, S, K,
     innovation, aug, E, Bx, L, rhs, IKH, work, KR) = akf_core.views(buf, d, m, n)
    for j in range(n):
        mu[j] = hook_mu[j]
        # eq:GPvarfwd: σ² held over the configuration's step (AKF._gp_var_scale)
        sigma2[j] = hook_var[j] * gp_var_scale if gp_var_scale != 1.0 else hook_var[j]
        for c in range(3 * n):
            dmu[j, c] = hook_jac[j, c]
    # Alg. 2 lines 7-11 / Alg. 1 lines 3-8
    status, nis = akf_core.filter_step(buf, d, m, n, True, dt)
    iout[I_STATUS] = status
    fout[F_NIS] = nis
    if status != akf_core.OK:
        return
    # the largest predicted variance over its cap (AKF.DIVERGED), then bounded P
    pmax = -np.inf
    for i in range(d):
        v = P_prior[i, i] / P_max[i]
        if v > pmax or v != v:
            pmax = v
            if v != v:
                break
    fout[F_PMAX] = pmax
    if not pmax < diverged:       # the caller raises CovarianceDiverged before P is capped
        return
    iout[I_CAPPED] = akf_core.cap_covariance(P, P_max)
    iout[I_PD] = is_pd(P)


@njit
def rigid_head(q, theta_m, dt, buf, d, m, n, ang, kin_buf, kin_C, kin_out, ddq, z, s_mode, S_base, B_u,
               tau_m_var, Gamma_u, iout, kernel, f0, q_l, dq_l, tau_l):
    """Steps 1-2 of a sample of a model with a rigid body (:func:`sample_head`), then what its
    forward dynamics takes at x̂_{k−1} (RigidTables.f_and_F): q, q̇ and the load-side torque
    besides the body's own bias (:func:`~sea_daemon.core.dynamics.load_side_torque`, no residual)."""
    sample_head(q, theta_m, dt, buf, d, m, n, ang, kin_buf, kin_C, kin_out, ddq, z, s_mode, S_base, B_u,
                tau_m_var, Gamma_u, iout)
    x = akf_core.views(buf, d, m, n)[10]
    for j in range(n):
        q_l[j] = x[j] + x[n + j]
        dq_l[j] = x[2 * n + j] + x[3 * n + j]
    tau = dynamics.load_side_torque(kernel, x, f0)
    for j in range(n):
        tau_l[j] = tau[j]


@njit
def rigid_body(buf, d, m, n, u, kernel, ddq_l, ddq_dq, ddq_dv, Minv, f0, z, box_lo, box_hi, box_z, box_clipped,
               noise_in_Q, hook_mu, hook_jac, hook_var, pack, sn2, keep_prev, x_prev, P_prev, iout, gate, gated,
               speed):
    """Step 3 of a sample of a model with a rigid body, given its forward dynamics and their
    derivatives at x̂_{k−1} (q̈, ∂q̈/∂q, ∂q̈/∂q̇, M⁻¹: RigidBody.forward_derivatives): F_nom,
    f_nom (:func:`~sea_daemon.core.dynamics.rigid_state`), the θ̈_s rows of G_μ = I_μ M⁻¹, then
    :func:`sample_residual`."""
    (A, xdot, mu, dmu, dz_dx, sigma2, G_mu, Sigma_nom, R, y, x, P, F, Gam, Q, x_prior, P_prior, S, K,
     innovation, aug, E, Bx, L, rhs, IKH, work, KR) = akf_core.views(buf, d, m, n)
    dynamics.rigid_state(kernel, x, u, ddq_l, ddq_dq, ddq_dv, Minv, f0, f0, A, xdot, True)
    for i in range(n):
        for j in range(n):
            G_mu[3 * n + i, j] = Minv[i, j]
    sample_residual(buf, d, m, n, z, box_lo, box_hi, box_z, box_clipped, noise_in_Q, hook_mu, hook_jac, hook_var,
                    pack, sn2, keep_prev, x_prev, P_prev, iout, gate, gated, speed)


@njit
def frozen_finish(x, P, sqrt_s, x_hat, P_hat, tau_hat, tau_sigma, tau_bound, tau_m, ht, hu, hcap, t, iout):
    """The sample's end: the published estimate (akf_core.fill_estimate) and τ_m of this sample
    pushed into the input history at time ``t`` (AKF._push_input; ``iout[I_HHEAD]`` its head)."""
    akf_core.fill_estimate(x, P, sqrt_s, x_hat, P_hat, tau_hat, tau_sigma, tau_bound)
    n = tau_m.shape[0]
    h = iout[I_HHEAD] + 1
    if h >= hcap:
        h = 0
    iout[I_HHEAD] = h
    ht[h] = t
    ht[h + hcap] = t
    for j in range(n):
        hu[h, j] = tau_m[j]
        hu[h + hcap, j] = tau_m[j]


@warmer
def _warm() -> None:
    """:func:`frozen_sample` and the rigid body's :func:`rigid_head`, :func:`rigid_body`,
    :func:`sample_tail` with the argument types :class:`GPAKF` passes (one joint)."""
    pack = GPPack([warm_up_loggp()])
    n, d, m = 1, 5, 4
    buf = np.zeros(akf_core.buffer_size(d, m, n))
    v = lambda k: np.zeros(k)  # noqa: E731
    iout = np.zeros(7, dtype=np.int64)
    iout[I_KIN_HEAD] = 6
    gated = np.zeros((n, 2), dtype=np.bool_)
    kin = (v(2 * n), np.zeros((14, 2 * n)), np.zeros((3, 7)), np.zeros((3, 2 * n)), v(n), v(3 * n))
    box = (-np.ones(3), np.ones(3), v(3), np.zeros(3, np.bool_))
    hook = (v(n), np.zeros((n, 3 * n)), v(n), pack.args(), pack.sn2, True, v(d), np.zeros((d, d)))
    for noise in (False, True):
        frozen_sample(v(n), v(n), 0.01, buf, d, m, n, *kin, np.zeros((8, n)), 2, np.eye(d), np.ones((d, n)), 1e-4,
                      np.zeros((d, n)), np.zeros((d, d)), np.zeros((d, n)), np.zeros((n, n)), 1.0, *box, noise,
                      *hook, np.ones(d), 1e12, iout, v(2), noise, gated, 0.03)
        rigid_head(v(n), v(n), 0.01, buf, d, m, n, *kin, 2, np.eye(d), np.ones((d, n)), 1e-4, np.zeros((d, n)), iout,
                   dynamics.example(n).packed(), v(n), v(n), v(n), v(n))
        rigid_body(buf, d, m, n, v(n), dynamics.example(n).packed(), v(n), np.eye(n), np.eye(n), np.eye(n), v(n),
                   v(3 * n), *box, noise, *hook, iout, noise, gated, 0.03)
        sample_tail(buf, d, m, n, 0.01, 1.0, v(n), np.zeros((n, 3 * n)), v(n), np.ones(d), 1e12, iout, v(2))
    frozen_finish(v(d), np.eye(d), 1.0, v(d), np.zeros((d, d)), v(n), v(n), v(n), v(n), v(8), np.zeros((8, n)), 4,
                  0.0, iout)
