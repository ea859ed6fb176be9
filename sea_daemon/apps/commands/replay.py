"""``sea-daemon replay LOG.csv --config MODEL.yaml [--train TRAIN.csv | --model MODEL.npz] --estimator E --out EST.csv``

Runs an estimator over a measured log (docs/interfaces.md §1, §3), writes EST.csv and prints a JSON
summary on stdout (``rmse`` when the log has ``tau_h_act``).  gp-akf with ``--train`` runs the
whole calibration on TRAIN.csv first (docs/calibration.md: noise, diagnose's physics, residual
GP, process noise; the values the configuration gives are kept), with ``--model`` it loads a
calibrated model (``sea-daemon fit``).  A log at another rate than the configuration's runs the
configuration at the log's rate (:func:`sea_daemon.core.rates.at_rate`, as ``run --rate`` does);
``--train`` must be at the log's rate.  An estimator fault (a log that does not fit the model or
its settings) is exit 2 with the sample and the reason.
"""
from __future__ import annotations

import json
import logging
import time

from sea_daemon.analysis.sufficiency import check_columns
from sea_daemon.apps.calibration.modelio import estimator_from_model, jsonable
from sea_daemon.apps.calibration.modelio import summary as cal_summary
from sea_daemon.apps.calibration.pipeline import STEPS, calibrate_log
from sea_daemon.apps.commands import add_log_and_config
from sea_daemon.apps.progress import Progress
from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.estimators.factory import RATE_TOLERANCE
from sea_daemon.core.rates import at_rate
from sea_daemon.core.replay import est_columns, replay, summarize
from sea_daemon.errors import InputError, shown
from sea_daemon.io.configfile import load_config, load_yaml
from sea_daemon.io.files import check_outputs
from sea_daemon.io.gpmodel import load_gp_model
from sea_daemon.io.logcsv import read_log, write_columns

DESCRIPTION = (
    "Run an estimator over LOG.csv and write EST.csv with t, tau_h_act_hat, tau_h_act_bound, "
    "tau_h_act_sigma (and tau_h_act when the log has it, and the state estimates). Prints a JSON "
    "summary on stdout. akf: augmented-state EKF (Park et al.; paper Alg. 1) on the model of "
    "--config; spring: the spring torque tau_s; gp-akf: the AKF with the residual learned online "
    "from --train (paper Alg. 2) after the whole calibration on it (docs/calibration.md), or a calibrated model "
    "from --model (sea-daemon fit). An 'oracle' AKF is akf with the true plant's config as --config.")

CHOICES = ("gp-akf", "akf", "spring")


def add_arguments(p) -> None:
    add_log_and_config(p)
    p.add_argument("--train", metavar="TRAIN.csv", default=None,
                   help="training log with a passive human, learned before estimation (gp-akf)")
    p.add_argument("--estimator", choices=CHOICES, default="gp-akf", help="estimator (default: gp-akf)")
    p.add_argument("--out", metavar="EST.csv", required=True, help="where to write the estimates")
    p.add_argument("--model", metavar="MODEL.npz", default=None,
                   help="a calibrated model file (sea-daemon fit / calibrate) instead of --train (gp-akf)")


def build_estimator(name: str, cfg, dt: float, train=None, raw=None, model_path=None, progress=None):
    """(estimator, calibration result or None).  gp-akf: with ``model_path`` the calibrated model
    file; with ``train`` the whole calibration on it (:func:`~sea_daemon.apps.calibration.pipeline.calibrate_log`,
    the values the configuration's YAML ``raw`` gives kept; ``progress`` its progress callback);
    the Theorem-1 bound on both."""
    if name == "gp-akf" and model_path is not None:
        residual, meta = load_gp_model(model_path, cfg)
        est = estimator_from_model(cfg, residual, meta, dt=dt, bound=theorem_bound)
        if est is None:
            raise InputError(f"--model {model_path}: not a calibrated model (write one with sea-daemon fit)")
        return est, None
    if name == "gp-akf":
        if abs(train.dt - dt) > RATE_TOLERANCE * dt:
            # the calibration identifies the differentiator's noise and the process noise at the log's rate
            raise InputError(f"--train {shown(train.path)}: sample period {train.dt:.6g} s, the log's is {dt:.6g} s; "
                             f"allowed within {100 * RATE_TOLERANCE:g} % (record both at one rate)")
        result = calibrate_log(train, cfg, raw, progress=progress)
        return result.estimator(dt=dt, bound=theorem_bound), result
    return make_estimator(name, cfg, dt=dt), None


def log_rate(log, cfg) -> float | None:
    """The log's rate [Hz] when it differs from the configuration's by more than
    :data:`RATE_TOLERANCE`, else None."""
    rate = 1.0 / log.dt
    return round(rate, 6) if abs(rate - cfg.rate_hz) > RATE_TOLERANCE * cfg.rate_hz else None


def run(args) -> int:
    check_outputs([("--out", args.out)], inputs=[args.log, args.config, args.train, args.model])
    cfg_file = load_config(args.config)
    log = read_log(args.log, n=cfg_file.joints, min_rows=2)
    # an encoder column that reports nothing: its line, not an estimator fault a few hundred samples in
    check_columns(log, torque=False)
    # the configuration at the log's rate (sea_daemon.core.rates: the differentiator's span in time
    # kept), as the daemon's --rate runs it: a 1 kHz log with a 100 Hz configuration
    cfg = at_rate(cfg_file, log_rate(log, cfg_file))
    train = read_log(args.train, n=cfg.joints, min_rows=2) if args.train else None
    if train is not None and args.estimator != "gp-akf":
        logging.getLogger("sea_daemon.replay").warning("--train is used only by gp-akf; ignored for %s",
                                                       args.estimator)
    if args.estimator == "gp-akf" and train is None and args.model is None:
        raise InputError("--estimator gp-akf needs --train TRAIN.csv (a log with a passive subject "
                         "to calibrate on) or --model MODEL.npz (a calibrated model, sea-daemon fit)")
    if args.estimator == "gp-akf" and train is not None and args.model is not None:
        raise InputError("--train and --model: give one (--train calibrates, --model loads a calibration)")
    # eq:bounds: tau_h_act_bound = the Theorem-1 ρ_k (gp-akf: GP error constants from the calibrated LoG-GPs)
    with Progress("replay") as progress:
        est, cal = build_estimator(args.estimator, cfg, log.dt, train, load_yaml(args.config), args.model,
                                   progress=progress.part(0, len(STEPS) + 1, "calibration on --train: "))
        progress(len(STEPS), len(STEPS) + 1, "the estimator over the log")
        res = replay(log, est, clock=time.perf_counter)
    res.estimator = args.estimator
    try:
        write_columns(args.out, est_columns(res))
    except OSError as e:
        raise InputError(f"--out {args.out}: cannot write: {e.strerror or e}") from None
    extra = {}
    if cal is not None:
        # what the calibration on --train identified, in numbers and plain words
        extra["calibration"] = jsonable(cal_summary(cal))
        extra["train"] = {"log": str(args.train)}
    if hasattr(est, "n_outside"):
        # samples whose z = [q, q̇, q̈] left the region the calibration data covered
        extra["outside_covered_share"] = est.n_outside / max(len(log) - 1, 1)
    summary = summarize(res, log=str(args.log), config=str(args.config), out=str(args.out), **extra)
    print(json.dumps(jsonable(summary), allow_nan=False))
    return 0

