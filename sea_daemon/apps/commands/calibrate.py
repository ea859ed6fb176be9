"""``sea-daemon calibrate --config MODEL.yaml --scenario SCENARIO.yaml --out MODEL.npz --log-dir DIR``

The training phase of the paper (Sec. IV-A, V-B) on the bus: the subject is passive, the
daemon's controller — the scenario's PID position controller tracking its minimum-jerk
trajectory (or its open-loop holding torque), output limited to ``hardware.torque_limit`` —
moves the joint, and the GP-AKF learns the load-side residual online in the fixed-rate loop
(bounded work per cycle: one LoG-GP update and its hyperparameter slice).  Then the model is
saved atomically (versioned, checksummed, no pickle; :mod:`sea_daemon.io.gpmodel`) and the
measured log (docs/interfaces.md §1 through the off-loop log writer) is kept as
``DIR/calibration-<UTC time>.csv`` — the input of ``sea-daemon diagnose`` and ``sea-daemon fit``; a
configuration it writes (``model_augmented.yaml``) calibrates the same way.

``--excitation`` drives the calibration excitation over the configuration's working range
(``calibration`` section: moves spread over angles, speeds and accelerations) instead of the
scenario's moves; ``--fit`` runs the whole calibration on the session's log (docs/calibration.md:
noise, diagnose's physics, residual GP, process noise) and writes the calibrated model to
MODEL.npz and the complete configuration to MODEL.yaml beside it; a log that cannot be
calibrated on is exit 2 with the line saying what to record instead (the log kept).  The session
lasts the scenario's training phase or the excitation's ``calibration.duration_s`` in seconds at
any ``--rate``; ``--duration SECONDS`` or ``--cycles`` set it.  Without ``--scenario`` the embedded
passive scenario of the configuration's joint count is used (``passive.yaml`` for one joint,
``two_joint_passive.yaml`` for two).  A JSON summary goes to stdout, the progress bar to stderr.

On the real bus the drives and encoder answer on ``hardware.bus``; ``--device-model`` starts the
simulated ones in this process (virtual bus), or run ``sea-daemon device-model --bus ipc
--channel NAME`` separately and point ``--bus ipc --channel NAME`` at it (docs/can.md).
Exit status: 0 model saved; 2 bad input or a log the calibration refuses; 1 fault, interruption (model not saved, log kept)
or internal error.
"""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from sea_daemon.apps.calibration import calibrate
from sea_daemon.apps.calibration.modelio import jsonable
from sea_daemon.apps.commands import daemon_args
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import data_root
from sea_daemon.runtime.service import StateFile

DESCRIPTION = __doc__
log = logging.getLogger("sea_daemon.calibrate")


def add_arguments(p) -> None:
    p.add_argument("--scenario", metavar="SCENARIO.yaml", default=None,
                   help="trajectory and controller gains (default: configs/scenarios/passive.yaml for one joint, "
                        "two_joint_passive.yaml for two)")
    p.add_argument("--out", metavar="MODEL.npz", required=True, help="model file to write (atomically)")
    daemon_args.add_common(p, cycles_help="training cycles (default: the scenario's training phase, or the excitation's "
                                          "calibration.duration_s, in seconds at the configured rate)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--excitation", action="store_true",
                   help="drive the calibration excitation over the configuration's calibration section "
                        "(working range, speeds) instead of the scenario's moves")
    p.add_argument("--fit", action="store_true",
                   help="then the whole calibration on the session's log (as sea-daemon fit): MODEL.npz is the "
                        "calibrated model and MODEL.yaml beside it the complete configuration")


#: the passive training scenario of a configuration of n joints when no --scenario is given
DEFAULT_SCENARIOS = {1: "passive.yaml", 2: "two_joint_passive.yaml"}


def default_scenario(joints: int) -> str:
    """The embedded passive scenario for ``joints`` joints, or an InputError asking for one."""
    if joints not in DEFAULT_SCENARIOS:
        raise InputError(f"--scenario: none given and none embedded for {joints} joints (embedded: 1 joint "
                         "configs/scenarios/passive.yaml, 2 joints two_joint_passive.yaml); give a scenario of "
                         f"{joints} joints (docs/simulator.md)")
    return str(data_root() / "configs" / "scenarios" / DEFAULT_SCENARIOS[joints])


def run(args) -> int:
    outs = [("--out", args.out)] + ([("--out", Path(args.out).with_suffix(".yaml"))] if args.fit else [])
    cfg, log_dir, state_dir, realtime = daemon_args.load(args, outputs=outs)
    scenario = args.scenario or default_scenario(cfg.joints)
    # one instance per state directory and bus, before the drives are touched
    with StateFile(state_dir).claim(daemon_args.bus_key(args, cfg)) as state:
        code, summary, message = calibrate(
            cfg, scenario, args.out, daemon_args.log_name(log_dir, "calibration"), state=state,
            cycles=args.cycles, sim=args.sim, device_model=args.device_model, realtime=realtime,
            rt_priority=args.rt_priority, cpus=args.cpus, supervisor=daemon_args.supervisor(args),
            progress=not args.no_progress and sys.stderr.isatty() and log.isEnabledFor(logging.INFO),
            config_name=str(args.config),
            socket_path=daemon_args.socket_path(args, state_dir), excitation=args.excitation, fit=args.fit,
            config_path=args.config)
    print(json.dumps(jsonable(summary), allow_nan=False))
    if code:
        log.error(message)
    return code
