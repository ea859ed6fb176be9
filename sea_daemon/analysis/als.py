"""Autocovariance least squares (ALS): noise covariances Q, R from a filter's innovations.

Odelson, Rajamani & Rawlings, "A new autocovariance least-squares method for estimating
noise covariances", Automatica 42 (2006) 303-308 — the method Sec. V-B of the paper uses to
set R.

Model (linear time-invariant)      x_{k+1} = A x_k + G w_k,   y_k = C x_k + v_k,
                                   w ~ N(0, Q), v ~ N(0, R) independent,
run with a stable, possibly sub-optimal, fixed filter gain L (x̂_{k|k} = x̂_{k|k−1} + L e_k,
x̂_{k+1|k} = A x̂_{k|k}).  The innovations e_k = y_k − C x̂_{k|k−1} then obey
    ε_{k+1} = Ā ε_k + G w_k − A L v_k,   e_k = C ε_k + v_k,   Ā = A − A L C,
so with P = Ā P Āᵀ + G Q Gᵀ + A L R Lᵀ Aᵀ (discrete Lyapunov):
    C_0 = E[e_k e_kᵀ]     = C P Cᵀ + R
    C_j = E[e_{k+j} e_kᵀ] = C Ā^j P Cᵀ − C Ā^{j−1} A L R,      j = 1 … N−1.
Every C_j is linear in (Q, R).  The sample autocovariances Ĉ_j of a long innovation
sequence give an over-determined linear system for the unknown entries of Q and R (the
stacked "autocovariance matrix" of Odelson et al.); we build its matrix column by column
(one Lyapunov solve per unknown), which is the same linear map as their Kronecker form.

Positive semi-definiteness: with ``diag=True`` the unknowns are diag(Q), diag(R) ≥ 0 and
the problem is solved by non-negative least squares (scipy.optimize.nnls); with
``diag=False`` by least squares over symmetric Q, R followed by projection onto the PSD
cone (eigenvalues clipped at 0).  Conditioning: innovations are whitened per channel by
their sample standard deviation and the design columns are normalised; the result is
mapped back.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.linalg import solve_discrete_are
from scipy.optimize import nnls

from sea_daemon.analysis.passive_noise import lyapunov_sum
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.linalg import discretize
from sea_daemon.errors import InputError


def sample_autocov(e: np.ndarray, lags: int) -> np.ndarray:
    """Ĉ_j = 1/(N − j) Σ_k e_{k+j} e_kᵀ for j = 0 … lags−1 → (lags, p, p)."""
    e = np.asarray(e, dtype=float)
    if e.ndim == 1:
        e = e[:, None]
    N = e.shape[0]
    if N <= 2 * lags:
        raise InputError(f"ALS needs more than {2 * lags} innovations for {lags} lags, got {N}")
    out = np.empty((lags, e.shape[1], e.shape[1]))
    for j in range(lags):
        out[j] = e[j:].T @ e[:N - j] / (N - j)
    return out


def model_autocov(A, G, C, L, Q, R, lags: int) -> np.ndarray:
    """Theoretical innovation autocovariances C_0 … C_{lags−1} (Odelson et al. 2006, eq. above)."""
    A, G, C, L = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (A, G, C, L))
    AL = A @ L
    Abar = A - AL @ C
    W = G @ Q @ G.T + AL @ R @ AL.T
    # by doubling, not scipy's direct solve: the Kronecker system I − Ā⊗Ā of a filter whose states
    # span the encoders' 1e-7 rad and the torque's N m is ill-conditioned by its scales alone
    # (rcond ~1e-16 at 1 kHz) although P itself is well determined
    P = lyapunov_sum(Abar, W)
    out = np.empty((lags, C.shape[0], C.shape[0]))
    out[0] = C @ P @ C.T + R
    Aj = np.eye(A.shape[0])            # Ā^{j−1}
    for j in range(1, lags):
        out[j] = C @ (Aj @ Abar) @ P @ C.T - C @ Aj @ AL @ R
        Aj = Aj @ Abar
    return out


def _stack(Cs: np.ndarray) -> np.ndarray:
    """C_0 upper triangle (symmetric) then C_1 … C_{N−1} in full."""
    p = Cs.shape[1]
    iu = np.triu_indices(p)
    return np.concatenate([Cs[0][iu], Cs[1:].ravel()])


def _basis(n: int, diag: bool) -> list[np.ndarray]:
    if diag:
        return [np.diag(np.eye(n)[i]) for i in range(n)]
    out = []
    for i in range(n):
        for j in range(i, n):
            E = np.zeros((n, n))
            E[i, j] = E[j, i] = 1.0
            out.append(E)
    return out


def _psd(X: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (X + X.T))
    return (V * np.clip(w, 0.0, None)) @ V.T


def stable_gain(A, C, Q, R) -> np.ndarray:
    """Steady-state Kalman filter gain L = P Cᵀ (C P Cᵀ + R)⁻¹ from the DARE (a guess of Q, R
    suffices: ALS only needs L to make A − A L C stable)."""
    A, C = np.atleast_2d(A), np.atleast_2d(C)
    P = solve_discrete_are(A.T, C.T, np.asarray(Q, float), np.asarray(R, float))
    return P @ C.T @ np.linalg.inv(C @ P @ C.T + R)


def innovations(A, C, L, y: np.ndarray, x0: np.ndarray | None = None, Bu: np.ndarray | None = None) -> np.ndarray:
    """e_k = y_k − C x̂_{k|k−1} of the fixed-gain filter (``Bu[k]``: known input term added to
    x̂_{k+1|k}, e.g. Γ_u u_k plus an affine offset of a linearisation)."""
    A, C, L = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (A, C, L))
    y = np.atleast_2d(np.asarray(y, dtype=float))
    N = y.shape[0]
    x = np.zeros(A.shape[0]) if x0 is None else np.array(x0, dtype=float)
    e = np.empty_like(y)
    for k in range(N):
        e[k] = y[k] - C @ x
        x = A @ (x + L @ e[k])
        if Bu is not None:
            x = x + Bu[k]
    return e


def identify(A, G, C, L, innovations: np.ndarray, lags: int = 15, diag: bool = True,
             Q: np.ndarray | None = None, burn_in: int = 0,
             R_basis: list[np.ndarray] | None = None, return_coefficients: bool = False):
    """ALS estimate (Q, R) from the innovations of the fixed-gain filter (A, C, L).

    A (d×d), G (d×g), C (p×d), L (d×p); ``innovations`` (N, p); ``lags`` the number N of
    autocovariance lags; ``diag`` estimates diagonal Q, R (nnls, ≥ 0) or full symmetric ones
    (least squares + PSD projection); ``Q`` given → only R is estimated (Q returned as given);
    ``burn_in`` leading innovations dropped (filter transient); ``R_basis``: R = Σ θ_i B_i
    with θ ≥ 0 over the given PSD matrices (a structured R, e.g. from independent sensors);
    ``return_coefficients``: return (Q, R, θ_R) with the coefficients of R in its basis.
    Raises InputError if A − A L C is not stable or the data are too short.
    """
    A, G, C, L = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (A, G, C, L))
    d, g, p = A.shape[0], G.shape[1], C.shape[0]
    if C.shape[1] != d or G.shape[0] != d or L.shape != (d, p):
        raise InputError(f"ALS: inconsistent shapes A {A.shape}, G {G.shape}, C {C.shape}, L {L.shape}")
    rad = np.max(np.abs(np.linalg.eigvals(A - A @ L @ C)))
    if not rad < 1.0:
        raise InputError(f"ALS: the filter gain does not stabilise A − A L C (spectral radius {rad:.4g}, "
                         f"must be < 1)")
    e = np.asarray(innovations, dtype=float)[burn_in:]
    if e.ndim == 1:
        e = e[:, None]
    if e.shape[1] != p:
        raise InputError(f"ALS: innovations have {e.shape[1]} channels, C has {p} rows")
    if not np.all(np.isfinite(e)):
        raise InputError("ALS: innovations contain NaN or inf")
    # whiten the channels: e' = S⁻¹ e  ⇒  C' = S⁻¹ C, L' = L S, R' = S⁻¹ R S⁻¹
    s = e.std(axis=0)
    s[s <= 0] = 1.0
    Cw, Lw, ew = C / s[:, None], L * s[None, :], e / s
    b = _stack(sample_autocov(ew, lags))
    Zg, Zp = np.zeros((g, g)), np.zeros((p, p))
    q_basis = [] if Q is not None else _basis(g, diag)
    # whitened basis S⁻¹ B S⁻¹ for a structured R
    r_basis = _basis(p, diag) if R_basis is None else [np.asarray(B, float) / np.outer(s, s) for B in R_basis]
    cols = [_stack(model_autocov(A, G, Cw, Lw, Eq, Zp, lags)) for Eq in q_basis]
    cols += [_stack(model_autocov(A, G, Cw, Lw, Zg, Er, lags)) for Er in r_basis]
    M = np.column_stack(cols)
    if Q is not None:
        b = b - _stack(model_autocov(A, G, Cw, Lw, np.asarray(Q, float), Zp, lags))
    norms = np.linalg.norm(M, axis=0)
    norms[norms == 0] = 1.0
    Mn = M / norms
    if diag or (R_basis is not None and Q is not None):
        theta, _ = nnls(Mn, b)
    else:
        theta = np.linalg.lstsq(Mn, b, rcond=None)[0]
    theta = theta / norms
    nq = len(q_basis)
    Qhat = np.asarray(Q, float) if Q is not None else sum(t * E for t, E in zip(theta[:nq], q_basis))
    Rw = sum(t * E for t, E in zip(theta[nq:], r_basis))
    Rhat = Rw * np.outer(s, s)
    if not diag:
        Rhat = _psd(Rhat)
        if Q is None:
            Qhat = _psd(Qhat)
    if return_coefficients:
        return Qhat, Rhat, theta[nq:].copy()
    return Qhat, Rhat


# ---------------------------------------------------------------------------- SEA logs

def encoder_R(var_m, var_q, fir) -> np.ndarray:
    """R (4n×4n) of y = [θ_m, θ_s, θ̇_m, θ̇_s] from independent white encoder noises.

    θ_m sees ν_m, θ_s = q − θ_m sees ν_q − ν_m; the velocities are the differentiator's FIR
    (rows c_a, c_v of ``fir``) applied to the same noise: R_vel = ‖c_v‖² R_ang,
    R_ang,vel = (c_a·c_v) R_ang.
    """
    var_m = np.atleast_1d(np.asarray(var_m, dtype=float))
    var_q = np.atleast_1d(np.asarray(var_q, dtype=float))
    n = var_m.size
    Ra = np.zeros((2 * n, 2 * n))
    for j in range(n):
        t_m = np.zeros(2 * n)
        t_m[j], t_m[n + j] = 1.0, -1.0
        Ra += var_m[j] * np.outer(t_m, t_m)
        Ra[n + j, n + j] += var_q[j]
    Cf = np.asarray(fir, dtype=float)
    g_v2 = float(Cf[1] @ Cf[1])
    c_av = float(Cf[0] @ Cf[1])
    R = np.zeros((4 * n, 4 * n))
    R[:2 * n, :2 * n] = Ra
    R[2 * n:, 2 * n:] = g_v2 * Ra
    R[:2 * n, 2 * n:] = R[2 * n:, :2 * n] = c_av * Ra
    return R


def identify_noise(cfg, log, lags: int = 15, burn_in: int = 50, diag: bool = True,
                   q_known: bool = False, channels: str = "angles") -> dict:
    """ALS on a measured log for the SEA AKF's R (and Q), as Sec. V-B does.

    1. run the AKF of ``cfg`` over ``log`` (its measurement y = [θ_m, θ_s, θ̇_m, θ̇_s] from the
       encoders and its state estimates);
    2. linearise the SEA model at the log's mean operating point (x̄, ū) and discretise it
       (SEAModel.F_nom + local-linearisation step): x_{k+1} = F x_k + Γ_u u_k + c, with the
       affine term c of the linearisation;
    3. fixed gain L from the DARE with the configured Σ_nom, R (ALS only needs A − ALC stable);
    4. innovations of that fixed-gain filter over the same y, u; ALS (:func:`identify`).

    The fixed-gain linear filter (not the AKF's own time-varying innovations) is what the
    ALS theory assumes; non-linearities away from the operating point are absorbed in Q.

    ``channels``: ALS needs white measurement noise.  The encoder angles have it; the
    velocities of y come from the causal differentiator, i.e. they are the angle noise
    passed through an FIR filter — coloured and correlated with the angles.  "angles"
    (default) therefore runs ALS on y_angles = [θ_m, θ_s] only, with R structured as two
    independent encoders per joint (θ_m sees ν_m, θ_s = q − θ_m sees ν_q − ν_m, so
    Cov(θ_m, θ_s) = −σ²_m): the unknowns are the encoder variances σ²_m, σ²_q ≥ 0 (nnls).
    The velocity block follows from the differentiator's FIR rows c_a, c_v
    (CausalDifferentiator.C): R_vel = ‖c_v‖² R_ang, R_ang,vel = (c_a·c_v) R_ang — the
    covariance of the differentiated white noise at one instant (its time correlation is
    not representable in R).  The returned R is then a full 4n×4n matrix.  "all" runs ALS on the four channels as
    the paper does (the white-noise assumption is then violated for the velocities).
    Returns a dict with R, Q (G = I, the AKF's Σ_nom convention), the operating point,
    the number of innovations used and the spectral radius of A − A L C.
    """
    n = cfg.joints
    N = len(log)
    if N <= burn_in + 2 * lags + 1:
        raise InputError(f"{log.path}: identify-noise needs more than {burn_in + 2 * lags + 1} samples "
                         f"(burn-in {burn_in} + 2 × {lags} lags), got {N}")
    akf = AKF(cfg, dt=log.dt)
    Y, X, U = _akf_run(akf, log)
    x_op, u_op = X.mean(axis=0), U.mean(axis=0)
    F, G_u, c = _linearised(akf, x_op, u_op, float(np.median(np.diff(log.t))))
    if channels not in ("angles", "all"):
        raise InputError(f"channels must be 'angles' or 'all', got {channels!r}")
    p = 2 * n if channels == "angles" else 4 * n
    H = akf.H[:p]
    Y = Y[:, :p]
    R0 = np.array(cfg.estimator.R, dtype=float)[:p, :p]
    Q0 = np.array(cfg.estimator.Sigma_nom, dtype=float)
    L = _fixed_gain(F, H, Q0, R0)
    e = innovations(F, H, L, Y, x0=X[0], Bu=U @ G_u.T + c)
    basis = _encoder_basis(n) if channels == "angles" else None
    # process noise enters through the velocity and τ_h,act (and τ̇_h,act) states only
    # (G = [0; I]): angles integrate the velocities, so their own per-step noise is not
    # identifiable from measurement noise on them and is physically negligible
    d = akf.d                      # 5n, or 6n with the integrated walk (StateLayout)
    Gq = np.eye(d)[:, 2 * n:]
    Qhat, Rhat, theta_R = identify(F, Gq, H, L, e, lags=lags, diag=diag,
                                   Q=Q0[2 * n:, 2 * n:] if q_known else None, burn_in=burn_in,
                                   R_basis=basis, return_coefficients=True)
    Q_full = np.zeros((d, d))
    Q_full[2 * n:, 2 * n:] = Qhat
    Qhat = Q_full
    rad = float(np.max(np.abs(np.linalg.eigvals(F - F @ L @ H))))
    enc = None
    if channels == "angles":
        th = theta_R
        enc = {"theta_m": th[0::2].tolist(), "q": th[1::2].tolist()}
        Rhat = encoder_R(th[0::2], th[1::2], akf.kin.C)
    return {"R": Rhat, "channels": channels, "encoder_variances": enc, "fir": np.asarray(akf.kin.C, float), "Q": Qhat, "x_op": x_op, "u_op": u_op, "innovations": int(N - burn_in),
            "lags": lags, "spectral_radius": rad}


def _akf_run(akf, log) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 1 of :func:`identify_noise`: the AKF over the log; per sample its measurement y (N, 4n),
    its state x̂ (N, d: 5n or 6n) and the input u that acted over step k → k+1 (N, n)."""
    n, N = akf.model.n, len(log)
    Y = np.empty((N, 4 * n))
    X = np.empty((N, akf.d))
    U = np.empty((N, n))
    akf.reset(log.q[0], log.theta_m[0], log.tau_m[0])
    Y[0], X[0] = akf.y, akf.x
    for k in range(1, N):
        akf.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        U[k - 1] = akf.u_applied if akf.has_delay else log.tau_m[k - 1]
        Y[k], X[k] = akf.y, akf.x
    U[N - 1] = log.tau_m[N - 1]
    return Y, X, U


def _linearised(akf, x_op: np.ndarray, u_op: np.ndarray, dt: float):
    """Step 2 of :func:`identify_noise`: x⁺ ≈ F x + Γ_u u + c about the operating point, in the
    filter's state (its :class:`~sea_daemon.core.model.StateLayout`)."""
    model = akf.model
    A = model.F_nom(x_op, u_op)
    # ZOH at the operating point: F = e^{A dt}, [Δx_op, Γ_u] = ∫₀^dt e^{As} ds [f_nom, B]
    F, Gam = discretize(A, np.column_stack([model.f_nom(x_op, u_op), akf.layout.pad(model.B_nom())]), dt)
    dx_op, G_u = Gam[:, 0], Gam[:, 1:]
    # x⁺ ≈ x + Δx_op + (F − I)(x − x_op) + Γ_u (u − u_op)  (ΦA = F − I)
    c = dx_op - (F - np.eye(F.shape[0])) @ x_op - G_u @ u_op
    return F, G_u, c


def _fixed_gain(F: np.ndarray, H: np.ndarray, Q0: np.ndarray, R0: np.ndarray) -> np.ndarray:
    """The stable fixed gain of :func:`identify_noise` (DARE with the configured Σ_nom, R), or
    InputError."""
    try:
        return stable_gain(F, H, Q0 + 1e-12 * np.eye(F.shape[0]), R0 + 1e-12 * np.eye(H.shape[0]))
    except (np.linalg.LinAlgError, ValueError) as e:
        raise InputError(f"identify-noise: no stabilising filter gain for the linearised model ({e}); "
                         f"check estimator.R and estimator.Sigma_nom") from None


def _encoder_basis(n: int) -> list[np.ndarray]:
    """R of y_angles as Σ_j σ²_m,j B_m,j + σ²_q,j B_q,j: the matrices B (m, q per joint).

    y_angles = [θ_m, θ_s] = T_e [θ_m,enc, q_enc] + noise of two independent encoders per joint:
    θ_m sees ν_m, θ_s = q − θ_m sees ν_q − ν_m."""
    basis = []
    for j in range(n):
        t_m = np.zeros(2 * n)
        t_m[j], t_m[n + j] = 1.0, -1.0
        t_q = np.zeros(2 * n)
        t_q[n + j] = 1.0
        basis += [np.outer(t_m, t_m), np.outer(t_q, t_q)]
    return basis


#: floor for identified variances of the "all"-channel mode, so a configuration stays valid
R_FLOOR = 1e-12


def floored_R(cfg, res: dict) -> tuple[np.ndarray, dict | None, list]:
    """R of :func:`identify_noise`'s result with variances floored: encoder variances at the
    quantisation noise Δ²/12 of the encoders (``hardware.encoder_counts``, else 2^encoder_bits
    counts) — Δ = 2π/counts for the load encoder, 2π/(counts · gear_ratio) joint side for the
    motor encoder, which sits before the gear (R rebuilt, stays PSD) — or diagonal entries at
    :data:`R_FLOOR`.  Returns (R, encoder variances, floored names)."""
    n = cfg.joints
    R = np.array(res["R"], dtype=float)
    enc = res.get("encoder_variances")
    if enc is not None:
        # joint-side quanta of the two encoders (HardwareConfig.encoder_resolution)
        dq_, dm_ = cfg.hardware.encoder_resolution(n)
        q_var, m_var = dq_**2 / 12.0, dm_**2 / 12.0
        vm, vq = np.array(enc["theta_m"]), np.array(enc["q"])
        floored = [f"theta_m_{j + 1}" for j in np.flatnonzero(vm < m_var)]
        floored += [f"q_{j + 1}" for j in np.flatnonzero(vq < q_var)]
        vm, vq = np.maximum(vm, m_var), np.maximum(vq, q_var)
        return encoder_R(vm, vq, res["fir"]), {"theta_m": vm.tolist(), "q": vq.tolist()}, floored
    floored = [int(i) for i in np.flatnonzero(np.diag(R) < R_FLOOR)]
    R[np.diag_indices(4 * n)] = np.maximum(np.diag(R), R_FLOOR)
    return R, None, floored


def config_with_R(cfg, R: np.ndarray, Q: np.ndarray | None = None):
    """``cfg`` with estimator.R = R and P0's measurement block = R (Sec. V-B: P0 set to R);
    with ``Q`` also Sigma_nom = Q."""
    n = cfg.joints
    est = cfg.estimator
    P0 = np.array(est.P0, dtype=float)
    P0[:4 * n, :4 * n] = R
    kw = {"Sigma_nom": Q} if Q is not None else {}
    return dataclasses.replace(cfg, estimator=dataclasses.replace(est, R=R, P0=P0, **kw))
