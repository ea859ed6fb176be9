"""The offline calibration of n joints (a ``model.urdf``): the steps of :mod:`.pipeline` per joint.

:func:`~.pipeline.calibrate` runs the same steps for one joint and for n; what differs for n
joints lives here:

* sufficiency per joint (:func:`assess_joints`): each joint's log judged on its own by the rules
  of one joint (:func:`~sea_daemon.analysis.sufficiency.assess` of that joint): what one joint's
  log refuses refuses the log, naming the joint; a joint held still keeps the nominal model — the
  effects found on it are dropped, and the report says so (:func:`nominal_where_unidentified`);
* the residual GP's hyperparameters (:func:`fit_gp_hyper_joints`): fitted on each joint's own
  leftover, each joint's length scales of (q_j, q̇_j, q̈_j) from its own fit; one LoG-GP per
  joint on z ∈ R^{3n} sharing them (:class:`~sea_daemon.core.learning.ResidualGP`);
* the GP's blocked cross-validation over all joints (:func:`gp_cross_validation_joints`);
* the working range per joint (:func:`data_working_ranges`) and the coverage per joint
  (:class:`~sea_daemon.core.excitation.JointsCoverage`);
* the rigid body of the URDF (the exoskeleton's links and the wearer's arm, a declared body),
  corrected first (:func:`correct_body`: its links' mass and length factors, which show on
  every joint, fitted beside each joint's load friction);
* the synthetic subjects of the τ_h,act walk (:func:`synthetic_sessions_joints`): a torque of
  the declared band and size on every joint, its own per joint, moving (the log's own motion)
  and with the arm held still.

Pure numerics and simulation: no files.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sea_daemon.analysis.sufficiency import Sufficiency, Verdict, assess
from sea_daemon.analysis.diagnose.residuals import kinematics_from_log, spring_torque, window_samples
from sea_daemon.apps.calibration.residual_gp import V_EXCLUDE, fit_gp_hyper
from sea_daemon.core.config import LearningConfig, ModelConfig
from sea_daemon.core.control import PIDGains
from sea_daemon.core.effects import make_effect
from sea_daemon.core.estimators.weighted import WeightedResidual
from sea_daemon.core.excitation import WorkingRange
from sea_daemon.core.kinematics import smooth_derivatives
from sea_daemon.core.learning import ResidualGP
from sea_daemon.core.log import MeasuredLog
from sea_daemon.core.model import SEAModel
from sea_daemon.core.replay import replay
from sea_daemon.core.rigid import fit_factors, link_masses
from sea_daemon.core.sim.plant import Plant
from sea_daemon.core.sim.session import BandLimitedTorque, run_session
from sea_daemon.errors import InputError

#: the quantities whose verdict is combined over the joints (the strictest joint's)
_ORDER = {"refuse": 0, "nominal": 1, "declared": 2, "identify": 3}


def joint_log(log: MeasuredLog, j: int) -> MeasuredLog:
    """Joint ``j`` (0-based) of an n-joint log as a one-joint log (same times and path)."""
    def col(a):
        return None if a is None else np.asarray(a)[:, [j]]
    return dataclasses.replace(log, q=col(log.q), theta_m=col(log.theta_m), tau_m=col(log.tau_m),
                               tau_h_act=col(log.tau_h_act), extra={})


class JointsSufficiency(Sufficiency):
    """The sufficiency of an n-joint log: each joint's (:attr:`joints`), the verdicts combined.

    A quantity is identified when every joint identifies it, except ``effects``: identified
    when one joint can (the others keep the nominal model, :func:`nominal_where_unidentified`)."""

    def __init__(self, joints: list[Sufficiency], names: list[str]):
        self.joints, self.names = joints, names
        figures = {"joints": [s.figures for s in joints], "still": all(s.still for s in joints)}
        for k in ("samples", "duration_s", "rate_hz", "config_rate_hz"):
            figures[k] = joints[0].figures.get(k)
        # the least any joint shows (the one-joint report's sentence reads these)
        for k in ("strokes_up", "strokes_down", "q_span_deg"):
            figures[k] = min(s.figures.get(k, 0) for s in joints)
        super().__init__(figures)
        for q in joints[0].verdicts:
            vs = [s.verdicts[q] for s in joints]
            if q == "effects" and any(v.status == "identify" for v in vs) and not any(v.status == "refuse" for v in vs):
                worst = next(v for v in vs if v.status == "identify")
            else:
                worst = min(vs, key=lambda v: _ORDER.get(v.status, 0))
            why = "; ".join(f"{n}: {v.why}" for n, v in zip(names, vs) if v.status != "identify") or worst.why
            self.verdicts[q] = Verdict(q, worst.status, why)
        self.notes = [f"{n}: {line}" for n, s in zip(names, joints) for line in s.notes]

    def joint_identifies(self, j: int, quantity: str) -> bool:
        return self.joints[j].identifies(quantity)

    def to_dict(self) -> dict:
        return {**super().to_dict(), "per_joint": {n: s.to_dict() for n, s in zip(self.names, self.joints)}}


def joint_names(cfg: ModelConfig) -> list[str]:
    """The joints' names: the URDF's, else ``joint 1`` … ``joint n``."""
    rigid = cfg.model.rigid
    if rigid is not None:
        return [f"joint {j + 1} ({name})" for j, name in enumerate(rigid.joint_names)]
    return [f"joint {j + 1}" for j in range(cfg.joints)]


def assess_joints(log: MeasuredLog, cfg: ModelConfig) -> JointsSufficiency:
    """Each joint of ``log`` assessed on its own, by the rules of one joint
    (:func:`~sea_daemon.analysis.sufficiency.assess` of that joint): a joint one joint's log
    would refuse (too short, too few moves each way, a dead encoder, ...) refuses the log, the
    ``refusal`` naming the first such joint; a joint held still keeps the nominal model where
    a still one-joint log keeps it (:func:`nominal_where_unidentified`)."""
    names = joint_names(cfg)
    per = [assess(log, cfg, joint=j) for j in range(cfg.joints)]
    s = JointsSufficiency(per, names)
    s.refusal = next((f"{n}: {p.refusal}" for n, p in zip(names, per) if p.refusal), None)
    return s


def nominal_where_unidentified(before: ModelConfig, after: ModelConfig, suff: JointsSufficiency,
                               report: dict) -> ModelConfig:
    """``after`` (the diagnosed model) without the effects diagnose added on a joint whose data
    cannot identify them (the nominal model there); the report's diagnose section names them."""
    keep_j = [suff.joint_identifies(j, "effects") for j in range(before.joints)]
    if all(keep_j):
        return after
    old = set(map(id, before.model.effects))
    kept, dropped = [], []
    for e in after.model.effects:
        j = int(getattr(e, "joint", 0))
        (kept if id(e) in old or keep_j[j] else dropped).append(e)
    d = report.setdefault("diagnose", {})
    names = joint_names(before)
    d["nominal_joints"] = [names[j] for j in range(before.joints) if not keep_j[j]]
    d["effects_dropped"] = [f"{type(e).__name__}[{int(getattr(e, 'joint', 0)) + 1}]" for e in dropped]
    d.setdefault("statements", []).append(
        f"Not identified from this log, the nominal model kept on {', '.join(d['nominal_joints'])} "
        f"({'; '.join(suff.joints[j].verdicts['effects'].why for j in range(before.joints) if not keep_j[j])})"
        + (f"; dropped the effects found there: {', '.join(d['effects_dropped'])}." if dropped else "."))
    added = d.get("effects_added", [])
    d["effects_added"] = [a for a in added if keep_j[int(a.get("joint", 1)) - 1]]
    return after.with_effects(kept)


