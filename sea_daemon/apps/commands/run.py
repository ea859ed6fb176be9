"""``sea-daemon run --config MODEL.yaml --model MODEL.npz --log-dir DIR``: the estimation service.

The GP-AKF with the residual learned by ``sea-daemon calibrate`` (learning frozen) runs in the
fixed-rate loop (:mod:`sea_daemon.runtime.loop`) on the CAN bus of the configuration: read →
control → write → estimate → log → sleep to the next absolute deadline.  systemd
(``systemd/sea-daemon.service``, Type=notify) gets READY=1 after start-up, WATCHDOG=1 from the
loop in every healthy cycle and STATUS= once a second; SIGTERM/SIGINT stop cleanly (log
drained and closed, STOPPING=1), SIGUSR1 (``sea-daemon reset``) clears a latched fault.
The measured log (docs/interfaces.md §1 plus estimate, bound, validity and loop timing columns) goes to
``DIR/run-<UTC time>.csv`` through the off-loop log writer; a JSON summary is printed on exit.

Every cycle, right after the estimate, the daemon publishes it: the TPDOs of its own CAN node
(``hardware.bus.master_node``; docs/can.md) and datagrams on ``STATE_DIR/sea-daemon.sock``
(``--socket``) for ``sea-daemon watch`` and :mod:`sea_daemon.client`.  With ``--lsl`` (or
``publish.lsl``) the log writer also streams every row as a Lab Streaming Layer outlet, with
``--mcap`` (or ``publish.mcap``) it records them in ``DIR/run-<UTC time>.mcap`` beside the CSV
(docs/interfaces.md §7; ``pip install sea-daemon[lsl]`` / ``[mcap]``).

The controller: with ``assist.enabled`` in the model YAML the assist-as-needed controller
(docs/assist.md) — the exoskeleton's compensation plus assistance from the estimate, gated by
its bound, with the innovation check of every filter step; for a ``human: track`` scenario
without it the same controller with no assistance (the exoskeleton only compensates itself);
otherwise the scenario's controller, or zero torque (estimation only).

Exit status: 0 stopped cleanly; 2 bad configuration, model file or arguments (a log
directory that cannot be written, another instance on the bus or state directory); 1 hardware
start-up failure, internal error, a fault still latched when the service stopped, rows of
the measured log lost (``rows_lost`` in the summary; the LOG_FAILED fault while it runs), or an
output asked for by ``--lsl`` / ``--mcap`` that failed (``outputs`` in the summary).
"""
from __future__ import annotations

import json
import logging

from sea_daemon.apps.calibration.modelio import estimator_from_model
from sea_daemon.apps.commands import daemon_args
from sea_daemon.core.assist import InnovationGuard
from sea_daemon.core.bounds.akf_bound import theorem_bound
from sea_daemon.core.estimators import make_estimator
from sea_daemon.io.gpmodel import load_gp_model
from sea_daemon.io.scenario import load_scenario
from sea_daemon.errors import InputError
from sea_daemon.runtime.controller import AssistController, ScenarioController, ZeroTorque, describe_assist
from sea_daemon.runtime.notify import Notifier
from sea_daemon.runtime.publish import make_publisher
from sea_daemon.runtime.rig import make_rig
from sea_daemon.runtime.service import StateFile, serve
from sea_daemon.runtime.sinks import LslSpec, McapSpec, require

DESCRIPTION = __doc__
log = logging.getLogger("sea_daemon.run")


def add_arguments(p) -> None:
    p.add_argument("--model", metavar="MODEL.npz", required=True, help="model file written by sea-daemon calibrate")
    daemon_args.add_common(p, cycles_help="stop after this many cycles (default: run until SIGTERM)")
    p.add_argument("--scenario", metavar="SCENARIO.yaml", default=None,
                   help="run this scenario's controller (estimation phase); default: the --device-model / "
                        "--sim scenario's, zero torque otherwise (estimation only)")
    p.add_argument("--lsl", action="store_true", default=None,
                   help="stream the estimate as a Lab Streaming Layer outlet (publish.lsl; pip install sea-daemon[lsl])")
    p.add_argument("--assist-dry-run", action="store_true",
                   help="with assist.enabled: compute, log and publish the assistance without commanding it "
                        "(assist.dry_run; the motor torque is the compensation alone)")
    p.add_argument("--mcap", action="store_true", default=None,
                   help="record the run in DIR/run-<UTC time>.mcap beside the CSV log (publish.mcap; "
                        "pip install sea-daemon[mcap])")


def run(args) -> int:
    cfg, log_dir, state_dir, realtime = daemon_args.load(args)
    if args.assist_dry_run and not cfg.assist.enabled:
        raise InputError(f"--assist-dry-run: {args.config} has assist.enabled: false; set it true to compute the "
                         "assistance")
    for output in ("lsl", "mcap"):
        if getattr(args, output) or getattr(cfg.publish, output):
            require(output)                                    # exit 2: pip install sea-daemon[...]
    # one instance per state directory and bus, before the drives are touched
    with StateFile(state_dir).claim(daemon_args.bus_key(args, cfg)) as state:
        return _run(args, cfg, log_dir, state_dir, state, realtime)


