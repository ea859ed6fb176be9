"""One calibration from one passive log and the nominal robot model: nothing hand-tuned.

    from sea_daemon.apps.calibration.pipeline import calibrate, CalibrationOptions
    result = calibrate(log, cfg, given=given_keys(raw_yaml))
    est = result.estimator()            # the GP-AKF on the calibrated model

In this order (each step uses what the previous ones identified; a value the configuration
gives is kept, see :func:`given_keys`):

1. kinematics (:func:`~sea_daemon.analysis.noise.choose_kinematics`) and measurement noise R
   (:func:`~sea_daemon.analysis.noise.measurement_noise`: ALS on the encoder angles, made robust, plus the
   differentiator's velocity error measured on the log);
2. the physical model: ``diagnose`` on the log → the nominal model with the effects it finds
   (the augmented model, ``model_augmented.yaml``);
3. the motor-torque noise σ_u (:func:`~sea_daemon.analysis.noise.motor_torque_noise`) on the augmented model;
4. the τ_h,act random walk q_τ (:func:`human_walk`): the identified model replayed with
   synthetic human torques of the declared band and size; the friction-sign smoothing on the
   real passive log;
5. the residual GP (LoG-GP) on what the augmented model leaves on the load side: hyperparameters by maximum
   likelihood on a subsample of the training pairs (σ_f then is the size of that leftover, so
   the GP error bound shrinks with it), learned online over the log by the GP-AKF itself;
   kept only if blocked cross-validation shows it predicts the leftover better than zero
   (``gp='auto'``);
6. the coverage of (q, q̇, q̈) by the log's data (:class:`~.excitation.Coverage`) and the
   expected accuracy (the synthetic replay's RMSE at the chosen q_τ, passive and active).

Pure numerics and simulation: no files (the commands write them).  ``progress(done, total,
what)``, when given, is called before each step (:class:`sea_daemon.apps.progress.Progress`).
"""
from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from sea_daemon.analysis.als import config_with_R
from sea_daemon.analysis.diagnose.engine import run_diagnosis
from sea_daemon.analysis.diagnose.prepare import prepare_log
from sea_daemon.analysis.noise import choose_kinematics, measurement_noise, motor_torque_noise
from sea_daemon.analysis.sufficiency import Sufficiency, assess, at_config_rate, decimate_by, finite
from sea_daemon.core.bounds.floor import floor_record, wearer_rate
from sea_daemon.apps.calibration.tau_model import declared_inputs, walk_scale
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.estimators.calibrated import CalibratedGPAKF, make_calibrated
from sea_daemon.core.estimators.health import NISMonitor
from sea_daemon.core.estimators.weighted import WeightedResidual
from sea_daemon.core.excitation import Coverage, JointsCoverage, WorkingRange
from sea_daemon.core.kinematics import smooth_derivatives
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.sim.session import BandLimitedTorque, run_session
from sea_daemon.errors import EstimatorFault, InputError
from sea_daemon.apps.calibration.expected import SYNTHETIC, expected_accuracy, scored
from sea_daemon.apps.calibration.joints import (assess_joints, correct_body, data_working_range, data_working_ranges, fit_gp_hyper_joints,
                                                gp_cross_validation_joints, nominal_where_unidentified, pairs_report, plant_substep,
                                                rmse_per_joint, synthetic_sessions_joints,
                                                working_ranges)
from sea_daemon.apps.calibration.walk_bound import common_walk, walk_per_joint
from sea_daemon.apps.calibration.residual_gp import (V_EXCLUDE, fit_gp_hyper, gp_cross_validation,
                                                     leftover_latent_variance, offline_gp, smooth_pairs,
                                                     stick_velocity_of)
from sea_daemon.io.configfile import load_config, load_yaml
from sea_daemon.io.logcsv import read_log

#: estimator keys whose presence in the YAML means "given, keep it"
ESTIMATOR_KEYS = ("R", "Sigma_nom", "tau_m_noise", "sign_eps")


@dataclass(frozen=True)
class HumanSpec:
    """What the user declares about the subject's active torque: its band [Hz] and RMS [N m]."""

    band_hz: tuple[float, float] = (0.1, 1.0)
    rms: float = 1.5

    @property
    def rate(self) -> float:
        """A bound of |dτ_h,act/dt| for a torque of this band and size [N m/s] (2π f_max √2 RMS)."""
        return wearer_rate(self.band_hz, self.rms)


