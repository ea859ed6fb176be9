"""Candidate effects for tracing the residuals.

Every type of the effect vocabulary (docs/interfaces.md §2, plus the ``spring_saturation`` extension) on every side
it may sit on, for every joint. A candidate explains a part of the stacked residual r = [r_load, r_motor] (N × 2n,
flattened) of the form

    Δr(θ, β) = o(θ) + X(θ) β,

θ its nonlinear parameter (one at most: Stribeck's v_s, cogging's periods, the backlash width, the saturation's
theta_max, the delay), β its linear coefficients. Δr is *what the effect removes from the residual*: Δr = r(model) −
r(model + effect). It is computed from the model itself (:func:`.residuals.residual_channels` with the effect
added), so the signs and the coupling through the spring are those of eq:unknwn_load / eq:motorside:

* a load-side torque e appears as +e in r_load, a motor-side one as +e in r_motor,
* a spring-torque change Δτ_s as +Δτ_s in r_load and −Δτ_s in r_motor,
* torque_scale κ as (1 − κ)·κ₀τ_m in r_motor, a delay as κ₀(τ_m(t) − τ_m(t − d)),
* an encoder offset through every term that uses that angle (C(q), τ_s, declared effects).

Linear coefficients map to the effect's parameters by :meth:`Candidate.natural`; the structural effects (backlash,
delay) have no free coefficient (their Δr is o(θ)); the encoder offset is linearised at δ = 0 for the search (X =
∂Δr/∂δ) and refined exactly afterwards (:mod:`.select`).
"""
from __future__ import annotations

import math

import numpy as np

from sea_daemon.core.effects import EFFECT_TYPES, PARAM_RANGES, Effect, make_effect
from sea_daemon.analysis.diagnose.context import Context
from sea_daemon.analysis.diagnose.excitation import hump_unseen

__all__ = ["Context", "Candidate", "build_candidates"]


class Candidate:
    """One effect type on one side of one joint (see module docstring)."""

    type: str = ""
    side: str = ""
    linear: tuple[str, ...] = ()        # names of the coefficients β
    nonlinear: str | None = None        # name of θ, if any
    #: natural parameters that the final refinement fits, with bounds (see bounds())
    params: tuple[str, ...] = ()
    #: linear coefficients that the vocabulary requires to be >= 0 (docs/interfaces.md §2 validation)
    nonneg: tuple[int, ...] = ()

    def __init__(self, side: str, joint: int = 0, joints: int = 1):
        self.side = side
        self.joint = joint
        #: number of joints of the model (the name carries the joint when there are several)
        self.joints = joints

    @property
    def name(self) -> str:
        j = f"[{self.joint + 1}]" if self.joints > 1 else ""
        return f"{self.type}/{self.side}{j}"

    # --- search
    def grid(self, ctx: Context) -> list[float | None]:
        return [None]

    def design(self, ctx: Context, theta) -> tuple[np.ndarray | None, np.ndarray]:
        """(o(θ) or None, X(θ) of shape (N·2n, len(linear)))."""
        raise NotImplementedError

    def natural(self, beta: np.ndarray, theta) -> dict[str, float]:
        """Effect parameters from (β, θ)."""
        raise NotImplementedError

    def bounds(self, ctx: Context) -> dict[str, tuple[float, float]]:
        return {p: (-np.inf, np.inf) for p in self.params}

    def effect(self, params: dict[str, float]) -> Effect:
        return make_effect(self.type, self.side, self.joint, **params)

    # --- physical sense (the joint refinement's arbiter between correlated effects)
    #: the parameter whose size says how much of the effect there is (None: not one number)
    size_param: str | None = None
    #: physical prior of the pair rule (:meth:`.select.Selector._conflict`): of two effects the
    #: log cannot tell apart, both plausible, the one with the higher prior is kept (then the
    #: earlier chosen).  An effect every plant of its kind has ranks 1 (the weight of an arm
    #: on the load); 0 for those a plant may or may not have
    prior: int = 0

    def magnitude(self, params: dict) -> float | None:
        """How much of the effect there is (0: none), for telling a refinement that takes an
        effect away."""
        return abs(float(params[self.size_param])) if self.size_param in params else None

    def implausible(self, ctx: Context, params: dict) -> str | None:
        """Why these parameters are not physical for this hardware, or None."""
        return None

    def unidentified(self, ctx: Context, params: dict) -> str | None:  # why the log's motion cannot identify them
        return None

    def describe(self, params: dict) -> str:
        return ", ".join(f"{k} = {v:.4g}" for k, v in params.items())

    # --- helpers
    def _unit(self, ctx: Context, **params) -> np.ndarray:
        return ctx.delta_r([self.effect(params)])

    def side_signals(self, ctx: Context):
        """(angle, vel, acc) of this side and joint (offsets removed)."""
        q, th = ctx.angles()
        k = ctx.kin
        j = self.joint
        if self.side == "load":
            return q[:, j], k.dq[:, j], k.ddq[:, j]
        if self.side == "motor":
            return th[:, j], k.dtheta_m[:, j], k.ddtheta_m[:, j]
        return q[:, j] - th[:, j], k.dq[:, j] - k.dtheta_m[:, j], k.ddq[:, j] - k.ddtheta_m[:, j]

    def _on_side(self, ctx: Context, col: np.ndarray) -> np.ndarray:
        """Place a torque e (N,) on this side: +e load / +e motor / (+e, −e) spring; flattened."""
        n = ctx.n
        out = np.zeros((ctx.kin.N, 2 * n))
        if self.side in ("load", "spring"):
            out[:, self.joint] = col
        if self.side == "motor":
            out[:, n + self.joint] = col
        if self.side == "spring":
            out[:, n + self.joint] = -col
        return out.reshape(-1)

    def regressor(self, ctx: Context, theta=None) -> tuple[np.ndarray, str]:
        """The signal to plot the residual against, and its label."""
        a, v, _ = self.side_signals(ctx)
        return v, {"load": "q̇", "motor": "θ̇_m", "spring": "θ̇_s"}[self.side] + " [rad/s]"


