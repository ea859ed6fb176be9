"""The two model residuals of a measured log.

From the log's encoder angles and motor torque, with zero-phase smoothed derivatives (an
offline log allows a non-causal filter), and the configured model:

load side  (eq:unknwn_load solved for what the model does not explain)
    r_load  = τ_h,act − (M q̈ + C(q) + Σ_load e + τ_s)
motor side (eq:motorside)
    r_motor = κ τ_m(t − d) − (J θ̈_m + D_m θ̇_m + Σ_motor e − τ_s)

τ_h,act is the log's ``tau_h_act`` column when present, else 0 (ass:passive_human).  An
undeclared effect that the load side must overcome shows up as +e in r_load only, one on the
motor side as +e in r_motor only, and an error Δτ_s of the spring torque as +Δτ_s in r_load
and −Δτ_s in r_motor: opposite signs.  r_load + r_motor is f(z) of eq:loadsidewmotor.

Consistent filtering ("filter every signal of the equation with the same filter", Ljung,
System Identification, §14.3): each balance is formed sample by sample from the measured
angles, the central second difference of the angles for q̈ and θ̈_m, the zero-phase
smoothed velocities (:func:`sea_daemon.core.kinematics.smooth_derivatives`) for the velocity
arguments, and the logged torque; the whole balance is then passed through one zero-phase
Savitzky–Golay smoother S.  An effect e therefore appears in the residual as S(e), exactly
as the candidates' regressors do (:mod:`.candidates` builds them through this function),
and the inertial terms see the same filter as the torques at every frequency (a separate
SG second-derivative filter does not, and a lightly damped controller's oscillation then
leaks into the residual).  The logged torque is the command
held over the sample (zero-order hold): its continuous-time equivalent at the sample
instant is the mean of the two neighbouring commands, i.e. the command sequence
interpolated at t − dt/2; a declared delay d shifts it further.

Arrays are (N, n) per channel; :func:`residual_channels` returns (N, 2n) with the load
channels first.  Everything here is vectorised over time; the per-sample maths is the
:class:`~sea_daemon.core.model.SEAModel` (its attributes) and the effects' own ``torque_array``, and
``tests/test_diagnose_residuals.py`` checks r_load + r_motor against
``SEAModel.residual_from_kinematics``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import correlate1d
from scipy.signal import savgol_coeffs

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.dynamics import spring_torque_many
from sea_daemon.core.effects import Coulomb, Stribeck
from sea_daemon.core.kinematics import smooth_derivatives
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel


@dataclass
class Kinematics:
    """Smoothed kinematics of a log (encoder readings as logged, offsets not yet removed)."""

    t: np.ndarray          # (N,)
    q_raw: np.ndarray      # (N, n) load angle as logged
    theta_m_raw: np.ndarray  # (N, n) motor angle as logged
    q: np.ndarray          # (N, n) load angle as read (= q_raw)
    dq: np.ndarray         # (N, n) short-window velocity
    ddq: np.ndarray        # (N, n) S(second difference)
    theta_m: np.ndarray    # (N, n) motor angle as read (= theta_m_raw)
    dtheta_m: np.ndarray
    ddtheta_m: np.ndarray
    d2q: np.ndarray        # (N, n) central second difference of q_raw (unsmoothed)
    d2theta_m: np.ndarray
    tau_m: np.ndarray      # (N, n) motor torque command as logged (raw)
    tau_h_act: np.ndarray | None
    window: int
    degree: int
    _tau_cache: dict = field(default_factory=dict, repr=False)
    _sg: np.ndarray | None = field(default=None, repr=False)

    @property
    def n(self) -> int:
        return self.q.shape[1]

    @property
    def N(self) -> int:
        return self.t.shape[0]

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.t)))

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """S: zero-phase Savitzky–Golay smoothing (derivative 0) of ``window`` samples and
        ``degree``; the ends are padded with the end value (what S does there matters little:
        it is the same for every term, and the fit leaves the ends out)."""
        if self._sg is None:
            w = min(self.window, self.N if self.N % 2 else self.N - 1)
            self._sg = savgol_coeffs(w, min(self.degree, w - 1))
        return correlate1d(np.asarray(x, dtype=float), self._sg, axis=0, mode="nearest")

    def shifted_command(self, shift: float, delay: np.ndarray) -> np.ndarray:
        """τ_m(t − shift − d_j) per joint j [N m], linearly interpolated on the log's times
        (cached per shift and delays, up to 256 of them)."""
        key = (shift, *np.round(delay, 12).tolist())
        sm = self._tau_cache.get(key)
        if sm is None:
            tau = np.empty_like(self.tau_m)
            for j in range(self.n):
                tq = self.t - shift - delay[j]
                tau[:, j] = np.interp(tq, self.t, self.tau_m[:, j])
            sm = tau
            if len(self._tau_cache) < 256:
                self._tau_cache[key] = sm
        return sm


Z95 = 1.959963984540054

#: default length [s] of the zero-phase Savitzky–Golay window (degree 3).  Long enough that
#: the acceleration noise from the motor-torque noise does not bias inertia-like terms
#: (errors in variables), short against the human motions (≳ 1 s).
WINDOW_S = 0.25
#: default length [s] of the velocity window (degree 3) for the nonlinear terms
VELOCITY_WINDOW_S = 0.05


def window_samples(t: np.ndarray, window_s: float = WINDOW_S) -> int:
    """Odd window length [samples] for ``window_s`` seconds at the log's rate (≥ 5, ≤ N)."""
    dt = float(np.median(np.diff(t)))
    w = max(5, int(round(window_s / dt)))
    w = min(w, len(t) if len(t) % 2 else len(t) - 1)
    return w if w % 2 else w + 1