@dataclass
class CalibrationOptions:
    human: HumanSpec = field(default_factory=HumanSpec)
    working_range: WorkingRange | None = None     # default: the log's own range
    gp: str = "auto"                               # auto | on | off
    gp_cv_gain: float = 0.1                        # auto: held-out MSE must fall by this share
    q_tau_grid: tuple[float, ...] = tuple(np.geomspace(1e-3, 1e2, 11))
    synth_s: float = 20.0                          # length of each synthetic session [s]
    seed: int = 0
    weight_power: float = 2.0
    hyper_points: int = 400                        # subsample for the ML hyperparameters
    diagnose: bool = True
    refuse: bool = True          # False: a log fit refuses is calibrated with the configured physics (benchmarks)
    walk_for: str = "estimate"   # the τ_h,act walk for the estimate, or for the bound too (walk_bound)


@dataclass
class CalibrationResult:
    cfg: ModelConfig                  # the complete model: augmented physics + identified noise
    gp: object | None                 # ResidualGP or None (physics alone)
    coverage: Coverage
    report: dict
    options: CalibrationOptions

    def estimator(self, dt: float | None = None, kind: str = "gp-akf", bound=None):
        """The estimator on the calibrated model: 'gp-akf' (the residual GP weighted by its
        variance; the AKF when the GP was not kept), 'akf' (physics alone).  ``bound``: a bound
        factory (e.g. :func:`~sea_daemon.core.bounds.akf_bound.theorem_bound`)."""
        return make_calibrated(self.cfg, self.gp, self.coverage, dt=dt, kind=kind, power=self.options.weight_power,
                               v_gate=self.report.get("gp_v_gate", 0.0), bound=bound,
                               var_ref=self.report.get("gp_var_ref", 0.0))


def given_keys(raw: Mapping | None) -> set[str]:
    """Which calibration values a raw YAML mapping gives: 'kinematics', 'learning' and the
    estimator keys of :data:`ESTIMATOR_KEYS` ('R', 'Sigma_nom', 'tau_m_noise')."""
    out: set[str] = set()
    if not raw:
        return out
    est = raw.get("estimator") or {}
    out |= {k for k in ESTIMATOR_KEYS if k in est}
    for sec in ("kinematics", "learning"):
        if raw.get(sec):
            out.add(sec)
    return out


def decimate(log: MeasuredLog, max_rate_hz: float = 250.0) -> MeasuredLog:
    """The log at ≤ ``max_rate_hz`` (:func:`~sea_daemon.analysis.sufficiency.decimate_by`: angles
    sampled every m-th sample, the motor torque averaged over the m commands it replaces).
    Unchanged when already slow."""
    return decimate_by(log, int(math.ceil(1.0 / (max_rate_hz * log.dt) - 1e-9)))


def _replace_est(cfg: ModelConfig, **kw) -> ModelConfig:
    return dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, **kw))


def sigma_nom_for(cfg: ModelConfig, q_tau: float) -> dict:
    """Estimator keys of the process noise: angles 1e-16 per step (conditioning), velocities through the motor-torque
    noise only, the walk q_τ × dt (one, or one per joint) of τ_h,act [N² m²/s] or, integrated, of τ̇_h,act [N² m²/s³]."""
    n, dt = cfg.joints, cfg.dt
    q = np.broadcast_to(np.asarray(q_tau, dtype=float) * dt, (n,))
    walk = [np.zeros(n), q] if cfg.estimator.integrated else [q]
    return {"Sigma_nom": np.diag(np.concatenate([np.full(2 * n, 1e-16), np.zeros(2 * n), *walk])), "Sigma_nom_dt": dt}


def with_R(cfg: ModelConfig, R: np.ndarray) -> ModelConfig:
    """R and P0's measurement block = R (Sec. V-B)."""
    return config_with_R(cfg, R)


# ---------------------------------------------------------------------------- τ_h,act walk