# ------------------------------------------------------------------------- additive, linear

class CoulombC(Candidate):
    type, linear, params = "coulomb", ("F_c",), ("F_c",)
    nonneg = (0,)

    size_param = "F_c"

    def design(self, ctx, theta):
        return None, self._unit(ctx, F_c=1.0)[:, None]

    def natural(self, beta, theta):
        return {"F_c": float(beta[0])}

    def bounds(self, ctx):
        return {"F_c": (0.0, ctx.largest_torque(self.side, self.joint))}

    def implausible(self, ctx, params):
        return _static_friction_implausible(ctx, self, params["F_c"])


class ViscousC(Candidate):
    type, linear, params = "viscous", ("b",), ("b",)

    size_param = "b"

    def implausible(self, ctx, params):
        # the side's total damping (declared + this) cannot be negative
        d = _declared_damping(ctx, self.side, self.joint)
        if params["b"] < -d - 1e-12:
            return (f"b = {params['b']:.4g} N m s/rad makes the {self.side} side's damping negative "
                    f"(declared {d:.4g})")
        return None

    def design(self, ctx, theta):
        return None, self._unit(ctx, b=1.0)[:, None]

    def natural(self, beta, theta):
        return {"b": float(beta[0])}


class InertiaC(Candidate):
    type, linear, params = "inertia", ("dI",), ("dI",)

    size_param = "dI"

    def implausible(self, ctx, params):
        m = ctx.model
        I0 = float((m.params.M if self.side == "load" else m.params.J)[self.joint, self.joint])
        if params["dI"] < -0.9 * I0:
            return f"dI = {params['dI']:.4g} kg m² leaves the {self.side} side under a tenth of its inertia ({I0:.4g})"
        return None

    def design(self, ctx, theta):
        return None, self._unit(ctx, dI=1.0)[:, None]

    def natural(self, beta, theta):
        return {"dI": float(beta[0])}

    def regressor(self, ctx, theta=None):
        _, _, acc = self.side_signals(ctx)
        return acc, ("q̈" if self.side == "load" else "θ̈_m") + " [rad/s²]"


