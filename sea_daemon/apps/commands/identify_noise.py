"""``sea-daemon identify-noise LOG.csv --config MODEL.yaml [--write OUT.yaml]``

Autocovariance least squares (Odelson, Rajamani & Rawlings 2006; paper Sec. V-B) on a
measured log: prints the identified measurement noise covariance R of the AKF (and the
process noise Q with ``--with-Q``) as JSON, and can write a copy of the configuration with
the new R (and, as in Sec. V-B, P0's measurement block set to R).  The log is taken at the
configuration's rate (R is per sample at ``rate_hz``): decimated from a whole multiple of it,
refused (exit 2, one line) at another rate or with a sensor column that reports nothing.
"""
from __future__ import annotations

import json
import logging

import numpy as np

from sea_daemon.analysis.als import R_FLOOR, config_with_R, floored_R, identify_noise
from sea_daemon.analysis.sufficiency import at_config_rate, check_columns
from sea_daemon.io.configfile import load_config, save_config
from sea_daemon.core.estimators.akf import AKF
from sea_daemon.core.replay import replay
from sea_daemon.errors import EstimatorFault, InputError
from sea_daemon.io.files import check_outputs
from sea_daemon.io.logcsv import read_log
from sea_daemon.apps.commands import add_log_and_config

logger = logging.getLogger("sea_daemon.identify_noise")

DESCRIPTION = (
    "Run the AKF of --config over LOG.csv, linearise the SEA model at the log's mean operating "
    "point, filter the measurements with a fixed stabilising gain and identify the noise "
    "covariances from the innovations' autocovariances (ALS, Odelson et al. 2006); by default on "
    "the encoder angles, with the velocity entries from the differentiator's noise gain. Prints JSON "
    "with R (diagonal, y = [theta_m, theta_s, dtheta_m, dtheta_s]) and, with --with-Q, Q "
    "(x = [theta_m, theta_s, dtheta_m, dtheta_s, tau_h_act], and dtau_h_act with the integrated "
    "walk). --write OUT.yaml saves the config with the new R (and P0's measurement block = R, as in "
    "the paper). An identified Q is kept only if the AKF with it runs over the same log without an "
    "estimator fault; else the configured Sigma_nom is kept and the reason printed. A log at a whole "
    "multiple of the configuration's rate_hz is decimated to it; one at another rate, or with a sensor "
    "column that reports nothing while the joint moves, is refused (exit 2, one line).")

def add_arguments(p) -> None:
    add_log_and_config(p)
    p.add_argument("--write", metavar="OUT.yaml", default=None, help="write the config with the identified R")
    p.add_argument("--with-Q", dest="with_q", action="store_true",
                   help="also print the identified process noise Q (and write it as Sigma_nom)")
    p.add_argument("--lags", type=int, default=15, help="autocovariance lags (default 15)")
    p.add_argument("--burn-in", dest="burn_in", type=int, default=50,
                   help="leading innovations dropped (filter transient; default 50)")
    p.add_argument("--full", action="store_true", help="full (not diagonal) R and Q, projected to PSD")
    p.add_argument("--channels", choices=("angles", "all"), default="angles",
                   help="angles (default): ALS on the encoder angles (white noise), velocity entries from "
                        "the differentiator's noise gain; all: ALS on all four channels as in the paper "
                        "(differentiated velocities violate its white-noise assumption)")


def run(args) -> int:
    if args.lags < 2:
        raise InputError(f"--lags must be >= 2, got {args.lags}")
    if args.burn_in < 0:
        raise InputError(f"--burn-in must be >= 0, got {args.burn_in}")
    check_outputs([("--write", args.write)], inputs=[args.log, args.config])
    cfg = load_config(args.config)
    log = read_log(args.log, n=cfg.joints, min_rows=2)
    # R is per sample at the configuration's rate (sea_daemon.core.rates scales it for others): a
    # log at a whole multiple of the rate is decimated to it, one at another rate refused
    log, note = at_config_rate(log, cfg)
    if note:
        logger.info(note)
    check_columns(log)
    res = identify_noise(cfg, log, lags=args.lags, burn_in=args.burn_in, diag=not args.full,
                         channels=args.channels)
    n = cfg.joints
    R, enc, floored = floored_R(cfg, res)
    full = args.full or args.channels == "angles"     # the angles mode gives a structured full R
    out = {"log": str(args.log), "config": str(args.config), "samples": len(log),
           "innovations": res["innovations"], "lags": res["lags"], "channels": res["channels"],
           "R": R.tolist() if full else np.diag(R).tolist(),
           "R_diag": np.diag(R).tolist(),
           "encoder_variances": enc,
           "R_config": np.diag(cfg.estimator.R).tolist(),
           "floored": floored, "filter_spectral_radius": round(res["spectral_radius"], 6),
           "operating_point": {"x": res["x_op"].tolist(), "tau_m": res["u_op"].tolist()}}
    Q = np.array(res["Q"])
    keep_q = False
    if args.with_q:
        Q[np.diag_indices(Q.shape[0])] = np.maximum(np.diag(Q), R_FLOOR)
        out["Q"] = np.diag(Q).tolist() if not args.full else Q.tolist()
        rejected = q_rejected(config_with_R(cfg, R, Q), log)
        keep_q = rejected is None
        if not keep_q:
            out["Q_rejected"] = rejected
            logger.warning(f"the identified Q is not kept, Sigma_nom stays as configured: {rejected}")
    if args.write:
        # Sec. V-B: P0's measurement block set to the measurement noise R
        new_cfg = config_with_R(cfg, R, Q if keep_q else None)
        try:
            save_config(new_cfg, args.write,
                        header=f"identify-noise: R{' and Q' if keep_q else ''} identified by ALS "
                               f"from {args.log}")
        except OSError as e:
            raise InputError(f"--write {args.write}: cannot write: {e.strerror or e}") from None
        out["written"] = str(args.write)
    print(json.dumps(out))
    return 0


def q_rejected(cfg, log) -> str | None:
    """Why the AKF of ``cfg`` (the identified R and Q) cannot be used on ``log``, or None.

    ALS identifies Q for the model linearised at the log's mean operating point; away from it
    (gravity, friction) the filter may be far too confident, which its innovation monitor then
    latches.  The same log is the least a written Q must pass."""
    try:
        replay(log, AKF(cfg, dt=log.dt))
    except EstimatorFault as e:
        return f"the AKF with it faults on this log ({e})"
    return None