def synthetic_sessions(cfg: ModelConfig, log: MeasuredLog, human: HumanSpec, sigma_u: float,
                       duration_s: float, seed: int, gp=None, power: float = 2.0,
                       v_gate: float = 0.0, var_ref: float = 0.0) -> list[MeasuredLog]:
    """The identified model as a simulated plant: a moving session (PID tracking the log's own
    motion) and a still-arm session (Sec. V-C, held at the log's median angle), each with a
    synthetic human torque of the declared band and RMS.  With ``gp`` the plant has the residual
    the estimator believes in too (its variance-weighted mean, as ``extra_load_torque``, held over
    each sample as the estimator's discrete-time model holds it: one GP prediction per sample,
    and the plant's compiled integration)."""
    plant_cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, torque_noise=float(sigma_u),
                                                                      torque_limit=max(cfg.hardware.torque_limit_max, 25.0)))
    if cfg.joints > 1:
        return synthetic_sessions_joints(cfg, plant_cfg, log, human, duration_s, seed, gp=gp, power=power,
                                         v_gate=v_gate, var_ref=var_ref)
    extra = None
    if gp is not None:
        # the residual the estimator believes in, as a load-side torque of the plant: its
        # variance-weighted mean at z = [q, q̇, 0] (the residual GP is long in q̈)
        hook = WeightedResidual(gp, cfg.estimator.gp_input_margin, False, power=power, v_gate=v_gate,
                                var_ref=var_ref)

        def extra(q, dq):
            mu, _, _ = hook.predict(np.array([q[0], dq[0], 0.0]))
            return mu.copy()
    N = min(len(log), int(round(duration_s / log.dt)))
    t = log.t[:N] - log.t[0]
    qs, _, _ = smooth_derivatives(log.t[:N], log.q[:N, 0], window=max(7, int(round(0.1 / log.dt)) | 1), degree=3)

    class _Ref:
        def reference(self, tt):
            return float(np.interp(tt, t, qs)), 0.0, 0.0

    (f_lo, f_hi), sub = human.band_hz, plant_substep(plant_cfg, 3e-3, cfg.rate_hz)     # a stable internal rate
    out = [run_session(plant_cfg, t[-1], reference=_Ref(), human=BandLimitedTorque(human.rms, f_lo, f_hi, seed=seed + 1),
                       seed=seed + 11, extra_load_torque=extra, extra_held=True, substep_hz=sub),
           run_session(plant_cfg, t[-1], hold_q=float(np.median(log.q[:N, 0])),
                       human=BandLimitedTorque(human.rms, f_lo, f_hi, seed=seed + 2), seed=seed + 12,
                       extra_load_torque=extra, extra_held=True, substep_hz=sub)]
    return out


def human_walk(cfg: ModelConfig, log: MeasuredLog, human: HumanSpec, sigma_u: float,
               opts: CalibrationOptions, tune_eps: bool = True, gp=None,
               v_gate: float = 0.0, var_ref: float = 0.0, tick: Callable | None = None) -> tuple[float, float, dict]:
    """(q_τ [N² m²/s], sign_eps [rad/s], info): the τ_h,act random walk and the friction-sign
    smoothing of the estimator's model (the AKF on the identified model, or the GP-AKF with
    ``gp``; health monitor off while scanning; ``tick(runs)`` after each filter run).  Each from
    the data that can speak for it:

    * sign_eps, a property of the plant's friction, from the real passive log alone: the ε of
      :data:`EPS_GRID` with the smallest RMS of τ̂ there (τ_h,act = 0, so every τ̂ is the
      leakage of model error).  At a turning point the true friction takes whatever value holds
      the joint; with ε wider than the velocity the filter resolves, the smoothed friction lags
      the stick and the difference leaks into τ̂ (on the simulator: passive RMSE 0.038 N m at
      ε = 0.01, 0.010 at ε = 0.003, oracle model); too narrow, the filter's velocity noise
      flips the friction sign, which the passive log shows as well.
    * q_τ, how fast the subject's torque moves, from the synthetic active sessions alone (the
      identified model as the plant, a human torque of the declared band and size, moving and
      still arm): decades of :attr:`CalibrationOptions.q_tau_grid` then its half-decades around
      the best; the smallest q_τ within 2 % of the best RMS (the smoothest estimate the data do
      not contradict) or, with ``walk_for`` "bound", among those within 10 % the one whose
      Theorem-1 bound there is smallest (:mod:`.walk_bound`).  A passive log says nothing of τ_h,act.

    sign_eps is chosen at the declared walk (:func:`declared_walk`), q_τ at that sign_eps, then
    sign_eps again at the chosen q_τ.  Without a simulated model, q_τ is the declared walk."""
    # ≤ ~4000 samples per synthetic session (20 s at 100 Hz, 10 s at 1 kHz: the lowest band shows)
    T = max(min(opts.synth_s, 4000 * log.dt), min(opts.synth_s, 10.0))
    # the passive log's first 2 T seconds (the leakage of model error into τ̂)
    passive = {"passive_log": log.slice(0, min(len(log), int(round(2 * T / log.dt))))}
    active, synth_note = _synthetic_logs(cfg, log, human, sigma_u, T, opts, gp, v_gate, var_ref)
    scan = _WalkScan(cfg, gp, opts, tune_eps, v_gate, var_ref, tick)
    q0 = declared_walk(human) * walk_scale(cfg, human)
    eps = scan.best_eps(q0, passive)
    qt, rule = scan.best_walk(eps, active, q0) if active else (q0, {"rule": "declared"})
    if cfg.joints > 1 and active:           # each joint's walk from its own errors and bound
        qt, rule = walk_per_joint(scan, eps, active, qt, cfg.joints)
    eps = scan.best_eps(qt, passive)
    logs = {**active, **passive}
    best = scan.evaluate(qt, eps, logs)
    best["objective"] = scan.objective(best, logs)
    # the NIS monitor's scale: what the chosen filter shows on these logs (its windowed mean NIS at
    # most 1/3 of the divergence threshold; at least the configured 10): a declared subject's
    # torque is not divergence
    scale = _nis_scale(cfg, gp, logs, best, opts, v_gate, var_ref)
    grid_rows = sorted(scan.table.values(), key=lambda r: (r["sign_eps"], float(np.max(r["q_tau"]))))
    info = {"grid": grid_rows, "chosen": best, "nis_scale": scale, "choice": rule}
    if synth_note:
        info["note"] = synth_note
    return qt, eps, info


