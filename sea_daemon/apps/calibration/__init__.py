"""Calibration: the daemon's calibration phase on the hardware and the calibration of a log.

:func:`calibrate` is the calibration phase that ``sea-daemon calibrate`` runs and other
applications (the loop benchmark, the demo) call: the daemon's controller moves the joint
(passive subject) — the scenario's moves or the calibration excitation over the configured
working range (``excitation``) — the GP-AKF learns the residual online in the fixed-rate loop and
the model file is saved; with ``fit`` the whole calibration of :mod:`.pipeline` runs on the
session's log instead and the model file is the calibrated model (:mod:`.modelio`).

:mod:`.pipeline` — one calibration from a passive log and the nominal model (noise, diagnose's
physics, residual GP, process noise), with its noise identification and diagnose from the
analysis layer (:mod:`sea_daemon.analysis.noise`, :mod:`sea_daemon.analysis.diagnose`);
:mod:`.modelio` — the calibrated model on disk (docs/calibration.md).
"""
from __future__ import annotations

import logging
import math
import shutil
import sys
import time
from pathlib import Path

from tqdm import tqdm

from sea_daemon.apps.calibration.joints import declared_working_ranges
from sea_daemon.apps.calibration.modelio import jsonable, save_calibrated, summary as cal_summary
from sea_daemon.apps.calibration.pipeline import calibrate_log
from sea_daemon.apps.progress import Progress
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.excitation import WorkingRange, excitation, excitation_joints
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import load_yaml
from sea_daemon.io.gpmodel import save_gp_model
from sea_daemon.io.logcsv import read_log
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.notify import Notifier
from sea_daemon.runtime.publish import make_publisher
from sea_daemon.runtime.safety import SafetySupervisor
from sea_daemon.runtime.controller import ScenarioController
from sea_daemon.runtime.rig import make_rig
from sea_daemon.runtime.service import StateFile, serve

log = logging.getLogger("sea_daemon.calibrate")


class _Progress:
    """tqdm bar updated at most 4 times a second, from the loop's end-of-cycle hook."""

    def __init__(self, total: int, enabled: bool, estimator):
        self.est = estimator
        self.bar = None
        if enabled:
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


def calibrate(cfg: ModelConfig, scenario: str | Path, out: str | Path, log_path: Path, *,
              state: StateFile | None = None, cycles: int | None = None, sim: str | None = None,
              device_model: str | None = None, realtime: bool = True, rt_priority: int | None = 80,
              supervisor: SafetySupervisor | None = None, progress: bool = False,
              config_name: str = "<memory>", socket_path: Path | None = None, excitation: bool = False,
              fit: bool = False, config_path: str | Path | None = None,
              cpus: tuple[int, ...] | None = None) -> tuple[int, dict, str]:
    """Run the training phase and save the model to ``out``.

    ``excitation``: the PID tracks the calibration excitation over ``cfg.calibration``'s working
    range (:func:`excitation_reference`) instead of the scenario's moves.  ``fit``: the whole
    calibration (:func:`.pipeline.calibrate_log`, values ``config_path`` gives kept) on the
    session's log; ``out`` is then the calibrated model and ``out`` with ``.yaml`` the complete
    configuration beside it.

    ``state``: the claimed :class:`~sea_daemon.runtime.service.StateFile` the pid file goes to
    (None: none).  Returns ``(exit status, JSON summary, message)``: 0 with the model saved; 1
    when a fault latched, the run was interrupted or the log lost rows (model not saved, the log
    kept).  The estimate is published
    every cycle like in ``run`` (the daemon's TPDOs; the local socket ``socket_path`` when given):
    ``sea-daemon watch`` shows whether the subject stays passive.  ``cpus``: as ``serve``'s (the
    loop's CPU; the calibration's GP learns in the loop, no bound worker).
    """
    sc = load_scenario(scenario)
    if sc.nominal.joints != cfg.joints:
        raise InputError(f"--scenario {scenario}: {sc.nominal.joints} joint(s), the configuration has {cfg.joints}")
    reference = excitation_reference(cfg, sc.controller.q0) if excitation else None
    cycles = cycles or session_cycles(cfg, sc, reference)
    # the training phase (ass:passive_human): learning on in every cycle
    estimator = make_estimator("gp-akf", cfg, dt=cfg.dt, learning=True, bound=False)
    rig = make_rig(cfg, sim=sim, device_model=device_model, phase="training")
    controller = ScenarioController(sc, cfg, rig.hold_torque, delay=rig.hw.actuation_delay, estimation_from=None,
                                    reference=reference)
    bar = _Progress(cycles, progress, estimator)
    publisher = make_publisher(rig, cfg, controller, socket_path=socket_path)
    try:
        res = serve(rig, estimator, controller, cfg.joints, cfg.dt, log_path, cycles=cycles, realtime=realtime,
                    notifier=Notifier(), state=state,
                    progress=bar, rt_priority=rt_priority, supervisor=supervisor, label="calibrate",
                    publisher=publisher, cpus=cpus)
    finally:
        bar.close(cycles)
    st, sup = res.stats, res.supervisor
    summary = {"model": None, "log": str(log_path), "scenario": str(scenario), "config": config_name,
               "hardware": rig.description, "cycles": st.cycles, "gp_points": estimator.gp.n_points,
               "pairs_learned": estimator.n_learned, "overruns": st.overruns,
               "rows_written": res.log["rows_written"], "rows_dropped": res.log["rows_dropped"],
               "rows_lost": res.log["rows_lost"], "log_error": res.log["error"],
               "fault": sup.latched.name, "realtime": res.realtime, "pace": "realtime" if realtime else "lockstep",
               "wall_s": round(res.wall_s, 3)}
    if not sup.ok:
        return 1, summary, f"{sup.status_line()}; model not saved, log kept: {log_path}"
    if st.cycles < cycles:
        return 1, summary, f"interrupted after {st.cycles} of {cycles} cycles; model not saved, log kept: {log_path}"
    if res.log["error"]:
        return 1, summary, (f"log incomplete, {res.log['rows_lost']} rows lost ({res.log['error']}); "
                            f"model not saved")
    if fit:
        return _fit(out, log_path, cfg, config_path, summary, rig.description, st.cycles)
    save_gp_model(out, cfg, estimator.gp, {
        "command": "calibrate", "scenario": str(scenario), "config": config_name, "log": str(log_path),
        "hardware": rig.description, "cycles": st.cycles, "pairs_learned": estimator.n_learned})
    summary["model"] = str(out)
    return 0, summary, ""