def fit_gp_hyper_joints(Z: np.ndarray, F: np.ndarray, points: int, seed: int) -> dict:
    """The residual GP's hyperparameters for n joints: :func:`~.residual_gp.fit_gp_hyper` on each
    joint's own leftover F[:, j] over its own (q_j, q̇_j, q̈_j); the length scales of z ∈ R^{3n}
    are each joint's own ([q_1..q_n, q̇_1..q̇_n, q̈_1..q̈_n]); σ_f and σ_on the largest over the
    joints (one setting for all the joints' GPs: the larger prior keeps every joint's GP honest
    about its variance).  ``per_joint``: each joint's fit."""
    n = F.shape[1]
    fits = [fit_gp_hyper(Z[:, [j, n + j, 2 * n + j]], F[:, [j]], points, seed + j) for j in range(n)]
    ls = np.array([f["lengthscales"] for f in fits])       # (n, 3)
    return {"sigma_f": max(f["sigma_f"] for f in fits), "sigma_n": max(f["sigma_n"] for f in fits),
            "lengthscales": [float(v) for v in ls.T.ravel()], "per_joint": fits}


def gp_cross_validation_joints(Z: np.ndarray, F: np.ndarray, lc: LearningConfig, folds: int = 5) -> dict:
    """Blocked K-fold of the n joints' GPs (:func:`~.residual_gp.gp_cross_validation` per joint):
    MSE against predicting 0, summed over the joints, and each joint's gain."""
    N, n = F.shape
    edges = np.linspace(0, N, folds + 1).astype(int)
    mse_gp, mse_0 = np.zeros(n), np.zeros(n)
    lc0 = dataclasses.replace(lc, hyperopt=False)
    for k in range(folds):
        test = np.arange(edges[k], edges[k + 1])
        train = np.setdiff1d(np.arange(N), test)
        gp = ResidualGP(n, lc0)
        gp.train(Z[train], F[train])
        for j in range(n):
            mu, _ = gp.gps[j].predict_many(Z[test])
            mse_gp[j] += float(np.sum((F[test, j] - mu) ** 2))
            mse_0[j] += float(np.sum(F[test, j] ** 2))
    return {"mse_gp": float(np.sum(mse_gp)) / N, "mse_zero": float(np.sum(mse_0)) / N,
            "gain": 1.0 - float(np.sum(mse_gp)) / max(float(np.sum(mse_0)), 1e-300),
            "gain_per_joint": [1.0 - a / max(b, 1e-300) for a, b in zip(mse_gp, mse_0)]}