def _synthetic_logs(cfg: ModelConfig, log: MeasuredLog, human: HumanSpec, sigma_u: float, T: float,
                    opts: CalibrationOptions, gp, v_gate: float, var_ref: float) -> tuple[dict, str | None]:
    """The synthetic active sessions of :func:`human_walk` ({name: log}, empty when the
    identified model cannot be simulated) and, then, why."""
    try:
        synth = synthetic_sessions(cfg, log, human, sigma_u, T, opts.seed, gp=gp, power=opts.weight_power,
                                   v_gate=v_gate, var_ref=var_ref)
        return {"synthetic_moving": synth[0], "synthetic_still": synth[1]}, None
    except (RuntimeError, ValueError, ArithmeticError, InputError) as e:
        # the identified model cannot be simulated (e.g. no static equilibrium found for its
        # spring): q_τ from the declared torque alone, the friction smoothing from the passive log
        why = str(e) if not re.search(r"\b(nan|inf)\b", str(e), re.I) else "the simulated state ran away"
        return {}, f"synthetic replay failed ({type(e).__name__}: {why}); q_tau from the declared torque"


class _WalkScan:
    """The scan of :func:`human_walk`: the RMS of τ̂ per log for each (q_τ, sign_eps) tried (``table``)."""

    def __init__(self, cfg: ModelConfig, gp, opts: CalibrationOptions, tune_eps: bool, v_gate: float,
                 var_ref: float, tick: Callable | None = None):
        self.cfg, self.gp, self.opts = cfg, gp, opts
        self.tune_eps, self.v_gate, self.var_ref = tune_eps, v_gate, var_ref
        self.tick, self.runs = tick, 0
        self.table: dict = {}
        self.has_friction = any(hasattr(e, "eps") for e in cfg.model.effects)

    def estimator(self, q, eps, dt: float, bound=None):
        """The filter at walk ``q`` and smoothing ``eps``, health monitor off; with ``bound`` (a bound
        factory) on the configuration with the subject's declared inputs (the filter is the same)."""
        c = _replace_est(self.cfg, nis_scale=1e12, sign_eps=float(eps), **sigma_nom_for(self.cfg, q))
        c = c if bound is None else declared_inputs(c, self.opts.human)
        if self.gp is None:
            return AKF(c, dt=dt, bound=bound)
        return CalibratedGPAKF(c, self.gp, dt=dt, power=self.opts.weight_power, v_gate=self.v_gate,
                               var_ref=self.var_ref, bound=bound)

    def ran(self) -> None:               # one filter run more (``tick``)
        self.runs += 1
        if self.tick is not None:
            self.tick(self.runs)

    def evaluate(self, q, eps, logs) -> dict:
        """The table's row of (q, eps), with the RMS of τ̂ on each of ``logs`` (inf: faulted)."""
        qk = float(q) if np.ndim(q) == 0 else tuple(map(float, q))
        row = self.table.setdefault((qk, float(eps)), {"q_tau": qk if np.ndim(q) == 0 else list(qk), "sign_eps": float(eps)})
        for name, lg in logs.items():
            if name in row:
                continue
            try:
                e = rmse_per_joint(lg, self.estimator(row["q_tau"], eps, lg.dt))
                row[name] = float(np.sqrt(np.mean(e ** 2)))
                row.setdefault("per_joint", {})[name] = e.tolist()
            except EstimatorFault:
                row[name] = math.inf
            self.ran()
        return row

    @staticmethod
    def objective(row: dict, logs) -> float:
        """RMS over ``logs`` of the row's RMS values."""
        return float(np.sqrt(np.mean([row[k] ** 2 for k in logs])))

    def best_eps(self, q, passive: dict) -> float:
        """The sign_eps of :data:`EPS_GRID` with the smallest RMS of τ̂ on the passive log at
        q_τ = q (the configured one without friction or tuning)."""
        if not (self.tune_eps and self.has_friction):
            return float(self.cfg.estimator.sign_eps)
        return min(EPS_GRID, key=lambda e: self.objective(self.evaluate(q, e, passive), passive))

    def best_walk(self, eps: float, active: dict, q0: float) -> tuple[float, dict]:
        """(q_τ, how it was chosen) at ``eps``: decades of the grid, the half-decades around the best,
        then :func:`.walk_bound.common_walk` (``q0`` when every replay faulted)."""
        grid = np.asarray(self.opts.q_tau_grid, dtype=float) * walk_scale(self.cfg, self.opts.human)
        for q in grid[::2]:
            self.evaluate(q, eps, active)
        b = min((r for (q, e), r in self.table.items() if e == eps and all(k in r for k in active)),
                key=lambda r: self.objective(r, active))
        if not math.isfinite(self.objective(b, active)):      # every synthetic replay faulted
            return q0, {"rule": "declared", "why": "every synthetic replay faulted"}
        i = int(np.argmin(np.abs(grid - b["q_tau"])))
        for j in [j for j in (i - 1, i + 1) if 0 <= j < len(grid)]:
            self.evaluate(grid[j], eps, active)
        return common_walk(self, eps, active, grid)