def session_cycles(cfg: ModelConfig, sc, reference=None) -> int:
    """The calibration session's cycles at the configuration's rate: the excitation's duration,
    or the scenario's training phase in seconds (its samples at the scenario model's rate), so
    that a session lasts as long at 1 kHz as at 100 Hz."""
    seconds = reference.duration if reference is not None else sc.training_samples * sc.nominal.dt
    return max(1, int(round(seconds * cfg.rate_hz)))


def excitation_reference(cfg: ModelConfig, q0: float):
    """The calibration excitation (:func:`~sea_daemon.core.excitation.excitation`) over the
    configuration's ``calibration`` working range, from ``q0``; without one declared, 10°–90°.
    n joints: :func:`~sea_daemon.core.excitation.excitation_joints` over each joint's range
    (:func:`.joints.declared_working_ranges`), from the n angles ``q0``."""
    c = cfg.calibration
    if cfg.joints > 1:       # each joint over its own range, their combinations (core.excitation.excitation_joints)
        return excitation_joints(declared_working_ranges(cfg), c.duration_s, seed=c.seed, q0=q0)
    lo = math.radians(c.q_min_deg if c.q_min_deg is not None else 10.0)
    hi = math.radians(c.q_max_deg if c.q_max_deg is not None else 90.0)
    return excitation(WorkingRange(lo, hi, c.v_max, c.a_max), c.duration_s, seed=c.seed, q0=float(q0))


def _fit(out, log_path: Path, cfg: ModelConfig, config_path, summary: dict, hardware: str,
         cycles: int) -> tuple[int, dict, str]:
    """The whole calibration on the session's log: ``out`` (model file) and ``out``.yaml."""
    raw = load_yaml(config_path) if config_path is not None else None
    try:
        with Progress("calibrate --fit") as progress:
            result = calibrate_log(read_log(log_path, n=cfg.joints, min_rows=2), cfg, raw, progress=progress)
    except InputError as e:
        # the session's log cannot be calibrated on (analysis.sufficiency): exit 2, the log kept
        summary["refused"] = str(e)
        return 2, summary, f"{e}; model not saved, log kept: {log_path}"
    yaml_path, npz_path = save_calibrated(Path(out).with_suffix(""), result,
                                          {"command": "calibrate --fit", "log": str(log_path),
                                           "hardware": hardware, "cycles": cycles})
    s = cal_summary(result)
    for line in s["text"]:
        log.info(line)
    summary.update({"model": str(npz_path), "config_calibrated": str(yaml_path),
                    "calibration": jsonable({k: v for k, v in s.items() if k != "text"})})
    return 0, summary, ""