def data_working_range(Z: np.ndarray, span_floor: float = math.radians(2.0)) -> WorkingRange:
    """The working range the pairs ``Z`` span, at least ``span_floor`` [rad] wide, 0.1 rad/s and
    1 rad/s² (a still arm spans a few encoder counts: a box that narrow has no cells to cover)."""
    return data_working_ranges(Z[:, :3], span_floor)[0]


def pairs_report(Z: np.ndarray, F: np.ndarray) -> dict:
    """The report's ``leftover`` and ``data_range`` of n joints' pairs: the leftover's RMS over all and
    per joint; the angles [rad] and the largest speed [rad/s] over all joints and per joint."""
    n = F.shape[1]
    return {"leftover": {"rms": float(np.sqrt(np.mean(F ** 2))), "pairs": int(len(Z)),
                         "rms_per_joint": np.sqrt(np.mean(F ** 2, axis=0)).tolist()},
            "data_range": {"q": [float(np.min(Z[:, :n])), float(np.max(Z[:, :n]))],
                           "dq": float(np.max(np.abs(Z[:, n:2 * n]))),
                           "per_joint": {"q": [[float(np.min(Z[:, j])), float(np.max(Z[:, j]))] for j in range(n)],
                                         "dq": np.max(np.abs(Z[:, n:2 * n]), axis=0).tolist()}}}


def data_working_ranges(Z: np.ndarray, span_floor: float = math.radians(2.0)) -> list[WorkingRange]:
    """Each joint's working range spanned by the pairs ``Z`` (N, 3n), as :func:`data_working_range`."""
    n = Z.shape[1] // 3
    out = []
    for j in range(n):
        q, dq, ddq = Z[:, j], Z[:, n + j], Z[:, 2 * n + j]
        lo, hi = float(np.min(q)), float(np.max(q))
        pad = max(0.0, 0.5 * (span_floor - (hi - lo)))
        out.append(WorkingRange(lo - pad, hi + pad, max(float(np.max(np.abs(dq))), 0.1),
                                max(float(np.max(np.abs(ddq))), 1.0)))
    return out