def second_difference(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(x[k+1] − 2x[k] + x[k−1]) / dt² on a uniform grid; the end rows repeat their neighbour."""
    dt = float(np.median(np.diff(t)))
    x = np.asarray(x, dtype=float)
    d = np.empty_like(x)
    d[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / dt**2
    d[0], d[-1] = d[1], d[-2]
    return d


def kinematics_from_log(log: MeasuredLog, window: int | None = None, degree: int = 3,
                        velocity_window: int | None = None) -> Kinematics:
    """Kinematics of a log for the residuals.

    ``window`` [samples] of the smoother S (default :data:`WINDOW_S` seconds);
    ``velocity_window`` [samples] of the velocity estimate used inside nonlinear terms
    (default :data:`VELOCITY_WINDOW_S`): short, so that e(q̇) sees the velocity the plant
    had (19-bit encoders make short-window velocities precise), and S is applied after the
    non-linearity.  Accelerations ``ddq``/``ddtheta_m`` are S(central second difference),
    the ones the balances use.
    """
    if window is None:
        window = window_samples(log.t)
    if velocity_window is None:
        velocity_window = window_samples(log.t, VELOCITY_WINDOW_S)
    _, dq, _ = smooth_derivatives(log.t, log.q, velocity_window, degree)
    _, dth, _ = smooth_derivatives(log.t, log.theta_m, velocity_window, degree)
    kin = Kinematics(t=np.asarray(log.t, float), q_raw=np.asarray(log.q, float),
                     theta_m_raw=np.asarray(log.theta_m, float),
                     d2q=second_difference(log.t, log.q), d2theta_m=second_difference(log.t, log.theta_m),
                     q=np.asarray(log.q, float), dq=dq, ddq=None, theta_m=np.asarray(log.theta_m, float),
                     dtheta_m=dth, ddtheta_m=None, tau_m=np.asarray(log.tau_m, float),
                     tau_h_act=None if log.tau_h_act is None else np.asarray(log.tau_h_act, float),
                     window=window, degree=degree)
    kin.ddq = kin.smooth(kin.d2q)
    kin.ddtheta_m = kin.smooth(kin.d2theta_m)
    return kin


def _effect_sum(effects, n, angle, vel, acc) -> np.ndarray:
    out = np.zeros_like(angle)
    for e in effects:
        j = e.joint
        out[:, j] += e.torque_array(angle[:, j], vel[:, j], acc[:, j])
    return out


def applied_torque(model: SEAModel, kin: Kinematics, zoh: bool = True) -> np.ndarray:
    """κ τ_m(t − d) (eq:motorside), ZOH-centred (t − dt/2); not yet smoothed."""
    shift = 0.5 * kin.dt if zoh else 0.0
    return model.kappa[None, :] * kin.shifted_command(shift, model.delay)


def spring_torque(model: SEAModel, theta_s: np.ndarray, dtheta_s: np.ndarray) -> np.ndarray:
    """τ_s = K_s g(θ_s) + D_s θ̇_s + Σ_spring e(θ_s)  (eq:spring_torque) at every sample of (N, n)
    arrays (:func:`sea_daemon.core.dynamics.spring_torque_many`)."""
    th = np.ascontiguousarray(theta_s, dtype=float)
    out = np.empty_like(th)
    spring_torque_many(model.kernel, th, np.ascontiguousarray(dtheta_s, dtype=float), out)
    return out


def _static_limit(effects, n) -> np.ndarray:
    """Largest friction torque at rest per joint, Σ (F_c + F_s) of the declared friction."""
    F = np.zeros(n)
    for e in effects:
        if isinstance(e, (Coulomb, Stribeck)):
            F[e.joint] += e.F_c if isinstance(e, Coulomb) else e.F_s
    return F


def _deadzone(x: np.ndarray, F: float) -> np.ndarray:
    """x − clip(x, −F, F): what a friction bounded by F cannot take up."""
    return x - np.clip(x, -F, F)


def inertia_and_bias(model: SEAModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N, n) the load side's rigid-body torque per sample: M q̈ + C(q) of a constant-inertia model, and
    M(q) q̈ + C(q, q̇) q̇ + g(q) of a ``model.urdf`` (one RNEA per sample)."""
    if model.rigid is None:
        return ddq @ model.M.T + model.C(q)
    # diagnose evaluates thousands of candidate balances on the same kinematics: the rigid body's
    # part is the same in all of them (the effects are summed apart), so it is kept per input
    rb = model.rigid
    key = (rb.urdf, rb.armature.tobytes(), rb.gravity_vector.tobytes(), q.tobytes(), dq.tobytes(), ddq.tobytes())
    hit = _RIGID_CACHE.get(key)
    if hit is not None:
        return hit
    out = np.array([rb.inverse(a, b, c) for a, b, c in zip(q, dq, ddq)]).reshape(q.shape)
    if len(_RIGID_CACHE) >= 8:
        _RIGID_CACHE.pop(next(iter(_RIGID_CACHE)))
    _RIGID_CACHE[key] = out
    return out


#: the last rigid-body torques of :func:`inertia_and_bias`, keyed by the body and its inputs
_RIGID_CACHE: dict = {}


def residual_channels(model: SEAModel, kin: Kinematics, zoh: bool = True,
                      passive: bool = False, v_stick: float | tuple[float, float] = 0.0) -> np.ndarray:
    """(N, 2n) array [r_load, r_motor] of the model on the log (see module docstring).

    ``passive``: ignore the log's tau_h_act column (ass:passive_human).
    ``v_stick`` [rad/s]: below this speed a side with declared Coulomb/Stribeck friction is
    taken as sticking, and its friction as set-valued (any torque up to the static limit
    Σ F_c + F_s, Coulomb's law at rest): the residual there is only what exceeds the limit.
    The smoothed sign of the model (tanh(v/ε), for the estimator's Jacobians) cannot hold a
    stuck joint, so without this every turning point would leave a residual of up to the
    static friction that no candidate could ever explain.  0 disables it.  A pair
    (load, motor) gives each side its own speed (encoders of different resolution).
    """
    n = kin.n
    # declared encoder offsets: the encoders read angle + δ (docs/interfaces.md §2)
    q, th = model.correct_measurement(kin.q_raw, kin.theta_m_raw)
    dq, dth = kin.dq, kin.dtheta_m
    tau_s = spring_torque(model, q - th, dq - dth)
    fric = [e for e in model.load_effects if isinstance(e, (Coulomb, Stribeck))]
    fric_m = [e for e in model.motor_effects if isinstance(e, (Coulomb, Stribeck))]
    # load side: M q̈ + C(q) + Σ_load e + τ_s − τ_h,act   (eq:unknwn_load)
    fr_l = _effect_sum(fric, n, q, dq, kin.ddq)
    lo = (inertia_and_bias(model, q, dq, kin.d2q) + fr_l
          + _effect_sum([e for e in model.load_effects if e not in fric], n, q, dq, kin.ddq) + tau_s)
    if kin.tau_h_act is not None and not passive:
        lo = lo - kin.tau_h_act
    # motor side: κ τ_m − (J θ̈_m + D_m θ̇_m + Σ_motor e − τ_s)   (eq:motorside)
    fr_m = _effect_sum(fric_m, n, th, dth, kin.ddtheta_m)
    mo = (applied_torque(model, kin, zoh) - kin.d2theta_m @ model.J.T - dth @ model.D_m.T - fr_m
          - _effect_sum([e for e in model.motor_effects if e not in fric_m], n, th, dth, kin.ddtheta_m) + tau_s)
    r_l, r_m = -lo, mo
    vs_l, vs_m = (v_stick, v_stick) if np.isscalar(v_stick) else v_stick
    if vs_l > 0 or vs_m > 0:
        F_l, F_m = _static_limit(fric, n), _static_limit(fric_m, n)
        for j in range(n):
            if F_l[j] > 0 and vs_l > 0:
                st = np.abs(dq[:, j]) < vs_l
                # the friction that balances the load side, bounded by the static limit
                r_l[st, j] = _deadzone(r_l[st, j] + fr_l[st, j], F_l[j])
            if F_m[j] > 0 and vs_m > 0:
                st = np.abs(dth[:, j]) < vs_m
                r_m[st, j] = _deadzone(r_m[st, j] + fr_m[st, j], F_m[j])
    # r_load = S(τ_h,act − (M q̈ + C + Σ e + τ_s)),  r_motor = S(κτ_m − (J θ̈_m + D_m θ̇_m + Σ e − τ_s))
    return kin.smooth(np.hstack([r_l, r_m]))


def integrated_autocorr_time(y: np.ndarray, max_lag: int = 200) -> float:
    """τ_int = 1 + 2 Σ ρ_k (summed until ρ_k first drops below 0.05), per column, max over columns.

    Sokal's estimator (Monte Carlo textbook); y (N, c)."""
    y = np.atleast_2d(y.T).T
    taus = []
    for col in y.T:
        x = col - col.mean()
        v = float(np.dot(x, x))
        if v <= 0:
            continue
        L = min(max_lag, len(x) // 4)
        f = np.fft.rfft(x, 2 * len(x))
        ac = np.fft.irfft(f * np.conj(f))[:L + 1] / v
        s = 1.0
        for k in range(1, L + 1):
            if ac[k] < 0.05:
                break
            s += 2.0 * ac[k]
        taus.append(s)
    return float(max(taus)) if taus else 1.0


#: samples of the short Savitzky–Golay low-pass (degree 2) that keeps the encoder's
#: second-difference noise out of the fast part of the motor balance (:func:`fast_command_gain`)
FAST_LOWPASS = 5


@dataclass
class FastGain:
    """The gain with which the fast part of the command reaches the motor side, per joint."""

    kappa: np.ndarray        # (n,) delivered / commanded, relative to the declared κ₀ times κ₀
    half_width: np.ndarray   # (n,) 95 % half-width (NaN: too few moving samples)
    samples: np.ndarray      # (n,) moving samples used


def fast_command_gain(model: SEAModel, kin: Kinematics, v_moving: float, zoh: bool = True) -> FastGain:
    """κ of the drive from the fast part of the motor balance (eq:motorside), per joint.

    A gain error of the drive scales every frequency of the command alike.  In a closed loop the
    slow part of the command is what the controller needs against friction and offsets, so a
    gain fitted to the smoothed residual can stand in for them (the command follows the
    friction); the fast part — what the smoother S removes, x − S(x), low-passed over
    :data:`FAST_LOWPASS` samples against the encoders' second-difference noise — is the
    controller's reaction to noise and quantisation, which friction does not follow.  So with
    b = J θ̈_m + D_m θ̇_m + Σ_motor e − τ_s (the declared motor side) and u = κ₀ τ_m(t − d − T/2),
    b_fast = κ_rel u_fast − κ_rel d' u̇_fast + noise is fitted by least squares over the samples
    where the motor moves (|θ̇_m| > ``v_moving``: a sticking motor takes up the command in its
    static friction), d' a small undeclared delay.  The command is known exactly (no
    errors-in-variables bias); the 95 % half-width is inflated by the autocorrelation time.
    """
    n = kin.n
    q, th = model.correct_measurement(kin.q_raw, kin.theta_m_raw)
    dq, dth = kin.dq, kin.dtheta_m
    tau_s = spring_torque(model, q - th, dq - dth)
    # eq:motorside, the declared motor side without the applied torque
    b = kin.d2theta_m @ model.J.T + dth @ model.D_m.T + _effect_sum(model.motor_effects, n, th, dth,
                                                                     kin.ddtheta_m) - tau_s
    u = applied_torque(model, kin, zoh)
    du = np.gradient(u, kin.t, axis=0)
    lp = savgol_coeffs(FAST_LOWPASS, 2)

    def fast(x):
        return correlate1d(x - kin.smooth(x), lp, axis=0, mode="nearest")
    bf, uf, duf = fast(b), fast(u), fast(du)
    N = kin.N
    edge = min(kin.window, N // 4)
    half = max(kin.window // 4, 1)
    out = FastGain(np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, dtype=int))
    for j in range(n):
        still = np.abs(dth[:, j]) <= v_moving
        # a sample near a stick phase sees it through the filters
        near = np.convolve(still.astype(float), np.ones(2 * half + 1), mode="same") > 0
        use = ~near
        use[:edge] = use[N - edge:] = False
        out.samples[j] = int(use.sum())
        if use.sum() < 50:
            continue
        beta, cov = inflated_lstsq(np.column_stack([uf[use, j], duf[use, j]]), bf[use, j])
        if cov is None:
            continue
        k0 = float(model.kappa[j])
        # b = κ_rel u: the drive's κ = κ_rel κ₀
        out.kappa[j] = float(beta[0]) * k0
        out.half_width[j] = Z95 * math.sqrt(max(cov[0, 0], 0.0)) * k0
    return out


def inflated_lstsq(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Least squares of y on the columns of A and the coefficients' covariance s² (AᵀA)⁻¹
    inflated by the residual's autocorrelation time (None when AᵀA is singular)."""
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    e = y - A @ beta
    tau = integrated_autocorr_time(e[:, None])
    try:
        return beta, np.linalg.inv(A.T @ A) * float(np.mean(e ** 2)) * tau
    except np.linalg.LinAlgError:
        return beta, None


def residuals_for(cfg: ModelConfig, kin: Kinematics, effects=(), **kw) -> np.ndarray:
    """Residual channels of ``cfg`` with ``effects`` appended to its declared ones
    (sticking below 3 × the configured sign_eps unless ``v_stick`` is given)."""
    c = cfg.with_effects(list(cfg.model.effects) + list(effects)) if effects else cfg
    kw.setdefault("v_stick", stick_velocity(cfg))
    return residual_channels(SEAModel.from_config(c), kin, **kw)


def stick_velocity(cfg: ModelConfig) -> float:
    """Speed [rad/s] below which a joint counts as sticking: 3 × the sign smoothing ε
    (tanh(3) = 0.995: above it the smoothed sign is the sign)."""
    return 3.0 * float(cfg.estimator.sign_eps)


def rms(r: np.ndarray) -> float:
    """RMS over all samples and channels [N m]."""
    return float(np.sqrt(np.mean(np.square(r))))