def declared_walk(human: HumanSpec) -> float:
    """q_τ [N² m²/s] from the declared torque alone: 2π f_max RMS² (a random walk whose spread
    over one period of the fastest declared component is ~ the torque's size)."""
    return 2.0 * math.pi * human.band_hz[1] * human.rms ** 2


def _nis_scale(cfg, gp, logs, best, opts, v_gate: float = 0.0, var_ref: float = 0.0) -> float:
    """max(configured nis_scale, 3 × the largest windowed mean NIS / the band's upper edge) of the
    chosen filter over the calibration's logs (passive log and synthetic subjects)."""
    c = _replace_est(cfg, nis_scale=1e12, sign_eps=best["sign_eps"], **sigma_nom_for(cfg, best["q_tau"]))
    worst = 0.0
    for lg in logs.values():
        est = AKF(c, dt=lg.dt) if gp is None else CalibratedGPAKF(c, gp, dt=lg.dt, power=opts.weight_power,
                                                                  v_gate=v_gate, var_ref=var_ref)
        mon = NISMonitor(4 * cfg.joints, c.estimator.nis_window, c.estimator.nis_alpha, 1e12)
        try:
            est.reset(lg.q[0], lg.theta_m[0], lg.tau_m[0])
            for k in range(1, len(lg)):
                est.update(lg.q[k], lg.theta_m[k], lg.tau_m[k], lg.t[k] - lg.t[k - 1])
                if est.est.k > 0:
                    worst = max(worst, mon.update(est.nis) / mon.upper)
        except EstimatorFault:
            continue
    return float(max(cfg.estimator.nis_scale, 3.0 * worst))


#: friction-sign smoothings [rad/s] the calibration chooses from
EPS_GRID = (0.002, 0.003, 0.005, 0.01, 0.02)


# ---------------------------------------------------------------------------- the whole flow

#: the steps of :func:`calibrate`, as its progress callback names them
STEPS = ("measurement noise", "physical effects (diagnose)", "motor-torque noise", "residual GP",
         "active-torque random walk", "coverage", "expected accuracy")


def sufficient_log(log: MeasuredLog, cfg: ModelConfig, refuse: bool = True) -> tuple[MeasuredLog, Sufficiency]:
    """The log at the configuration's rate (decimated from a whole multiple of it) and what it
    can identify (:mod:`sea_daemon.analysis.sufficiency`); InputError, one line saying what to
    record instead, when it cannot be calibrated on (``refuse`` False: the refusal stays in the
    returned verdicts, and what they do not identify keeps its configured value)."""
    if log.n != cfg.joints:
        raise InputError(f"{log.path}: {log.n} joint(s), the configuration has {cfg.joints}")
    # a gap or a duplicated sample is refused at its line (diagnose's time base), before any figure
    prepare_log(log)
    log, note = at_config_rate(log, cfg)
    suff = assess(log, cfg) if cfg.joints == 1 else assess_joints(log, cfg)
    if suff.refusal and refuse:
        raise InputError(suff.refusal)
    if note:
        suff.notes.insert(0, note[0].upper() + note[1:] + ".")
    return log, suff


