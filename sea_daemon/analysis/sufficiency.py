"""Can this log identify that?  The sufficiency of a calibration log, per identified quantity.

    from sea_daemon.analysis.sufficiency import assess, at_config_rate
    log, note = at_config_rate(log, cfg)       # converted to the configuration's rate, or refused
    s = assess(log, cfg)                       # the figures and one verdict per quantity
    if s.refusal: raise InputError(s.refusal)  # one line: what is missing, what to record instead

What the calibration identifies (docs/calibration.md) and what each needs from the log:

* ``R`` and ``tau_m_noise`` — the encoders' and the motor torque's noise: seconds of data, any
  motion (a still arm shows the noise alone);
* ``effects`` — the physical effects ``diagnose`` adds (the arm's weight, the elbow, friction,
  inertia, ...): motion over a range of angles, in both directions, repeated (friction's sign
  is seen only where the joint turns; moving one way only, friction and the static load are one
  number), with speeds and accelerations well above the differentiator's noise;
* ``residual_gp`` — what the physics leaves, where the log has data (the coverage map flags the
  rest);
* ``sign_eps`` — the friction's sign smoothing: turning points of the joint, both ways;
* ``q_tau`` — the τ_h,act random walk: from the declared subject (``calibration`` section), not
  from the log.

Each verdict is ``identify``, ``nominal`` (the log cannot identify it: the configured value is
kept and the calibration says so) or ``refuse`` (the log is not a calibration of this robot as
configured: exit 2 with the line of :attr:`Sufficiency.refusal`).  Signal-to-noise per
parameter class is the regressor's spread over its noise through the same zero-phase smoother
(angle: gravity, elbow; speed each way: friction, damping; acceleration: inertia; motor speed:
the drive's friction; deflection: the spring).

Pure: numpy and scipy, no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.excitation import WorkingRange
from sea_daemon.core.log import MeasuredLog, column_names
from sea_daemon.errors import InputError

#: the quantities a calibration identifies, in its order
QUANTITIES = ("R", "effects", "tau_m_noise", "residual_gp", "sign_eps", "q_tau")
#: what to record instead, in every refusal and every fall-back
RECORD = "record a calibration over the working range: sea-daemon calibrate --excitation --fit"


@dataclass(frozen=True)
class Limits:
    """What a calibration log must hold, in seconds and degrees (the same at every rate)."""

    min_noise_s: float = 2.0          # R and σ_u: seconds of data
    min_physics_s: float = 10.0       # the physical effects: seconds of data
    min_strokes: int = 2              # moves each way (a move: ≥ min_stroke_deg between turning points)
    min_stroke_deg: float = 5.0
    still_span_deg: float = 1.0       # the load angle spans less: a still-arm log
    min_snr: float = 10.0             # signal over noise of each regressor the physics needs
    saturated_flag: float = 0.02      # share of samples at the torque limit that is reported ...
    saturated_refuse: float = 0.05    # ... and that is refused (bench generalize --degenerate)
    rate_tolerance: float = 0.01      # sample period within this share of the configuration's
    smooth_s: float = 0.1             # the zero-phase smoother of the regressors
    min_range_share: float = 0.8      # of the declared working range's angles and speed, else a note
    spring_slope_factor: float = 4.0  # τ_m against K_s (θ_m − q): a slope beyond ×/÷ this is refused


@dataclass(frozen=True)
class Verdict:
    """One quantity: ``status`` identify | nominal | declared | refuse, and why, in plain words."""

    quantity: str
    status: str
    why: str

    def to_dict(self) -> dict:
        return {"status": self.status, "why": self.why}


@dataclass
class Sufficiency:
    """The figures of a log (all finite, or None where not measurable) and the verdicts."""

    figures: dict
    verdicts: dict = field(default_factory=dict)
    refusal: str | None = None
    notes: list = field(default_factory=list)

    @property
    def still(self) -> bool:
        return bool(self.figures.get("still"))

    def identifies(self, quantity: str) -> bool:
        return self.verdicts[quantity].status == "identify"

    def to_dict(self) -> dict:
        return {"figures": self.figures, "verdicts": {k: v.to_dict() for k, v in self.verdicts.items()},
                "refusal": self.refusal, "notes": list(self.notes)}

    def lines(self) -> list[str]:
        """Plain sentences for the calibration's printed report (:meth:`lines_of`)."""
        return self.lines_of(self.to_dict())

    @staticmethod
    def lines_of(d: dict) -> list[str]:
        """The sentences of a :meth:`to_dict` form: the log, each quantity the log cannot
        identify, the notes."""
        f = d["figures"]
        motion = ("the arm held still" if f.get("still") else
                  f"moves {f.get('strokes_up', 0)} up and {f.get('strokes_down', 0)} down over "
                  f"{f.get('q_span_deg', 0.0):.0f} deg")
        rate = f"{f['rate_hz']:.0f} Hz" if f.get("rate_hz") is not None else "an unknown rate"
        out = [f"This log: {f['duration_s']:.1f} s at {rate}, {motion}."]
        for name, v in d["verdicts"].items():
            if v["status"] == "nominal":
                out.append(f"Not identified from this log, the configured value kept: {name} ({v['why']}).")
        return out + list(d.get("notes", []))