def declared_working_ranges(cfg: ModelConfig) -> list[WorkingRange]:
    """Each joint's working range for the calibration excitation: the ``calibration`` section's angles
    (the same for every joint) when declared, else the URDF's joint limits where it gives them, else
    10°–90°; the section's v_max and a_max."""
    c = cfg.calibration
    rigid = cfg.model.rigid
    out = []
    for j in range(cfg.joints):
        lo, hi = math.radians(10.0), math.radians(90.0)
        if c.q_min_deg is not None and c.q_max_deg is not None:
            lo, hi = math.radians(c.q_min_deg), math.radians(c.q_max_deg)
        elif rigid is not None and np.isfinite(rigid.q_min[j]) and np.isfinite(rigid.q_max[j]) \
                and rigid.q_max[j] > rigid.q_min[j]:
            lo, hi = float(rigid.q_min[j]), float(rigid.q_max[j])
        out.append(WorkingRange(lo, hi, c.v_max, c.a_max))
    return out


def working_ranges(given, n: int) -> list[WorkingRange] | None:
    """The declared working range(s) as a list of n (one range given: the same for every joint)."""
    if given is None:
        return None
    if isinstance(given, WorkingRange):
        return [given] * n
    given = list(given)
    if len(given) != n:
        raise InputError(f"working ranges: {len(given)} given, the configuration has {n} joints")
    return given


def plant_substep(cfg: ModelConfig, sign_eps: float, rate_hz: float) -> float:
    """The smallest internal rate (1 kHz or the sample rate, doubled as needed up to 32 kHz) at which the
    plant of ``cfg`` is stable (a light distal link with a sharp friction sign is a stiff mode)."""
    sub = max(1000.0, float(rate_hz))
    for _ in range(6):
        try:
            Plant(cfg, q0=np.full(cfg.joints, 0.5), substep_hz=sub, sign_eps=sign_eps)
            return sub
        except ValueError as e:
            if "substep" not in str(e):
                raise
            sub *= 2.0
    return sub


def rmse_per_joint(log: MeasuredLog, est) -> np.ndarray:
    """The RMSE of ``est``'s τ̂_h,act over ``log`` per joint (against τ_h,act = 0 when the log has no truth)."""
    res = replay(log, est)
    truth = log.tau_h_act if log.tau_h_act is not None else np.zeros_like(res.tau_h_act_hat)
    return np.sqrt(np.mean((res.tau_h_act_hat - truth) ** 2, axis=0))


class _Interp:
    """The log's smoothed angles replayed as the reference of n joints (velocity and acceleration 0:
    the session's PID tracks the angle, with :data:`SYNTHETIC_GAINS`)."""

    def __init__(self, t: np.ndarray, Q: np.ndarray):
        self.t, self.Q = t, Q
        self.z = np.zeros(Q.shape[1])

    def reference(self, tt: float):
        return np.array([float(np.interp(tt, self.t, c)) for c in self.Q.T]), self.z, self.z


#: the still-arm synthetic subject also holds the arm where it started [N m/rad, N m s/rad] (a relaxed
#: arm's stiffness and damping, ``run_session``'s ``hold``, as the two-joint family's still sessions):
#: without it the open-loop n-joint arm wanders under the subject's torque (the example's elbow over
#: 10 deg in 6 s), away from the one angle a still-arm calibration knows, and the still-arm promise
#: was the model's error there (the two-joint demo: 2.52 N m promised, 0.03-0.05 measured)
STILL_HOLD = (20.0, 2.0)

#: the PID gains with which the moving synthetic session tracks the log's own angles [N m/rad,
#: N m/(rad s), N m s/rad]: stiff, so that the session moves as the log did.  The log's angles are
#: already a closed loop's response, resonance included; tracked again by a session's usual soft
#: gains (40, 80, 2) that resonance is amplified a second time (a two-joint log whose shoulder moved
#: at 2.5 rad/s: the synthetic shoulder swung from -31 to 122 deg, 29 deg RMS from the log, against
#: the torque limit), the estimate's error there is the end stops' and the saturation's, and the
#: walk chosen on it is the smallest of the grid, too slow for a wearer who pushes.  With these
#: gains the same sessions stay within 1-4 deg RMS of the log.
SYNTHETIC_GAINS = PIDGains(200.0, 200.0, 10.0, velocity_filter_hz=30.0)


