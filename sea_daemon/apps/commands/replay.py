"""``sea-daemon replay LOG.csv --config MODEL.yaml [--train TRAIN.csv] --estimator E --out EST.csv``

Runs an estimator over a measured log (docs/interfaces.md §1, §3), writes EST.csv and prints a JSON
summary on stdout (``rmse`` when the log has ``tau_h_act``).
"""
from __future__ import annotations

import json
import sys
import time

from sea_daemon.io.configfile import load_config
from sea_daemon.errors import InputError
from sea_daemon.core.estimators import make_estimator
from sea_daemon.io.logcsv import read_log, write_columns
from sea_daemon.core.replay import est_columns, replay, summarize
from sea_daemon.apps.commands import add_log_and_config

NAME = "replay"
HELP = "run an estimator (gp-akf, akf, spring) over a measured log; EST.csv + JSON summary"
ORDER = 30
DESCRIPTION = (
    "Run an estimator over LOG.csv and write EST.csv with t, tau_h_act_hat, tau_h_act_bound, "
    "tau_h_act_sigma (and tau_h_act when the log has it, and the state estimates). Prints a JSON "
    "summary on stdout. akf: augmented-state EKF (Park et al.; paper Alg. 1) on the model of "
    "--config; spring: the spring torque tau_s; gp-akf: the AKF with the residual learned online "
    "from --train (paper Alg. 2). An 'oracle' AKF is akf with the true plant's config as --config.")

CHOICES = ("gp-akf", "akf", "spring")


def add_arguments(p) -> None:
    add_log_and_config(p)
    p.add_argument("--train", metavar="TRAIN.csv", default=None,
                   help="training log with a passive human, learned before estimation (gp-akf)")
    p.add_argument("--estimator", choices=CHOICES, default="gp-akf", help="estimator (default: gp-akf)")
    p.add_argument("--out", metavar="EST.csv", required=True, help="where to write the estimates")


def run(args) -> int:
    cfg = load_config(args.config)
    log = read_log(args.log, n=cfg.joints, min_rows=2)
    train = read_log(args.train, n=cfg.joints, min_rows=2) if args.train else None
    if train is not None and args.estimator != "gp-akf":
        print(f"sea-daemon replay: note: --train is used only by gp-akf; ignored for {args.estimator}",
              file=sys.stderr)
    if args.estimator == "gp-akf" and train is None:
        raise InputError("--estimator gp-akf needs --train TRAIN.csv (a log with a passive subject "
                         "to learn the residual from)")
    # eq:bounds: tau_h_act_bound = the Theorem-1 ρ_k (gp-akf: GP error constants from the trained LoG-GPs)
    est = make_estimator(args.estimator, cfg, dt=log.dt, train=train if args.estimator == "gp-akf" else None)
    res = replay(log, est, clock=time.perf_counter)
    res.estimator = args.estimator
    try:
        write_columns(args.out, est_columns(res))
    except OSError as e:
        raise InputError(f"--out {args.out}: cannot write: {e.strerror or e}") from None
    extra = {}
    if getattr(est, "gp", None) is not None and train is not None:
        # GP-AKF: what was learned from --train (one LoG-GP per joint)
        extra["train"] = {"log": str(args.train), "pairs": int(est.n_learned),
                          "leaves": [int(g.n_leaves) for g in est.gp.gps]}
    summary = summarize(res, log=str(args.log), config=str(args.config), out=str(args.out), **extra)
    print(json.dumps(summary))
    return 0