def calibrate(log: MeasuredLog, cfg: ModelConfig, given: set[str] | None = None,
              opts: CalibrationOptions | None = None, progress: Callable | None = None) -> CalibrationResult:
    """The calibration of the module docstring on one passive log; ``progress(done, total, what)``
    before each of its :data:`STEPS`.  What the log cannot identify is not identified
    (:func:`sufficient_log`): refused, or the configured value kept and the report says so."""
    step = _stepper(progress)
    opts = opts or CalibrationOptions()
    given = set() if given is None else set(given)
    log, suff = sufficient_log(log, cfg, opts.refuse)
    report: dict = {"log": log.path, "samples": len(log), "given": sorted(given), "sufficiency": suff.to_dict()}
    # 1. kinematics and R
    step()
    cfg = _kinematics_and_R(log, cfg, given, report)
    cfg = correct_body(log, cfg, suff, report)          # the wearer's arm of a URDF model
    # the filter starts on measured velocities; the NIS monitor's window is 1 s (a transient of
    # 50 samples is 0.5 s at 100 Hz but 50 ms at 1 kHz: the same monitor in samples would trip
    # on it at 1 kHz)
    cfg = _replace_est(cfg, init_after_kinematics=True, gp_noise_in_Q=True,
                       nis_window=max(cfg.estimator.nis_window, int(round(cfg.rate_hz))))
    # 2. physics: diagnose (on the log decimated to ≤ 250 Hz: its smoother spans 0.25 s), only on a
    # log that can identify it (a still arm: the nominal model, its static torque left to the GP)
    step()
    if opts.diagnose and suff.identifies("effects"):
        nominal = cfg
        cfg = _diagnosed(log, cfg, report, progress=None if progress is None else (
            lambda done, total, what: progress(1, len(STEPS), f"{STEPS[1]}: {what}")))
        if cfg.joints > 1:            # a joint whose data cannot tell keeps the nominal model
            cfg = nominal_where_unidentified(nominal, cfg, suff, report)
    else:
        v = suff.verdicts["effects"]
        report["diagnose"] = {"effects_added": [], "skipped": v.why if v.status != "identify" else "not asked",
                              "correlated_pairs": []}
    # 3. motor-torque noise
    step()
    if "tau_m_noise" not in given:
        su, sinfo = motor_torque_noise(log, cfg)
        cfg = _replace_est(cfg, tau_m_noise=su)
        report["tau_m_noise"] = {"identified": su, **sinfo}
    else:
        report["tau_m_noise"] = {"given": cfg.estimator.tau_m_noise}
    # 4. residual GP (before the process noise: the walk is chosen for the complete model)
    step()
    Z, F = smooth_pairs(cfg, log)
    cfg, gp = _residual_gp(cfg, Z, F, given, opts, report)
    # 5. τ_h,act random walk and friction smoothing, for the complete model (physics + GP)
    step()
    cfg = _walk(log, cfg, given, opts, gp, report, tune_eps=suff.identifies("sign_eps"),
                tick=None if progress is None else (
                    lambda runs: progress(4, len(STEPS), f"{STEPS[4]} ({runs} filter runs)")))
    cfg = declared_inputs(cfg, opts.human)
    report["bound_floor"] = floor_record(cfg, opts.human.band_hz, opts.human.rms)
    # the τ_h,act walk off the covered region (core/estimators/calibrated.py) is left as configured
    # (default 0: the chosen q_τ everywhere; docs/calibration.md says why)
    report["tau_h_act_walk_outside"] = cfg.estimator.tau_h_act_walk_outside
    # 6. coverage
    step()
    if cfg.joints == 1:
        cov = Coverage(opts.working_range or data_working_range(Z))
    else:
        cov = JointsCoverage(working_ranges(opts.working_range, cfg.joints) or data_working_ranges(Z))
    cov.add(Z)
    report["coverage"] = cov.report()
    result = CalibrationResult(cfg, gp, cov, report, opts)
    # 7. what the calibration can promise
    step()
    report["expected_accuracy"] = expected_accuracy(result, log, suff, synthetic_figures(result, log))
    step()
    return result