class GravityC(Candidate):
    """a sin(q + φ) = a cos φ · sin q + a sin φ · cos q."""

    type, linear, params = "gravity", ("a_cos_phi", "a_sin_phi"), ("a", "phi")

    size_param = "a"
    # a limb on the load always has weight; a relaxed elbow's stiffness may be absent.  Over a
    # narrow range of q the two trade (a sin(q + φ) and k_h (q − q_h0) are both nearly lines);
    # beyond it the weight's sine stays bounded while a line fitted in its place runs away
    prior = 1

    def design(self, ctx, theta):
        s = self._unit(ctx, a=1.0, phi=0.0)
        c = self._unit(ctx, a=1.0, phi=math.pi / 2)
        return None, np.column_stack([s, c])

    def natural(self, beta, theta):
        a = float(math.hypot(beta[0], beta[1]))
        return {"a": a, "phi": float(math.atan2(beta[1], beta[0]))}

    def bounds(self, ctx):
        return {"a": (0.0, np.inf), "phi": (-2 * math.pi, 2 * math.pi)}

    def regressor(self, ctx, theta=None):
        a, _, _ = self.side_signals(ctx)
        return a, "q [rad]"


class HumanViscoelasticC(Candidate):
    """k_h (q − q_h0) + b_h q̇ = k_h q + c + b_h q̇ with c = −k_h q_h0."""

    type, linear, params = "human_viscoelastic", ("k_h", "c", "b_h"), ("k_h", "q_h0", "b_h")

    def design(self, ctx, theta):
        kq = self._unit(ctx, k_h=1.0, q_h0=0.0, b_h=0.0)
        one = self._unit(ctx, k_h=1.0, q_h0=-1.0, b_h=0.0) - kq
        bv = self._unit(ctx, k_h=0.0, q_h0=0.0, b_h=1.0)
        return None, np.column_stack([kq, one, bv])

    def natural(self, beta, theta):
        k = float(beta[0])
        q0 = -float(beta[1]) / k if abs(k) > 1e-9 else 0.0
        return {"k_h": k, "q_h0": q0, "b_h": float(beta[2])}

    def regressor(self, ctx, theta=None):
        a, _, _ = self.side_signals(ctx)
        return a, "q [rad]"


class SpringCubicC(Candidate):
    type, linear, params = "spring_cubic", ("k3",), ("k3",)

    size_param = "k3"

    def implausible(self, ctx, params):
        # the spring must stay a spring: K_s + 3 k3 θ_s² > 0 over the deflections of the log
        a, _, _ = self.side_signals(ctx)
        K = float(ctx.model.K_s[self.joint, self.joint])
        th = float(np.max(np.abs(a)))
        if K + 3.0 * params["k3"] * th**2 <= 0.1 * K:
            return f"k3 = {params['k3']:.4g} N m/rad³ softens the spring to under a tenth of K_s at |θ_s| = {th:.3g} rad"
        return None

    def design(self, ctx, theta):
        return None, self._unit(ctx, k3=1.0)[:, None]

    def natural(self, beta, theta):
        return {"k3": float(beta[0])}

    def regressor(self, ctx, theta=None):
        a, _, _ = self.side_signals(ctx)
        return a, "θ_s [rad]"


class TorqueOffsetC(Candidate):
    """Δr = −tau_0 on r_motor (the drive delivers tau_0 more): X = Δr(tau_0 = 1)."""

    type, linear, params = "torque_offset", ("tau_0",), ("tau_0",)
    size_param = "tau_0"

    def design(self, ctx, theta):
        return None, self._unit(ctx, tau_0=1.0)[:, None]

    def natural(self, beta, theta):
        return {"tau_0": float(beta[0])}

    def regressor(self, ctx, theta=None):
        return ctx.kin.t, "t [s]"