def synthetic_sessions_joints(cfg: ModelConfig, plant_cfg: ModelConfig, log: MeasuredLog, human, duration_s: float,
                              seed: int, gp=None, power: float = 2.0, v_gate: float = 0.0,
                              var_ref: float = 0.0) -> list[MeasuredLog]:
    """:func:`~.pipeline.synthetic_sessions` for n joints: the identified model ``plant_cfg`` as the
    plant, a moving session (the log's own motion) and a still-arm one (held at the log's median
    angles), each with a torque of the declared band and RMS on every joint (its own per joint)."""
    n = cfg.joints
    extra = None
    if gp is not None:
        hook = WeightedResidual(gp, cfg.estimator.gp_input_margin, False, power=power, v_gate=v_gate, var_ref=var_ref)
        zc = np.zeros(3 * n)

        def extra(q, dq):
            zc[:n], zc[n:2 * n] = q, dq
            mu, _, _ = hook.predict(zc)
            return mu.copy()
    N = min(len(log), int(round(duration_s / log.dt)))
    t = log.t[:N] - log.t[0]
    w = max(7, int(round(0.1 / log.dt)) | 1)
    Q = np.column_stack([smooth_derivatives(log.t[:N], log.q[:N, j], window=w, degree=3)[0] for j in range(n)])
    f_lo, f_hi = human.band_hz

    def subject(s0: int):
        parts = [BandLimitedTorque(human.rms, f_lo, f_hi, seed=s0 + 17 * j) for j in range(n)]
        out = np.zeros(n)

        def tau(tt):
            for j, p in enumerate(parts):
                out[j] = p(tt)
            return out
        return tau
    sub = plant_substep(plant_cfg, 3e-3, cfg.rate_hz)
    return [run_session(plant_cfg, t[-1], reference=_Interp(t, Q), human=subject(seed + 1), seed=seed + 11,
                        gains=SYNTHETIC_GAINS, extra_load_torque=extra, extra_held=True, substep_hz=sub),
            run_session(plant_cfg, t[-1], hold_q=np.median(log.q[:N], axis=0), human=subject(seed + 2),
                        seed=seed + 12, extra_load_torque=extra, extra_held=True, substep_hz=sub, hold=STILL_HOLD)]


#: the correction is kept when it lowers the RMS torque error of the rigid body by at least this share
BODY_GAIN = 0.1