def run_estimator(cfg, model_path):
    """The estimator ``run`` runs for ``cfg`` and the model file ``model_path``: a calibrated model
    (sea-daemon fit, calibrate --fit) gives the GP-AKF on the augmented model with the
    variance-weighted residual (the AKF when the calibration kept no GP), any other the GP-AKF
    with the file's residual, learning off; with ``assist.enabled`` behind the innovation check."""
    residual, meta = load_gp_model(model_path, cfg)             # ModelFileError → exit 2, one line
    # the Theorem-1 bound ρ_k is what the log's tau_h_act_bound publishes (docs/bounds.md);
    # its GP constants (estimator.gp_beta) are those of the loaded model, computed at the first reset
    estimator = estimator_from_model(cfg, residual, meta, dt=cfg.dt, bound=theorem_bound)
    if estimator is None:
        estimator = make_estimator("gp-akf", cfg, dt=cfg.dt, residual=residual, learning=False)
    if cfg.assist.enabled:
        # a filter step whose innovation is an outlier is a fault: zero torque in that cycle
        estimator = InnovationGuard(estimator, cfg.assist.innovation_max)
    return estimator


def _run(args, cfg, log_dir, state_dir, state, realtime) -> int:
    estimator = run_estimator(cfg, args.model)
    rig = make_rig(cfg, sim=args.sim, device_model=args.device_model, phase="estimation")
    scen = args.scenario or args.device_model or args.sim
    sc = load_scenario(scen) if scen else None
    # the simulated tracking subject's torque, for the summary's effort figures
    subject = getattr(rig.tau_h_act, "tau", None)
    if cfg.assist.enabled:
        controller = AssistController(cfg, dry_run=True if args.assist_dry_run else None, subject=subject)
        kind = "assist-dry-run" if controller.dry_run else "assist"
    elif sc is not None and sc.human == "track":
        controller, kind = AssistController(cfg, gain=0.0, subject=subject), "transparent"
    elif sc is not None:
        controller, kind = ScenarioController(sc, cfg, rig.hold_torque, delay=rig.hw.actuation_delay,
                                              estimation_from=0), "scenario"
    else:
        controller, kind = ZeroTorque(cfg.joints), "zero"
    log_path = daemon_args.log_name(log_dir, "run")
    publisher = make_publisher(rig, cfg, controller, socket_path=daemon_args.socket_path(args, state_dir))
    sinks = _sinks(args, cfg, log_path)
    res = serve(rig, estimator, controller, cfg.joints, cfg.dt, log_path, cycles=args.cycles, realtime=realtime,
                notifier=Notifier(), state=state, rt_priority=args.rt_priority, cpus=args.cpus,
                supervisor=daemon_args.supervisor(args), label="run", publisher=publisher,
                bound_in=cfg.estimator.bound_in, bound_max_age=cfg.estimator.bound_max_age,
                sinks=sinks, sinks_wait=cfg.publish.lsl_wait_s)
    st, sup = res.stats, res.supervisor
    summary = {"log": str(log_path), "model": str(args.model), "hardware": rig.description,
               "cycles": st.cycles, "overruns": st.overruns, "skipped": st.skipped,
               "max_late_ms": round(st.max_late_s * 1e3, 3), "rows_written": res.log["rows_written"],
               "rows_dropped": res.log["rows_dropped"], "rows_lost": res.log["rows_lost"],
               "log_error": res.log["error"], "log_files": res.log["files"],
               "fault": sup.latched.name, "faults_latched": st.faults, "realtime": res.realtime,
               "pace": "realtime" if realtime else "lockstep", "wall_s": round(res.wall_s, 3),
               "stopped_by_signal": res.stopped_by_signal, "controller": kind,
               "publish": res.extra.get("publish"), "bound": res.extra.get("bound"),
               "outputs": res.log.get("sinks", [])}
    if isinstance(controller, AssistController):
        summary["assist"] = controller.summary(st.cycles)
        log.info(describe_assist(summary["assist"]))
    print(json.dumps(summary))
    if not sup.ok:
        log.error(sup.status_line())
        return 1
    if res.log["error"]:
        log.error("log incomplete, %s rows lost: %s", res.log["rows_lost"], res.log["error"])
        return 1
    failed = [out for out in res.log.get("sinks", []) if out["error"]]
    for out in failed:
        log.error("the %s output failed: %s (the CSV log is complete)", out["output"], out["error"])
    return 1 if failed else 0


def _sinks(args, cfg, log_path) -> tuple:
    """The log writer's other outputs asked for by ``--lsl`` / ``--mcap`` or the ``publish`` section."""
    p, out = cfg.publish, []
    if args.lsl or p.lsl:
        out.append(LslSpec(p.lsl_name, cfg.joints, cfg.rate_hz, p.lsl_wait_s))
    if args.mcap or p.mcap:
        out.append(McapSpec(str(log_path.with_suffix(".mcap")), cfg.joints, cfg.rate_hz, str(log_path)))
    return tuple(out)