class TorqueScaleC(Candidate):
    """Δr(κ) = (1 − κ)·κ₀τ_m on r_motor: X = Δr(κ = 2) = −κ₀τ_m, β = κ − 1."""

    type, linear, params = "torque_scale", ("kappa_minus_1",), ("kappa",)

    #: delivered / commanded torque a working drive can have (gear efficiency, amplifier gain)
    PLAUSIBLE = (0.2, 2.0)
    #: relative tolerance of the fast-part gain (the amplifier's bandwidth, the filters' phase)
    FAST_TOL = 0.25
    #: the fast part decides only when its 95 % half-width is below this share of its value
    FAST_INFORMATIVE = 0.2

    def magnitude(self, params):
        return abs(float(params["kappa"]) - 1.0)

    def fast_range(self, ctx) -> tuple[float, float] | None:
        """The gains the fast part of the command allows, or None when it does not decide
        (:func:`.residuals.fast_command_gain`)."""
        g = ctx.fast_gain
        k, hw = float(g.kappa[self.joint]), float(g.half_width[self.joint])
        if not (np.isfinite(k) and np.isfinite(hw) and k > 0 and hw < self.FAST_INFORMATIVE * k):
            return None
        tol = max(hw, self.FAST_TOL * k)
        return k - tol, k + tol

    def implausible(self, ctx, params):
        lo, hi = self.PLAUSIBLE
        k = params["kappa"]
        if not lo <= k <= hi:
            return (f"κ = {k:.3g}: the drive would deliver {'under a fifth' if k < lo else 'over twice'} "
                    "the torque commanded")
        fr = self.fast_range(ctx)
        if fr is not None and not fr[0] <= k <= fr[1]:
            g = ctx.fast_gain
            return (f"κ = {k:.3g} from the slow part of the command, but its fast part reaches the motor with "
                    f"κ = {g.kappa[self.joint]:.3g} ± {g.half_width[self.joint]:.2g}: a gain scales every "
                    "frequency alike, so the slow shortfall is something the controller works against "
                    "(friction, an offset), not a gain")
        return None

    def design(self, ctx, theta):
        return None, self._unit(ctx, kappa=2.0)[:, None]

    def natural(self, beta, theta):
        return {"kappa": 1.0 + float(beta[0])}

    def bounds(self, ctx):
        # the refinement stays within what a working drive can deliver
        return {"kappa": self.PLAUSIBLE}

    def regressor(self, ctx, theta=None):
        return ctx.kin.tau_m[:, self.joint], "τ_m [N m]"


class EncoderOffsetC(Candidate):
    """The encoder reads angle + δ: enters every term that uses that angle (C(q), τ_s, the
    declared effects), so Δr(δ) is computed exactly from the model and δ found by
    Gauss–Newton from δ = 0 (:meth:`.select.Selector.fit_candidate`): linearised
    ∂Δr/∂δ as the regressor, re-linearised at each iterate."""

    type, linear, nonlinear, params = "encoder_offset", (), "delta", ("delta",)
    gauss_newton = True
    H = 1e-4

    size_param = "delta"

    def design(self, ctx, theta):
        return self._unit(ctx, delta=float(theta)), np.zeros((ctx.r0.size, 0))

    def natural(self, beta, theta):
        return {"delta": float(theta)}

    def bounds(self, ctx):
        return {"delta": (-0.5, 0.5)}

    def regressor(self, ctx, theta=None):
        q, th = ctx.angles()
        return q[:, self.joint] - th[:, self.joint], "θ_s [rad]"


# ------------------------------------------------------------------------- nonlinear in θ

class StribeckC(Candidate):
    type, linear, nonlinear, params = "stribeck", ("F_s",), "v_s", ("F_s", "v_s")
    nonneg = (0,)

    size_param = "F_s"

    def grid(self, ctx):
        _, v, _ = self.side_signals(ctx)
        vmax = max(float(np.percentile(np.abs(v), 99)), 1e-3)
        return list(np.geomspace(0.005, 2.0 * vmax, 28))

    def design(self, ctx, theta):
        return None, self._unit(ctx, F_s=1.0, v_s=float(theta))[:, None]

    def natural(self, beta, theta):
        return {"F_s": float(beta[0]), "v_s": float(theta)}

    def bounds(self, ctx):
        return {"F_s": (0.0, ctx.largest_torque(self.side, self.joint)),
                "v_s": (ctx.stick_speed(self.side) / 3.0, np.inf)}

    def implausible(self, ctx, params):
        v0 = ctx.stick_speed(self.side) / 3.0
        if params["v_s"] < v0:
            return (f"v_s = {params['v_s']:.3g} rad/s: a hump below a third of the {self.side} side's stick speed "
                    f"({3 * v0:.3g} rad/s) acts only where the encoders cannot tell motion from standing still")
        return self.unidentified(ctx, params) or _static_friction_implausible(ctx, self, params["F_s"])

    def unidentified(self, ctx, params) -> str | None:
        _, v, _ = self.side_signals(ctx)
        return hump_unseen(v, ctx.stick_speed(self.side), params["v_s"], len(self.params), self.side)