def finite(x) -> float | None:
    """``x`` as a float, None when it is not finite (the report's "not measurable")."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# ---------------------------------------------------------------------------- rate

def decimate_by(log: MeasuredLog, m: int) -> MeasuredLog:
    """Every ``m``-th sample: angles sampled, the motor torque averaged over the m commands it
    replaces (the torque held over the longer interval that moves the plant the same to first
    order, eq:motorside), the truth column sampled.  ``m`` ≤ 1: the log itself."""
    if m <= 1:
        return log
    N = (len(log) - 1) // m * m + 1
    idx = np.arange(0, N, m)
    tau = np.asarray(log.tau_m[:N - 1], float).reshape(-1, m, log.n).mean(axis=1)
    tau = np.vstack([tau, log.tau_m[N - 1:N]])
    return MeasuredLog(t=log.t[idx], q=log.q[idx], theta_m=log.theta_m[idx], tau_m=tau,
                       tau_h_act=None if log.tau_h_act is None else log.tau_h_act[idx], path=log.path)


def at_config_rate(log: MeasuredLog, cfg: ModelConfig, tolerance: float = Limits.rate_tolerance
                   ) -> tuple[MeasuredLog, str | None]:
    """The log at the configuration's rate: itself; decimated when it was recorded at a whole
    multiple of it (and a note saying so); InputError (one line) otherwise."""
    dt = log.dt
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"{log.path}: its sample times do not increase; a measured log has t rising by one "
                         "sample period per row")
    rate = 1.0 / dt
    m = int(round(cfg.dt / dt))
    if m >= 1 and abs(m * dt - cfg.dt) <= tolerance * cfg.dt:
        if m == 1:
            return log, None
        return decimate_by(log, m), (f"the log was recorded at {rate:.6g} Hz, the configuration runs at "
                                     f"{cfg.rate_hz:g} Hz (rate_hz): calibrated on every {m}th sample; to calibrate "
                                     f"at {rate:.6g} Hz give rate_hz: {rate:.6g} (or calibrate --rate {rate:.6g})")
    raise InputError(f"{log.path}: recorded at {rate:.6g} Hz, the configuration runs at {cfg.rate_hz:g} Hz "
                     f"(rate_hz); allowed: {cfg.rate_hz:g} Hz or a whole multiple of it; record the calibration at "
                     f"the configured rate (sea-daemon calibrate --excitation --fit) or set rate_hz to the log's")


# ---------------------------------------------------------------------------- figures

def turning_points(x: np.ndarray, h: float) -> list[int]:
    """Indices of the turning points of ``x`` with hysteresis ``h`` (a reversal counts once it
    has gone back by ``h``); the first sample and the last extreme included."""
    pts, d, ext = [0], 0, 0
    for i in range(1, len(x)):
        if d == 0:
            if abs(x[i] - x[0]) >= h:
                d, ext = (1 if x[i] > x[0] else -1), i
        elif d * (x[i] - x[ext]) > 0:
            ext = i
        elif d * (x[ext] - x[i]) >= h:
            pts.append(ext)
            d, ext = -d, i
    if d != 0:
        pts.append(ext)
    return pts


def _noise_std(x: np.ndarray, smooth: np.ndarray, quantum: float) -> float:
    """Robust std of the samples about their smoothed curve, at least the quantum's Δ/√12."""
    r = np.asarray(x, float) - np.asarray(smooth, float)
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return max(mad, quantum / math.sqrt(12.0))


