"""``sea-daemon calibrate-bound LOG.csv --config MODEL.yaml --model MODEL.npz [--target gp|torque] [--write OUT.yaml]``

β of the GP error bound for a trained GP model, from a held-out log with a passive subject
that the model never learned: prints it as JSON and can write a copy of the configuration with
``estimator.gp_beta`` set to it, which ``sea-daemon run`` then uses for the Theorem-1 bound ρ_k
(η = β √(σ² + s_loc²)).  ``--target gp`` (default): split conformal on the GP error of each
training pair (docs/bounds.md §2b).  ``--target torque``: the smallest β whose ρ_k covers the
estimate's own error τ̂_h,act − 0 on the log in ⌈(m+1)(1 − δ)⌉ of its m steps (§2c).
When the configuration already has a number ``estimator.gp_beta``, the JSON also reports the
fraction of the log's steps its ρ_k covers (``configured``): a held-out check of that β.
"""
from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np

from sea_daemon.analysis.sufficiency import check_columns
from sea_daemon.apps.calibration.modelio import jsonable
from sea_daemon.apps.commands import add_log_and_config
from sea_daemon.apps.progress import Progress
from sea_daemon.core.bounds.calibration import conformal_gp_constants
from sea_daemon.core.bounds.torque_beta import torque_calibrated_beta, torque_coverage
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.rates import at_rate
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import load_config, save_config
from sea_daemon.io.files import check_outputs
from sea_daemon.io.gpmodel import load_gp_model
from sea_daemon.io.logcsv import read_log

DESCRIPTION = (
    "Run the GP-AKF of --config with the GP of --model (frozen) over LOG.csv, a log with a passive "
    "subject (ass:passive_human) that the model was NOT trained on (e.g. a second calibration "
    "session), form each sample's training pair (z, f) with the filter's causal kinematics and "
    "take the split-conformal quantile of |f - mu(z)| / s(z) at alpha = delta_GP / (2 n) "
    "(delta_GP = estimator.delta / 2; the factor 2 turns the bound on the noisy targets into one on "
    "the noise-free GP error). Valid for inputs exchangeable with the log's (the same kind of "
    "motion, subject and plant) and per step, not uniformly (docs/bounds.md 2b). --target torque "
    "instead searches the smallest beta whose Theorem-1 bound rho_k covers the GP-AKF's torque "
    "error (truth 0, passive subject) in 1 - delta of the log's steps (docs/bounds.md 2c; one "
    "replay of the log per trial beta, about 10). With a number estimator.gp_beta in --config the "
    "JSON also has the coverage of that beta on the log (configured). Prints JSON; "
    "--write OUT.yaml saves the config with estimator.gp_beta = beta.")


def add_arguments(p) -> None:
    add_log_and_config(p, "held-out measured log, passive subject")
    p.add_argument("--model", metavar="MODEL.npz", required=True, help="model file written by sea-daemon calibrate")
    p.add_argument("--target", choices=("gp", "torque"), default="gp",
                   help="calibrate the GP error of each pair (gp, default) or the bound on the torque "
                        "estimate itself (torque)")
    p.add_argument("--write", metavar="OUT.yaml", default=None,
                   help="write the config with estimator.gp_beta = the calibrated beta")


def run(args) -> int:
    check_outputs([("--write", args.write)], inputs=[args.log, args.config, args.model])
    cfg_file = load_config(args.config)
    log = read_log(args.log, n=cfg_file.joints, min_rows=2)
    check_columns(log, torque=False)          # an encoder column that reports nothing
    # the configuration at the log's rate (sea_daemon.core.rates): a 1 kHz log with the 100 Hz file
    rate = round(1.0 / log.dt, 6)
    cfg = at_rate(cfg_file, rate if abs(rate - cfg_file.rate_hz) > 1e-6 * cfg_file.rate_hz else None)
    residual, _ = load_gp_model(args.model, cfg)                # ModelFileError → exit 2, one line
    if all(g.n_points == 0 for g in residual.gps):
        # a calibration that kept no GP (physics alone): no GP error for β to scale
        raise InputError(f"--model {args.model}: holds no residual GP (its calibration kept the physics alone, or "
                         "it learned nothing): there is no GP error for beta to bound and estimator.gp_beta has no "
                         "effect with it; replay or run the model as it is")
    est = make_estimator("gp-akf", cfg, dt=log.dt, residual=residual, learning=False, bound=False)
    delta_gp = 0.5 * cfg.estimator.delta                         # the adapter's default split
    out = {"log": str(args.log), "model": str(args.model), "config": str(args.config), "target": args.target,
           "delta": cfg.estimator.delta}
    if args.target == "torque":
        beta, how = _torque_beta(est, log, cfg.estimator.delta, args.log), "the torque error"
        out.update(beta=beta["beta"], steps=beta["steps"], coverage=beta["coverage"],
                   target_coverage=beta["target"], runs=[[b, c] for b, c in beta["runs"]])
        beta, n_used = beta["beta"], f"{beta['steps']} steps"
        if cfg.learning.extrapolation_scale == 0:
            # calibrated where the GP has data, a small β says nothing about inputs off it
            out["warning"] = ("learning.extrapolation_scale is 0: the bound has no term for inputs off the GP's "
                              "data, and a beta calibrated on the torque error does not cover them "
                              "(docs/bounds.md 2d)")
            logging.getLogger("sea_daemon.calibrate_bound").warning(out["warning"])
    else:
        try:
            consts, _, scores = conformal_gp_constants(est, log, delta_gp)
        except ValueError as e:
            raise InputError(f"{args.log}: {e}") from None
        beta, how, n_used = max(c.sqrt_beta for c in consts), "split conformal", f"{len(scores)} pairs"
        out.update(pairs=int(len(scores)), delta_gp=delta_gp, alpha=delta_gp / (2 * cfg.joints), beta=beta,
                   beta_per_joint=[c.sqrt_beta for c in consts],
                   score_quantiles={q: np.quantile(scores, float(q) / 100, axis=0).tolist()
                                    for q in ("50", "90", "99")})
    if isinstance(cfg.estimator.gp_beta, float):
        # a held-out check of the configured β: the fraction of steps its ρ_k covers
        cov, steps = torque_coverage(est, log, cfg.estimator.gp_beta, log.tau_h_act)
        out["configured"] = {"beta": cfg.estimator.gp_beta, "coverage": cov, "steps": steps}
    if args.write:
        new = dataclasses.replace(cfg_file, estimator=dataclasses.replace(cfg_file.estimator, gp_beta=float(beta)))
        try:
            save_config(new, args.write, header=f"calibrate-bound: estimator.gp_beta by {how} on "
                                                f"{args.log} ({n_used}) for {args.model}")
        except OSError as e:
            raise InputError(f"--write {args.write}: cannot write: {e.strerror or e}") from None
        out["written"] = str(args.write)
    print(json.dumps(jsonable(out), allow_nan=False))
    return 0


def _torque_beta(est, log, delta: float, path) -> dict:
    """:func:`~sea_daemon.core.bounds.torque_beta.torque_calibrated_beta` with its progress on stderr."""
    with Progress("calibrate-bound (torque): replays", unit="beta") as bar:
        tried = [0]

        def progress(b, c):
            tried[0] += 1
            bar(tried[0], None, f"beta {b:.3g}: coverage {c:.3f}")
        try:
            return torque_calibrated_beta(est, log, delta, truth=log.tau_h_act, progress=progress)
        except ValueError as e:
            raise InputError(f"{path}: {e}") from None