class CoggingC(Candidate):
    """A sin(P θ_m + φ) = A cos φ · sin Pθ_m + A sin φ · cos Pθ_m, P on a grid."""

    type, linear, nonlinear, params = "cogging", ("A_cos_phi", "A_sin_phi"), "periods", ("A", "periods", "phi")
    #: fewest ripple periods over the log's travel
    MIN_PERIODS = 2.0

    def implausible(self, ctx, params):
        a, _, _ = self.side_signals(ctx)
        n_per = params["periods"] * float(np.ptp(a)) / (2 * math.pi)
        if n_per < self.MIN_PERIODS:
            return (f"{params['periods']:.3g} periods per radian repeat only {n_per:.2g} times over the log's travel "
                    "(a ripple must repeat to be told from any other smooth function of the angle)")
        return None

    size_param = "A"

    def grid(self, ctx):
        a, v, _ = self.side_signals(ctx)
        # resolvable at the sample rate: P |θ̇_m| dt < π/2 for most samples
        vmax = max(float(np.percentile(np.abs(v), 90)), 1e-6)
        pmax = min(0.5 * math.pi / (vmax * ctx.kin.dt), 2000.0)
        span = max(float(np.ptp(a)), 1e-6)
        # one period change across the travelled range is the resolution in P
        step = 0.25 * 2 * math.pi / span
        # a ripple repeats: at least MIN_PERIODS of it over the travelled range (fewer is a
        # smooth function of the angle that the log cannot tell from any other)
        pmin = max(self.MIN_PERIODS * 2 * math.pi / span, 0.5)
        return list(np.arange(pmin, pmax, step))

    def design(self, ctx, theta):
        s = self._unit(ctx, A=1.0, periods=float(theta), phi=0.0)
        c = self._unit(ctx, A=1.0, periods=float(theta), phi=math.pi / 2)
        return None, np.column_stack([s, c])

    def fast_design(self, ctx, theta):
        """The same columns, unsmoothed, from the effect's torque alone (cogging is additive)."""
        a, v, c = self.side_signals(ctx)
        return tuple(self._on_side(ctx, self.effect({"A": 1.0, "periods": float(theta), "phi": phi}).torque_array(a, v, c))
                     for phi in (0.0, math.pi / 2))

    def natural(self, beta, theta):
        return {"A": float(math.hypot(beta[0], beta[1])), "periods": float(theta),
                "phi": float(math.atan2(beta[1], beta[0]))}

    def bounds(self, ctx):
        return {"A": (0.0, np.inf), "periods": (1e-3, np.inf), "phi": (-2 * math.pi, 2 * math.pi)}

    def regressor(self, ctx, theta=None):
        a, _, _ = self.side_signals(ctx)
        if theta:
            return np.mod(theta * a, 2 * math.pi), "P·θ_m mod 2π [rad]"
        return a, "θ_m [rad]"


class SpringSaturationC(Candidate):
    type, linear, nonlinear, params = "spring_saturation", ("k_stop",), "theta_max", ("theta_max", "k_stop")
    nonneg = (0,)

    size_param = "k_stop"

    def grid(self, ctx):
        a, _, _ = self.side_signals(ctx)
        qs = np.percentile(np.abs(a), [40, 97])
        return list(np.linspace(max(qs[0], 1e-4), max(qs[1], 2e-4), 20))

    def design(self, ctx, theta):
        return None, self._unit(ctx, theta_max=float(theta), k_stop=1.0)[:, None]

    def natural(self, beta, theta):
        return {"theta_max": float(theta), "k_stop": float(beta[0])}

    def bounds(self, ctx):
        a, _, _ = self.side_signals(ctx)
        return {"theta_max": (1e-5, float(np.max(np.abs(a)))), "k_stop": (1e-6, np.inf)}

    def regressor(self, ctx, theta=None):
        a, _, _ = self.side_signals(ctx)
        return a, "θ_s [rad]"