def _snr(signal: float, noise: float) -> float | None:
    return finite(signal / noise) if noise > 0 else None


def _directional_rms(v: np.ndarray, floor: float) -> tuple[float, float]:
    """RMS of the speed over the samples moving up, and down (above ``floor``); 0 without any."""
    up, down = v[v > floor], v[v < -floor]
    return (float(np.sqrt(np.mean(up ** 2))) if up.size else 0.0,
            float(np.sqrt(np.mean(down ** 2))) if down.size else 0.0)


def _kinematics(t: np.ndarray, x: np.ndarray, dt: float, lim: Limits):
    """(smoothed, velocity, acceleration, gains of the velocity and the acceleration to white
    noise) of one angle by the zero-phase Savitzky–Golay smoother of ``lim.smooth_s``."""
    from scipy.signal import savgol_coeffs, savgol_filter   # local import: scipy.signal is slow to import
    w = max(7, int(round(lim.smooth_s / dt)) | 1)
    w = min(w, len(x) if len(x) % 2 else len(x) - 1)
    deg = min(3, w - 1)
    kw = dict(window_length=w, polyorder=deg, delta=dt, mode="interp")
    g1 = float(np.linalg.norm(savgol_coeffs(w, deg, deriv=1, delta=dt)))
    g2 = float(np.linalg.norm(savgol_coeffs(w, deg, deriv=2, delta=dt))) if deg >= 2 else math.inf
    return (savgol_filter(x, deriv=0, **kw), savgol_filter(x, deriv=1, **kw),
            savgol_filter(x, deriv=2, **kw) if deg >= 2 else np.zeros_like(x), g1, g2)


