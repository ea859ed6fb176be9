"""``sea-daemon fit CAL.csv --config MODEL.yaml --out PREFIX``: the whole calibration offline.

From one passive calibration log (the subject relaxed, e.g. what ``sea-daemon calibrate`` keeps)
and the model configuration (the nominal robot; any value it gives is kept): measurement noise,
the physical effects ``diagnose`` finds, the motor-torque noise, the residual GP on what the
physics leaves, the active-torque random walk for the declared human torque
(``calibration.human_band_hz``, ``human_torque_rms``), the coverage of (q, q̇, q̈)
(docs/calibration.md).  Writes ``PREFIX.yaml`` (the complete configuration), ``PREFIX.npz``
(the model file for ``run --model`` / ``replay --model``) and ``PREFIX.report.json``; prints
what was identified and the expected accuracy in plain words (stderr) and a JSON summary
(stdout); while it works (a few minutes), its step on stderr (``-q``: none).

First, what the log can identify (:mod:`sea_daemon.analysis.sufficiency`): a log recorded at a
whole multiple of the configuration's rate is decimated to it; a log that cannot be calibrated on
(too short, moving one way only, swapped columns, constant angles, a sensor column of zeros, at the
torque limit, another rate) is exit 2 with one line saying what to record instead; from a still arm the physical
effects are not identified (the configured model kept, and the report says so).  Exit 2 on bad
input.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

from sea_daemon.apps.calibration.modelio import jsonable, save_calibrated, summary
from sea_daemon.apps.calibration.pipeline import calibrate_from_files
from sea_daemon.apps.commands import add_log_and_config
from sea_daemon.apps.progress import Progress
from sea_daemon.io.files import atomic_write_text, check_outputs

DESCRIPTION = __doc__
log = logging.getLogger("sea_daemon.fit")


def add_arguments(p) -> None:
    add_log_and_config(p, log_help="passive calibration log")
    p.add_argument("--out", metavar="PREFIX", required=True, help="writes PREFIX.yaml, PREFIX.npz, PREFIX.report.json")
    p.add_argument("--gp", choices=("auto", "on", "off"), default="auto",
                   help="residual GP: auto (kept if it predicts the leftover on held-out parts of the log), on, off")


def outputs(prefix) -> list[tuple[str, Path]]:
    """The files ``fit --out PREFIX`` writes."""
    p = Path(prefix)
    return [("--out", p.with_suffix(".yaml")), ("--out", p.with_suffix(".npz")),
            ("--out", Path(str(p) + ".report.json"))]


def run(args) -> int:
    outs = outputs(args.out)
    check_outputs(outs, inputs=[args.log, args.config])
    with Progress("fit") as progress:
        result = calibrate_from_files(args.log, args.config, args.gp, progress=progress)
    yaml_path, npz_path = save_calibrated(args.out, result, {"command": "fit", "log": str(args.log),
                                                             "config": str(args.config)})
    rep_path = outs[2][1]
    atomic_write_text(rep_path, json.dumps(jsonable(result.report), indent=1, allow_nan=False))
    s = summary(result)
    for line in s["text"]:
        log.info(line)
    print(json.dumps(jsonable({"config": str(yaml_path), "model": str(npz_path), "report": str(rep_path), **s}),
                     allow_nan=False))
    return 0