class BacklashC(Candidate):
    """Structural: Δr(w) from the model with a dead band of width w; no free coefficient."""

    type, linear, nonlinear, params = "spring_backlash", (), "width", ("width",)

    #: share of the samples that must lie on each side of the dead band
    MIN_SIDE = 0.02

    size_param = "width"

    def implausible(self, ctx, params):
        # a dead band that holds most deflections of the log leaves the spring carrying no
        # torque most of the time: that is not play, it is the model switching the spring off
        a, _, _ = self.side_signals(ctx)
        inside = float(np.mean(np.abs(a) < 0.5 * params["width"]))
        if inside > 0.5:
            return (f"a dead band of {params['width']:.4g} rad holds {100 * inside:.0f} % of the log's spring "
                    "deflections (the spring would carry no torque most of the time)")
        return None

    def grid(self, ctx):
        """Widths whose dead band the deflection passes: samples on both sides of ±w/2, the
        band holding at most half of them.

        With a deflection of one sign only, a dead band is an exactly constant spring-torque
        offset, indistinguishable from an encoder offset: no evidence of backlash, no width.
        """
        a, _, _ = self.side_signals(ctx)
        # up to a dead band that holds half the deflections (wider is not play: see implausible)
        wmax = 2.0 * float(np.median(np.abs(a)))
        ws = np.linspace(wmax / 30, wmax, 30)
        return [float(w) for w in ws
                if np.mean(a > w / 2) >= self.MIN_SIDE and np.mean(a < -w / 2) >= self.MIN_SIDE]

    def design(self, ctx, theta):
        return self._unit(ctx, width=float(theta)), np.zeros((ctx.r0.size, 0))

    def natural(self, beta, theta):
        return {"width": float(theta)}

    def bounds(self, ctx):
        # up to a dead band that holds half the log's deflections (see implausible)
        a, _, _ = self.side_signals(ctx)
        return {"width": (0.0, 2.0 * float(np.median(np.abs(a))))}

    def regressor(self, ctx, theta=None):
        a, _, _ = self.side_signals(ctx)
        return a, "θ_s [rad]"


#: the longest delay a configuration may declare (the effect's range, core.effects.PARAM_RANGES)
_MAX_DELAY_S = PARAM_RANGES[("delay", "seconds")][1]


class DelayC(Candidate):
    """Structural: Δr(d) = κ₀(τ_m(t) − τ_m(t − d)) on r_motor; no free coefficient."""

    type, linear, nonlinear, params = "delay", (), "seconds", ("seconds",)

    size_param = "seconds"

    def grid(self, ctx):
        dt = ctx.kin.dt
        return list(np.linspace(dt / 8, min(8 * dt, _MAX_DELAY_S), 40))

    def design(self, ctx, theta):
        return self._unit(ctx, seconds=float(theta)), np.zeros((ctx.r0.size, 0))

    def natural(self, beta, theta):
        return {"seconds": float(theta)}

    def bounds(self, ctx):
        return {"seconds": (0.0, min(20 * ctx.kin.dt, _MAX_DELAY_S))}

    def regressor(self, ctx, theta=None):
        k = ctx.kin
        return np.gradient(k.smooth(k.tau_m[:, self.joint]), k.t), "τ̇_m [N m/s]"


def _static_friction_implausible(ctx: Context, cand: Candidate, amplitude: float) -> str | None:
    """Why a friction amplitude is not physical: above the largest torque the log puts on that side
    (:meth:`Context.largest_torque`), it would have held the side still for good."""
    top = ctx.largest_torque(cand.side, cand.joint)
    if amplitude > top:
        return (f"{cand.size_param} = {amplitude:.4g} N m exceeds every torque on the {cand.side} side in this log "
                f"(at most {top:.3g} N m): it would never have let that side move")
    return None


def _declared_damping(ctx: Context, side: str, j: int) -> float:
    """Viscous damping [N m s/rad] the configuration already gives a side: D_m on the motor,
    declared viscous effects and a human's b_h."""
    m = ctx.model
    d = float(m.D_m[j, j]) if side == "motor" else 0.0
    for e in m.effects:
        if e.joint == j and e.side == side:
            d += float(getattr(e, "b", 0.0)) + float(getattr(e, "b_h", 0.0))
    return d


_CLASSES = {"coulomb": CoulombC, "viscous": ViscousC, "stribeck": StribeckC, "inertia": InertiaC, "gravity": GravityC,
            "human_viscoelastic": HumanViscoelasticC, "spring_cubic": SpringCubicC, "spring_backlash": BacklashC,
            "torque_scale": TorqueScaleC, "encoder_offset": EncoderOffsetC, "delay": DelayC, "cogging": CoggingC,
            "spring_saturation": SpringSaturationC, "torque_offset": TorqueOffsetC}


def build_candidates(ctx: Context, types=None) -> list[Candidate]:
    """Every vocabulary type × every side it may sit on × every joint (``types`` to restrict)."""
    out = []
    for typ, eff_cls in EFFECT_TYPES.items():
        if types is not None and typ not in types:
            continue
        cls = _CLASSES[typ]
        for side in eff_cls.sides:
            for j in range(ctx.n):
                out.append(cls(side, j, ctx.n))
    return out