def measure(log: MeasuredLog, cfg: ModelConfig, lim: Limits = Limits(), joint: int = 0) -> dict:
    """The figures of one joint's log, joint ``joint`` (0-based) of an n-joint log (finite numbers or None)."""
    dt = log.dt
    q, th, u = (np.asarray(a, float)[:, joint] for a in (log.q, log.theta_m, log.tau_m))
    dq_quant, dm_quant = (float(a[joint]) for a in cfg.hardware.encoder_resolution(cfg.joints))
    # the time the log covers: its N samples of one period each (2000 rows at 200 Hz are 10 s)
    duration = float(log.t[-1] - log.t[0]) + dt if len(log) > 1 else 0.0
    f: dict = {"samples": int(len(log)), "duration_s": finite(duration) or 0.0, "rate_hz": finite(1.0 / dt),
               "config_rate_hz": float(cfg.rate_hz),
               "constant_angles": bool(np.ptp(q) == 0.0 and np.ptp(th) == 0.0), **column_figures(log, joint)}
    if len(log) < 8:
        f.update(still=True, q_span_deg=0.0, strokes_up=0, strokes_down=0, snr={})
        return f
    qs, dqs, ddqs, g1, g2 = _kinematics(log.t, q, dt, lim)
    ms, dms, _, _, _ = _kinematics(log.t, th, dt, lim)
    sq, sm = _noise_std(q, qs, dq_quant), _noise_std(th, ms, dm_quant)
    lo, hi = np.percentile(qs, [1.0, 99.0])
    span = math.degrees(float(hi - lo))
    h = max(math.radians(0.5), 10.0 * sq)
    pts = turning_points(qs, h)
    exc = np.diff(qs[pts])
    big = np.abs(exc) >= math.radians(lim.min_stroke_deg)
    v_floor = max(0.02, 5.0 * sq * g1)
    up, down = _directional_rms(dqs, v_floor)
    mup, mdown = _directional_rms(dms, max(0.02, 5.0 * sm * g1))
    defl = ms - qs
    f.update(q_range_deg=[math.degrees(float(lo)), math.degrees(float(hi))], q_span_deg=span,
             still=bool(span < lim.still_span_deg and not big.any()),
             strokes_up=int(np.sum(big & (exc > 0))), strokes_down=int(np.sum(big & (exc < 0))),
             moving_up_s=float(np.sum(dqs > v_floor) * dt), moving_down_s=float(np.sum(dqs < -v_floor) * dt),
             dq_max=float(np.max(np.abs(dqs))), ddq_max=float(np.max(np.abs(ddqs))),
             noise={"q": sq, "theta_m": sm, "dq": sq * g1, "ddq": sq * g2},
             snr={"angle": _snr(float(np.std(qs)), sq), "speed_up": _snr(up, sq * g1),
                  "speed_down": _snr(down, sq * g1), "acceleration": _snr(float(np.sqrt(np.mean(ddqs ** 2))), sq * g2),
                  "motor_speed_up": _snr(mup, sm * g1), "motor_speed_down": _snr(mdown, sm * g1),
                  "deflection": _snr(float(np.std(defl)), math.hypot(sq, sm))})
    f["torque_limit_share"] = float(np.mean(np.abs(u) >= 0.999 * cfg.hardware.torque_limits(cfg.joints)[joint]))
    f["spring_slope"] = _spring_slope(u, defl, float(np.diag(np.atleast_2d(cfg.model.K_s))[joint]))
    return f