def load_regressors(q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """(N, n, 4n) regressors of the load-side torques :func:`correct_body` fits beside the body, in
    joint j's row: its viscous and Coulomb friction ``q̇_j``, ``sign(q̇_j)``, and a stiffness about
    a rest angle (the wearer's tissue) ``q_j``, ``1``; coefficients [b (n), F_c (n), k (n), c (n)]."""
    N, n = dq.shape
    X = np.zeros((N, n, 4 * n))
    for j in range(n):
        X[:, j, j], X[:, j, n + j] = dq[:, j], np.sign(dq[:, j])
        X[:, j, 2 * n + j], X[:, j, 3 * n + j] = q[:, j], 1.0
    return X


def correct_body(log: MeasuredLog, cfg: ModelConfig, suff: Sufficiency, report: dict, points: int = 600) -> ModelConfig:
    """The rigid body of a ``model.urdf`` corrected from the passive log: the mass and length
    factors of every link with a mass — the exoskeleton's links (a length moves the joints the
    link carries: an elbow set for another wearer) and the wearer's arm (the links named
    ``human_…``) — that best explain the load side's torque −τ_s − Σ declared load effects
    (eq:loadside with τ_h,act = 0) on up to ``points`` samples where every joint moves
    (:func:`sea_daemon.core.rigid.fit_factors`, least squares over RNEA).  Each joint's viscous
    and Coulomb load friction and a linear stiffness about a rest angle (the wearer's tissue) are
    fitted beside them (:func:`load_regressors`), so that torques the model does not declare yet
    do not bend the factors; those that hold are added to the model (:func:`beside_effects`),
    and diagnose then adds what the log shows beyond them.  A wrong link mass or length shows on every joint it
    loads (M(q), C(q, q̇), g(q)), so one factor explains it on all of them — the per-joint effects
    of diagnose could only imitate it.  Kept when it lowers the RMS torque error by
    :data:`BODY_GAIN` or more; the report's ``body`` says what was fitted and whether it was kept.
    Unchanged without a URDF or a log that identifies the physics (``suff``)."""
    rigid = cfg.model.rigid
    if rigid is None or not suff.identifies("effects"):
        return cfg
    links = list(link_masses(rigid.urdf, rigid.source))
    if not links:
        report["body"] = {"skipped": "no link with a mass in model.urdf"}
        return cfg
    model = SEAModel.from_config(cfg)
    kin = kinematics_from_log(log)
    q, th = model.correct_measurement(kin.q_raw, kin.theta_m_raw)
    tau = -spring_torque(model, q - th, kin.dq - kin.dtheta_m)
    for e in model.load_effects:
        tau[:, e.joint] -= np.array([e.evaluate(a, b, c)[0] for a, b, c in
                                     zip(q[:, e.joint], kin.dq[:, e.joint], kin.ddq[:, e.joint])])
    edge = window_samples(log.t)
    idx = np.arange(edge, len(log) - edge)
    idx = idx[np.all(np.abs(kin.dq[idx]) >= V_EXCLUDE, axis=1)]
    if len(idx) < 50:
        report["body"] = {"skipped": "fewer than 50 samples with every joint moving"}
        return cfg
    idx = idx[np.linspace(0, len(idx) - 1, min(points, len(idx))).astype(int)]
    fit = fit_factors(rigid, links, q[idx], kin.dq[idx], kin.ddq[idx], tau[idx],
                      nuisance=load_regressors(q[idx], kin.dq[idx]))
    before, after = float(np.sqrt(np.mean(fit.rms_before ** 2))), float(np.sqrt(np.mean(fit.rms_after ** 2)))
    keep = after <= (1.0 - BODY_GAIN) * before
    n = cfg.joints
    report["body"] = {"links": links, "mass": fit.mass, "length": fit.length, "kept": bool(keep),
                      "beside": dict(zip(("viscous", "coulomb", "stiffness", "offset"), fit.coefficients.reshape(4, n).tolist())),
                      "rms_before": fit.rms_before.tolist(), "rms_after": fit.rms_after.tolist(), "samples": int(len(idx))}
    if not keep:
        return cfg
    added = beside_effects(fit.coefficients.reshape(4, n), q[idx], kin.dq[idx], fit.rms_after)
    # a joint whose data cannot identify its physics (held still) keeps the nominal model
    per_joint = getattr(suff, "joint_identifies", None)
    added = [e for e in added if per_joint is None or per_joint(e.joint, "effects")]
    report["body"]["effects_added"] = [f"{e.type}(load)[{e.joint + 1}]" for e in added]
    return dataclasses.replace(cfg, model=cfg.model.with_rigid(fit.body).with_effects((*cfg.model.effects, *added)))


def beside_effects(coef: np.ndarray, q: np.ndarray, dq: np.ndarray, rms: np.ndarray) -> list:
    """The load effects of the torques fitted beside the body (``coef`` rows b, F_c, k, c of
    :func:`load_regressors`, per joint) that hold: viscous and Coulomb friction and the tissue's
    stiffness (``human_viscoelastic``, k (q − q_0), q_0 = −c/k) where the coefficient is positive
    (a friction that opposes the motion, a stiffness that pulls back) and the term's largest torque
    over the samples exceeds the RMS error the fit leaves on that joint (``rms``)."""
    out = []
    for j in range(q.shape[1]):
        b, F_c, k, c = (float(v) for v in coef[:, j])
        span = float(np.max(q[:, j]) - np.min(q[:, j]))
        if b > 0.0 and b * float(np.max(np.abs(dq[:, j]))) > rms[j]:
            out.append(make_effect("viscous", "load", joint=j, b=b))
        if F_c > rms[j]:
            out.append(make_effect("coulomb", "load", joint=j, F_c=F_c))
        if k > 0.0 and k * span > rms[j]:
            out.append(make_effect("human_viscoelastic", "load", joint=j, k_h=k, q_h0=-c / k, b_h=0.0))
    return out