def synthetic_figures(result: CalibrationResult, log: MeasuredLog) -> dict:
    """The synthetic subjects' RMSE of the calibrated filter (:data:`.expected.SYNTHETIC` → float or
    None, and ``KEY_why`` when it faulted there): the walk's scan's when it ran, else the
    calibrated estimator, its health monitor on, on freshly simulated sessions (Sigma_nom given)."""
    chosen = (result.report.get("tau_h_act_walk") or {}).get("chosen") or {}
    if all(k in chosen for k in SYNTHETIC):
        return {k: finite(chosen[k]) for k in SYNTHETIC}
    opts, rep = result.options, result.report
    T = max(min(opts.synth_s, 4000 * log.dt), min(opts.synth_s, 10.0))
    active, _ = _synthetic_logs(result.cfg, log, opts.human, result.cfg.estimator.tau_m_noise or 0.0, T, opts,
                                result.gp, rep.get("gp_v_gate", 0.0), rep.get("gp_var_ref", 0.0))
    out: dict = {}
    for k in SYNTHETIC:
        out[k], why = scored(active[k], result.estimator(dt=active[k].dt)) if k in active else (None, None)
        if why:
            out[f"{k}_why"] = why
    return out


def _stepper(progress: Callable | None) -> Callable[[], None]:
    """A function that reports the next of :data:`STEPS` to ``progress`` at each call."""
    done = [0]

    def step() -> None:
        k = done[0]
        if progress is not None:
            progress(k, len(STEPS), STEPS[k] if k < len(STEPS) else "done")
        done[0] = k + 1
    return step


def _kinematics_and_R(log: MeasuredLog, cfg: ModelConfig, given: set[str], report: dict) -> ModelConfig:
    """Step 1: the kinematics for the rate and the measurement noise R (unless given)."""
    if "kinematics" not in given:
        cfg = dataclasses.replace(cfg, kinematics=choose_kinematics(cfg.rate_hz))
    report["kinematics"] = dataclasses.asdict(cfg.kinematics)
    if "R" not in given:
        R, rinfo = measurement_noise(log, cfg)
        cfg = with_R(cfg, R)
        report["R"] = {"identified": np.diag(R).tolist(), **rinfo}
    else:
        report["R"] = {"given": np.diag(cfg.estimator.R).tolist()}
    return cfg


def _diagnosed(log: MeasuredLog, cfg: ModelConfig, report: dict, progress: Callable | None = None) -> ModelConfig:
    """Step 2: the nominal model with the effects diagnose finds on the log (decimated)."""
    dg = run_diagnosis(decimate(log), cfg, passive=True, estimate=False, progress=progress)
    report["diagnose"] = {"effects_added": dg.result["effects_added"],
                          "residual_rms_before": dg.result["residual_rms_before"],
                          "residual_rms_after": dg.result["residual_rms_after"],
                          "unexplained_fraction": dg.result["unexplained_fraction"],
                          "statements": dg.result["statements"],
                          # effects the log cannot tell apart: one kept, the other dropped
                          "correlated_pairs": [{k: c[k] for k in ("kept", "dropped", "correlation")}
                                               for c in dg.result.get("correlated_pairs", [])]}
    return dg.cfg_after