def _spring_slope(u: np.ndarray, defl: np.ndarray, K_s: float) -> dict:
    """The motor torque against the spring's deflection θ_m − q (low frequencies: τ_m ≈ K_s (θ_m − q),
    eq:motorside): the least-squares slope over K_s (≈ 1 as configured, ≈ −1 with q and θ_m
    swapped or τ_m of the other sign) and the share of τ_m's mean square it explains."""
    from scipy.ndimage import uniform_filter1d   # local import: scipy.ndimage is slow to import
    us = uniform_filter1d(u, size=max(1, len(u) // 200) | 1)
    den = float(np.dot(defl, defl)) * K_s
    if den <= 0 or not np.any(us):
        return {"slope": None, "explained": None}
    a = float(np.dot(us, defl)) / den
    expl = 1.0 - float(np.sum((us - a * K_s * defl) ** 2)) / float(np.sum(us ** 2))
    return {"slope": finite(a), "explained": finite(expl)}


# ---------------------------------------------------------------------------- verdicts

def _refusal(f: dict, lim: Limits, path: str) -> str | None:
    """The one line of a log that is not a calibration of this robot as configured, or None."""
    if f["constant_angles"]:
        return (f"{path}: q and theta_m do not change over its {f['samples']} rows: the encoders report neither "
                f"motion nor noise; check the encoders, then {RECORD}")
    dead = dead_column(f, path, lim)
    if dead:
        return dead
    if f["duration_s"] < lim.min_noise_s:
        return (f"{path}: {f['duration_s']:.2f} s of data; the calibration needs at least {lim.min_noise_s:g} s "
                f"(the sensors' noise) and {lim.min_physics_s:g} s of motion (the physical effects); {RECORD}")
    sp = f.get("spring_slope") or {}
    if sp.get("slope") is not None and sp["slope"] < -0.3 and (sp.get("explained") or 0.0) >= 0.5:
        return (f"{path}: the motor torque pushes against the spring's deflection theta_m - q (slope "
                f"{sp['slope']:.2f} x K_s; expected about +1): q and theta_m swapped, or tau_m of the other sign; "
                "check the log's columns (docs/interfaces.md section 1)")
    lo, hi = 1.0 / lim.spring_slope_factor, lim.spring_slope_factor
    if sp.get("slope") is not None and (sp.get("explained") or 0.0) >= 0.5 and not lo <= sp["slope"] <= hi:
        return (f"{path}: the motor torque is {sp['slope']:.3g} x K_s times the spring's deflection theta_m - q "
                f"(allowed {lo:g}-{hi:g} x; expected about 1): model.K_s, hardware.gear_ratio (the motor angle on the "
                "joint side) or the units of the angle or torque columns are off by about that factor; check them "
                "(docs/interfaces.md section 1)")
    share = f.get("torque_limit_share", 0.0)
    if share >= lim.saturated_refuse:
        return (f"{path}: the motor torque is at the hardware limit (hardware.torque_limit) in {100 * share:.0f} % "
                f"of the log (allowed below {100 * lim.saturated_refuse:.0f} %): the joint did not follow the "
                "calibration's moves; lower calibration.v_max / a_max or check for a mechanical stop, then "
                + RECORD.split(": ", 1)[1])
    return None


def column_figures(log: MeasuredLog, joint: int = 0) -> dict:
    """Joint ``joint``'s sensor columns: their names in the log, the span of each angle [deg], and
    the value of each column that holds one value in every row (``constant``)."""
    cols = {base: np.asarray(a, float)[:, joint] for base, a in (("q", log.q), ("theta_m", log.theta_m),
                                                                   ("tau_m", log.tau_m))}
    return {"columns": {base: column_names(base, log.n)[joint] for base in cols},
            "angle_span_deg": {b: math.degrees(float(np.ptp(cols[b]))) if len(log) else 0.0 for b in ("q", "theta_m")},
            "constant": {b: float(a[0]) for b, a in cols.items() if len(a) and np.ptp(a) == 0.0}}


def dead_column(f: dict, path: str, lim: Limits = Limits(), torque: bool = True) -> str | None:
    """The one line of a log one of whose sensor columns holds one value in every row while the
    joint moves (the other angle spans at least ``lim.still_span_deg``): a sensor or a column
    that reports nothing, on which nothing can be identified; or None.  ``f``: the figures of
    :func:`column_figures` (and ``samples``); ``torque=False``: the two angles only (a drive
    commanding no torque while the wearer moves the joint logs a constant ``tau_m``)."""
    const, span, col = f.get("constant", {}), f.get("angle_span_deg", {}), f.get("columns", {})
    rows = f"in all {f.get('samples', 0)} rows"
    for name, other, what in (("q", "theta_m", "the load encoder"), ("theta_m", "q", "the motor encoder")):
        if name in const and span.get(other, 0.0) >= lim.still_span_deg:
            return (f"{path}: column {col[name]} is {const[name]:.6g} rad {rows} while {col[other]} spans "
                    f"{span[other]:.1f} deg: {what} reports nothing (the spring between them cannot deflect that "
                    f"far); check it and the log's columns (docs/interfaces.md section 1), then {RECORD}")
    moved = max(span.values(), default=0.0)
    if torque and "tau_m" in const and moved >= lim.still_span_deg:
        return (f"{path}: column {col['tau_m']} is {const['tau_m']:.6g} N m {rows} while the joint moves over "
                f"{moved:.1f} deg: the drive's torque is not in the log; check the drive's torque reading and the "
                f"log's columns (docs/interfaces.md section 1), then {RECORD}")
    return None


def check_columns(log: MeasuredLog, lim: Limits = Limits(), torque: bool = True) -> None:
    """InputError with :func:`dead_column`'s line when a sensor column of any joint of ``log``
    reports nothing while that joint moves (``torque=False``: an angle column)."""
    for j in range(log.n):
        line = dead_column({"samples": len(log), **column_figures(log, j)}, log.path, lim, torque)
        if line:
            raise InputError(line)


def _still_over_range(f: dict, cfg: ModelConfig, path: str) -> str | None:
    """The one line refusing a still-arm log when the configuration declares a working range
    (``calibration.q_min_deg`` and ``q_max_deg``: the model must hold over it), or None.  A
    still arm shows the sensors' noise and the static torque at the held angle alone; the arm's
    weight, the elbow, friction and inertia over the range show only in motion.  Without a
    declared range a still log is the still-arm protocol (Sec. V-C: the estimate at the held
    angle) and is calibrated at that angle."""
    c = cfg.calibration
    if not f.get("still") or c.q_min_deg is None or c.q_max_deg is None:
        return None
    lo, hi = f.get("q_range_deg", [float("nan")] * 2)
    at = f"at {0.5 * (lo + hi):.0f} deg " if math.isfinite(lo) and math.isfinite(hi) else ""
    return (f"{path}: the arm held still {at}(the load angle spans {f.get('q_span_deg', 0.0):.2f} deg) and the "
            f"configuration declares the working range {c.q_min_deg:.4g}-{c.q_max_deg:.4g} deg "
            "(calibration.q_min_deg, q_max_deg): a still arm shows the sensors' noise alone, not the arm's weight, "
            f"the elbow, friction or inertia over that range; {RECORD}")


def record_motion(lim: Limits = Limits()) -> str:
    """What to record instead of a log that moves too little: the motion the physical effects
    need, in seconds and degrees, and the command that records it."""
    return (f"record at least {lim.min_physics_s:g} s moving at least {lim.min_strokes} times each way over "
            f"at least {lim.min_stroke_deg:g} deg: sea-daemon calibrate --excitation --fit")


def _physics(f: dict, lim: Limits) -> Verdict:
    """Whether the log can identify the physical effects: identify, nominal (a still arm) or
    refuse (it moves, but not enough to tell friction, the arm's weight and inertia apart)."""
    if f["still"]:
        return Verdict("effects", "nominal",
                       f"the arm held still (the load angle spans {f['q_span_deg']:.2f} deg): the arm's weight, the "
                       "elbow, friction and inertia show only in motion; the static torque at the held angle is "
                       "left to the residual GP")
    missing = []
    if f["duration_s"] < lim.min_physics_s:
        # rounded down: a log short of the limit never reads as long as it
        missing.append(f"is {math.floor(10 * f['duration_s'] + 1e-6) / 10:.1f} s long (at least {lim.min_physics_s:g} s)")
    if min(f["strokes_up"], f["strokes_down"]) < lim.min_strokes:
        missing.append(f"has {f['strokes_up']} move(s) up and {f['strokes_down']} down of at least "
                       f"{lim.min_stroke_deg:g} deg (at least {lim.min_strokes} each way: friction's sign shows "
                       "only where the joint turns)")
    snr = f.get("snr", {})
    for key, what in (("angle", "the angle's spread"), ("speed_up", "the speed moving up"),
                      ("speed_down", "the speed moving down")):
        v = snr.get(key)
        if v is None or v < lim.min_snr:
            missing.append(f"has {what} {'not measurable' if v is None else f'{v:.1f}'} x its noise "
                           f"(at least {lim.min_snr:g})")
    if missing:
        return Verdict("effects", "refuse", "the log " + "; ".join(missing))
    return Verdict("effects", "identify", "motion both ways over the range")


def _working_range_note(f: dict, cfg: ModelConfig, lim: Limits) -> str | None:
    """Against the declared working range (``calibration.q_min_deg``, ``q_max_deg``, ``v_max``):
    the share of its angles and of its speed the log reaches (into ``f``), and a sentence when
    it reaches less than ``lim.min_range_share`` of either (the model is extrapolated beyond)."""
    c = cfg.calibration
    if c.q_min_deg is None or c.q_max_deg is None or "q_range_deg" not in f or c.q_max_deg <= c.q_min_deg:
        return None
    lo, hi = f["q_range_deg"]
    share = max(0.0, min(hi, c.q_max_deg) - max(lo, c.q_min_deg)) / (c.q_max_deg - c.q_min_deg)
    speed = min(1.0, f["dq_max"] / c.v_max)
    f["working_range_share"] = {"angle": share, "speed": speed}
    if f["still"] or (share >= lim.min_range_share and speed >= lim.min_range_share):
        return None
    return (f"The log spans {lo:.0f}-{hi:.0f} deg at up to {f['dq_max']:.2g} rad/s: {100 * share:.0f} % of the "
            f"declared working range's angles ({c.q_min_deg:g}-{c.q_max_deg:g} deg) and {100 * speed:.0f} % of its "
            "speed (calibration.v_max); beyond, the model is extrapolated. To cover it, " + RECORD + ".")


def assess(log: MeasuredLog, cfg: ModelConfig, lim: Limits = Limits(), joint: int | None = None) -> Sufficiency:
    """The figures of ``log`` (one joint, at the configuration's rate: :func:`at_config_rate`)
    and a verdict per quantity of :data:`QUANTITIES`; ``refusal`` the one line when the log
    cannot be calibrated on.  ``joint``: the joint (0-based) of an n-joint log to assess."""
    if log.n != 1 and joint is None:
        raise InputError(f"{log.path}: {log.n} joints; the calibration's sufficiency check is for one joint")
    f = measure(log, cfg, lim, joint or 0)
    s = Sufficiency(f)
    s.refusal = _refusal(f, lim, log.path) or _still_over_range(f, cfg, log.path)
    phys = _physics(f, lim) if s.refusal is None else Verdict("effects", "refuse", "see the refusal")
    if s.refusal is None and phys.status == "refuse":
        s.refusal = f"{log.path}: cannot identify the physical effects: {phys.why}; {record_motion(lim)}"
    noise = Verdict("R", "identify", f"{f['duration_s']:.1f} s of data")
    s.verdicts = {
        "R": noise,
        "effects": phys,
        "tau_m_noise": Verdict("tau_m_noise", "identify", noise.why),
        "residual_gp": Verdict("residual_gp", "identify",
                               "at the held angle only" if f["still"] else "where the log has data (coverage)"),
        "sign_eps": (Verdict("sign_eps", "identify", "turning points both ways") if phys.status == "identify" else
                     Verdict("sign_eps", "nominal", "no turning points: friction is not identified")),
        "q_tau": Verdict("q_tau", "declared", "from the declared subject (calibration section)")}
    share = f.get("torque_limit_share", 0.0)
    if lim.saturated_flag <= share < lim.saturated_refuse:
        s.notes.append(f"The motor torque is at the hardware limit in {100 * share:.0f} % of the log: the joint may "
                       "not have followed the calibration's moves there.")
    cover = _working_range_note(f, cfg, lim)
    if cover and s.refusal is None:
        s.notes.append(cover)
    sp = f.get("spring_slope") or {}
    if sp.get("slope") is not None and (sp.get("explained") or 0.0) >= 0.5 and not 0.5 <= sp["slope"] <= 2.0 \
            and s.refusal is None:
        s.notes.append(f"The motor torque is {sp['slope']:.2f} x K_s times the spring's deflection (expected about "
                       "1): check model.K_s, hardware.gear_ratio and the angle columns.")
    return s


def working_range_of(f: dict, wr: WorkingRange | None, span_floor_deg: float = 2.0) -> WorkingRange | None:
    """``wr``, or the log's own range from its figures widened to at least ``span_floor_deg``
    (a still arm's range is a few encoder counts: a box of that width has no cells to cover);
    None without figures."""
    if wr is not None:
        return wr
    if "q_range_deg" not in f:
        return None
    lo, hi = (math.radians(v) for v in f["q_range_deg"])
    pad = max(0.0, 0.5 * (math.radians(span_floor_deg) - (hi - lo)))
    return WorkingRange(lo - pad, hi + pad, max(f["dq_max"], 0.1), max(f["ddq_max"], 1.0))
