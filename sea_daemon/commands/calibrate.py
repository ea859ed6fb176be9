"""``sea-daemon calibrate --config MODEL.yaml --scenario SCENARIO.yaml --out MODEL.npz --log-dir DIR``

The training phase of the paper (Sec. IV-A, V-B) on the bus: the subject is passive, the
daemon's controller — the scenario's PID position controller tracking its minimum-jerk
trajectory (or its open-loop holding torque), output limited to ``hardware.torque_limit`` —
moves the joint, and the GP-AKF learns the load-side residual online in the fixed-rate loop
(bounded work per cycle: one LoG-GP update and its hyperparameter slice).  Then the model is
saved atomically (versioned, checksummed, no pickle; :mod:`sea_daemon.daemon.gpmodel`) and the
measured log (contracts §1 through the off-loop log writer) is kept as
``DIR/calibration-<UTC time>.csv`` — the input of ``sea-daemon diagnose``; a configuration it
writes (``model_augmented.yaml``) calibrates the same way.  A JSON summary goes to stdout, the
progress bar to stderr.

On the real bus the drives and encoder answer on ``hardware.bus``; ``--device-model`` starts the
simulated ones in this process (virtual bus), or run ``sea-daemon device-model --bus remote``
separately and point ``--bus remote --channel ws://…`` at it.
Exit status: 0 model saved; 2 bad input; 1 fault, interruption (model not saved, log kept)
or internal error.
"""
from __future__ import annotations

import json
import sys
import time

from ..config import repo_root
from . import _daemon_args

NAME = "calibrate"
HELP = "training phase on the bus: PID moves, GP learned online, model file + measured log"
ORDER = 55
DESCRIPTION = __doc__


def add_arguments(p) -> None:
    p.add_argument("--scenario", metavar="SCENARIO.yaml",
                   default=str(repo_root() / "configs" / "scenarios" / "passive.yaml"),
                   help="trajectory and controller gains (default: configs/scenarios/passive.yaml)")
    p.add_argument("--out", metavar="MODEL.npz", required=True, help="model file to write (atomically)")
    _daemon_args.add_common(p, cycles_help="training cycles (default: the scenario's training samples)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


class _Progress:
    """tqdm bar updated at most 4 times a second, from the loop's end-of-cycle hook."""

    def __init__(self, total: int, enabled: bool, estimator):
        self.est = estimator
        self.bar = None
        if enabled:
            from tqdm import tqdm
            import shutil
            # a terminal that reports a size of 0 x 0 would hide the bar (tqdm): fall back to 100 x 20
            size = shutil.get_terminal_size((100, 20))
            self.bar = tqdm(total=total, unit="cycle", desc="calibrate", file=sys.stderr, mininterval=0.25,
                            ncols=size.columns or 100, nrows=size.lines or 20)
        self._next = 0.0
        self._done = 0

    def __call__(self, k: int, est) -> None:
        if self.bar is None:
            return
        now = time.monotonic()
        if now >= self._next:
            self._next = now + 0.25
            self.bar.update(k + 1 - self._done)
            self._done = k + 1
            self.bar.set_postfix_str(f"GP points {self.est.gp.n_points}", refresh=False)

    def close(self, k: int) -> None:
        if self.bar is not None:
            self.bar.update(max(0, k - self._done))
            self.bar.close()


def run(args) -> int:
    from ..daemon.gpmodel import save_gp_model
    from ..daemon.notify import Notifier
    from ..daemon.service import ScenarioController, StateFile, make_rig, serve
    from ..errors import InputError
    from ..estimators.gpakf import GPAKF
    from ..sim.scenario import load_scenario

    cfg, log_dir, state_dir, realtime = _daemon_args.load(args)
    sc = load_scenario(args.scenario)
    if sc.nominal.joints != cfg.joints:
        raise InputError(f"--scenario {args.scenario}: {sc.nominal.joints} joint(s), the configuration has {cfg.joints}")
    cycles = args.cycles or sc.training_samples
    # the training phase (ass:passive_human): learning on in every cycle
    estimator = GPAKF(cfg, dt=cfg.dt, learning=True)
    rig = make_rig(cfg, sim=args.sim, device_model=args.device_model, phase="training")
    controller = ScenarioController(sc, cfg, "training", rig.hold_torque, delay=getattr(rig.hw, "actuation_delay", 0))
    log_path = _daemon_args.log_name(log_dir, "calibration")
    progress = _Progress(cycles, not args.no_progress and sys.stderr.isatty() or False, estimator)
    try:
        res = serve(rig, estimator, controller, cfg.joints, cfg.dt, log_path, cycles=cycles, realtime=realtime,
                    notifier=Notifier(), state=StateFile(state_dir), progress=progress,
                    rt_priority=args.rt_priority, supervisor=_daemon_args.supervisor(args), label="calibrate")
    finally:
        progress.close(cycles)
    st, sup = res.stats, res.supervisor
    summary = {"model": None, "log": str(log_path), "scenario": str(args.scenario), "config": str(args.config),
               "hardware": rig.description, "cycles": st.cycles, "gp_points": estimator.gp.n_points,
               "pairs_learned": estimator.n_learned, "overruns": st.overruns,
               "rows_written": res.log["rows_written"], "rows_dropped": res.log["rows_dropped"],
               "fault": sup.latched.name, "realtime": res.realtime, "pace": "realtime" if realtime else "lockstep",
               "wall_s": round(res.wall_s, 3)}
    if not sup.ok:
        print(json.dumps(summary))
        print(f"sea-daemon calibrate: {sup.status_line()}; model not saved, log kept: {log_path}", file=sys.stderr)
        return 1
    if st.cycles < cycles:
        print(json.dumps(summary))
        print(f"sea-daemon calibrate: interrupted after {st.cycles} of {cycles} cycles; model not saved, "
              f"log kept: {log_path}", file=sys.stderr)
        return 1
    save_gp_model(args.out, cfg, estimator.gp, {
        "command": "calibrate", "scenario": str(args.scenario), "config": str(args.config), "log": str(log_path),
        "hardware": rig.description, "cycles": st.cycles, "pairs_learned": estimator.n_learned})
    summary["model"] = str(args.out)
    print(json.dumps(summary))
    return 0