def _residual_gp(cfg: ModelConfig, Z: np.ndarray, F: np.ndarray, given: set[str], opts: CalibrationOptions,
                 report: dict) -> tuple[ModelConfig, object]:
    """Step 4: the residual GP's hyperparameters (unless given) and the GP on the leftover
    pairs, when kept (``opts.gp``: 'on', 'off', or 'auto' by blocked cross-validation)."""
    # the speed below which the GP has no pairs (0: a still-arm log, every pair kept)
    v_stick = max(stick_velocity_of(cfg), V_EXCLUDE)
    n = cfg.joints
    report["gp_v_gate"] = v_stick if np.all(np.abs(Z[:, n:2 * n]) >= v_stick - 1e-12) else 0.0
    report["leftover"] = {"rms": float(np.sqrt(np.mean(F ** 2))), "pairs": int(len(Z))}
    # the angles and speeds the log's moving data span [rad, rad/s]
    report["data_range"] = {"q": [float(np.min(Z[:, 0])), float(np.max(Z[:, 0]))],
                            "dq": float(np.max(np.abs(Z[:, 1])))}
    report.update(pairs_report(Z, F) if n > 1 else {})
    if "learning" not in given:
        hyp = (fit_gp_hyper(Z, F, opts.hyper_points, opts.seed) if n == 1 else
               fit_gp_hyper_joints(Z, F, opts.hyper_points, opts.seed))
        # the tree splits in length scales: in raw units q̈ (span ~10–30 rad/s², length scale twice
        # that) would take every split and the routing would key the mean on q̈
        lc = dataclasses.replace(cfg.learning, sigma_f=hyp["sigma_f"], lengthscales=tuple(hyp["lengthscales"]),
                                 sigma_n=hyp["sigma_n"], hyperopt=False, split_in_lengthscales=True)
        cfg = dataclasses.replace(cfg, learning=lc)
        report["gp_hyper"] = hyp
    gp = None
    keep = opts.gp == "on"
    if opts.gp == "auto":
        cv = gp_cross_validation(Z, F, cfg.learning) if n == 1 else gp_cross_validation_joints(Z, F, cfg.learning)
        report["gp_cv"] = cv
        keep = cv["gain"] >= opts.gp_cv_gain
    if keep:
        # the load side's leftover pairs, trained directly: no filter in the loop (nothing to diverge)
        gp = offline_gp(cfg, Z, F)
    report["gp_kept"], report["gp_directions"] = gp is not None, gp.directions_record() if gp is not None else None
    if gp is None and not cfg.estimator.model_error and len(F):
        # the AKF's bound needs a term for the model error it makes (docs/bounds.md §7): the largest
        # leftover torque of this log, +25 % (a GP-AKF's GP error takes its place)
        cfg = _replace_est(cfg, model_error=1.25 * float(np.max(np.abs(F))))
        report["model_error"] = cfg.estimator.model_error
    # the weight's reference (core/estimators/weighted.py): what the physics alone costs on these
    # pairs, the leftover's mean square less the GP's noise variance σ_on² (its latent part)
    report["gp_var_ref"] = leftover_latent_variance(F, cfg.learning.sigma_n)
    return cfg, gp


def _walk(log: MeasuredLog, cfg: ModelConfig, given: set[str], opts: CalibrationOptions, gp,
          report: dict, tune_eps: bool = True, tick: Callable | None = None) -> ModelConfig:
    """Step 5: the τ_h,act random walk and the friction smoothing (:func:`human_walk`; the
    smoothing only with ``tune_eps``, a log with turning points), unless Sigma_nom is given."""
    if "Sigma_nom" not in given:
        qt, eps, qinfo = human_walk(cfg, log, opts.human, cfg.estimator.tau_m_noise or 0.0, opts,
                                    tune_eps=tune_eps and "sign_eps" not in given, gp=gp, v_gate=report["gp_v_gate"],
                                    var_ref=report["gp_var_ref"], tick=tick)
        cfg = _replace_est(cfg, sign_eps=eps, nis_scale=qinfo["nis_scale"], **sigma_nom_for(cfg, qt))
        report["tau_h_act_walk"] = {"q_tau": float(np.max(qt)), "sign_eps": eps,
                                    **({"q_tau_per_joint": list(qt)} if np.ndim(qt) else {}), "human": dataclasses.asdict(opts.human), **qinfo}
    else:
        report["tau_h_act_walk"] = {"given": np.diag(cfg.estimator.Sigma_nom).tolist()}
    return cfg


def options_from_config(cfg: ModelConfig, gp: str = "auto") -> CalibrationOptions:
    """:class:`CalibrationOptions` from the configuration's ``calibration`` section."""
    c = cfg.calibration
    wr = None
    if c.q_min_deg is not None and c.q_max_deg is not None:
        wr = WorkingRange(math.radians(c.q_min_deg), math.radians(c.q_max_deg), c.v_max, c.a_max)
    return CalibrationOptions(human=HumanSpec(tuple(c.human_band_hz), c.human_torque_rms), working_range=wr,
                              gp=gp, seed=c.seed, walk_for=c.walk_for)


def calibrate_log(log: MeasuredLog, cfg: ModelConfig, raw: Mapping | None, gp: str = "auto",
                  progress: Callable | None = None) -> CalibrationResult:
    """The calibration of ``log`` with the configuration ``cfg`` whose YAML mapping is ``raw``
    (its given values kept, :func:`given_keys`; options from its ``calibration`` section)."""
    return calibrate(log, cfg, given=given_keys(raw), opts=options_from_config(cfg, gp), progress=progress)


def calibrate_from_files(log_path, config_path, gp: str = "auto", progress: Callable | None = None) -> CalibrationResult:
    """The calibration of the log file ``log_path`` with the configuration file ``config_path``."""
    cfg = load_config(config_path)
    log = read_log(log_path, n=cfg.joints, min_rows=2)
    return calibrate_log(log, cfg, load_yaml(config_path), gp, progress)
