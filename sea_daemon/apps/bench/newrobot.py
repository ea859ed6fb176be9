"""``sea-daemon bench newrobot``: one plant, calibrated once, estimated on sessions unlike it.

A new robot's table, run as a user would: a plant written down in a directory of scenario
files (``configs/scenarios/newrobot/``: ``robot.yaml`` the nominal robot model and its
``calibration`` section, the scenarios sharing one hidden plant, ``table.yaml`` naming the
calibration scenario and the estimation sessions)::

    calibration: calibration.yaml      # its training phase is the calibration log
    sessions:
      - {name: faster17, scenario: faster17.yaml}
      - {name: same, scenario: calibration.yaml, seed: 51}   # optional seed: another noise draw

Each scenario is simulated by :func:`sea_daemon.runtime.sim_runner.simulate` (the scenario
simulator of ``sea-daemon simulate``); a session is the estimation phase of its scenario.  The
calibration is :func:`sea_daemon.apps.calibration.pipeline.calibrate_log` on the calibration log
with ``robot.yaml`` — what ``sea-daemon replay LOG --train CAL.csv --config robot.yaml
--estimator gp-akf`` runs: the nominal robot model and the log are its only inputs.  Per session
(:func:`.generalize.run_sessions`): the GP-AKF on the calibrated model, the AKF on the nominal
robot, the AKF on the augmented model (diagnose's effects), the oracle AKF (the true plant),
RMSE of τ̂_h,act against the truth; the targets: passive ≤ 0.05 N m, active ≤ 0.1.

``--calibration excitation`` calibrates instead on the calibration excitation over
``robot.yaml``'s ``calibration`` section (what ``sea-daemon calibrate --excitation`` drives), on
the same plant with the calibration scenario's PID gains and seed.

The logs are written to ``OUT/logs/*.csv`` (docs/interfaces.md §1, with ``tau_h_act``), so each
row can be re-run with ``sea-daemon replay``; the figures go to ``OUT/results.json``.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from sea_daemon.apps.bench import add_choice_argument, choose, machine
from sea_daemon.apps.bench.generalize import ESTIMATORS, calibration_row, run_sessions
from sea_daemon.apps.calibration import excitation_reference
from sea_daemon.apps.calibration.pipeline import calibrate_log
from sea_daemon.core.sim.session import run_session
from sea_daemon.core.validate import check_keys
from sea_daemon.errors import ConfigError
from sea_daemon.io.configfile import data_root, load_yaml
from sea_daemon.io.files import atomic_write_text, check_output_dir
from sea_daemon.io.logcsv import write_log
from sea_daemon.io.scenario import PIDSpec, load_scenario
from sea_daemon.runtime.sim_runner import simulate

DESCRIPTION = __doc__
#: the targets [N m]: passive sessions (τ_h,act = 0) and active subjects
TARGET = {"passive": 0.05, "active": 0.1}


def add_arguments(p) -> None:
    p.add_argument("--plant", default=str(data_root() / "configs" / "scenarios" / "newrobot"),
                   help="directory with table.yaml, the nominal robot and the scenarios "
                        "(default configs/scenarios/newrobot)")
    p.add_argument("--out", default="bench_newrobot", help="directory for results.json and logs/ (default bench_newrobot)")
    add_choice_argument(p, "--estimators", ESTIMATORS)
    p.add_argument("--bound", action="store_true", help="also the Theorem-1 bound of the GP-AKF (guaranteed beta)")
    p.add_argument("--calibration", choices=("scenario", "excitation"), default="scenario",
                   help="the calibration log: the calibration scenario's training phase (default), or the "
                        "calibration excitation over robot.yaml's calibration section (what calibrate "
                        "--excitation drives) on the same plant")
    p.add_argument("--gp", choices=("auto", "on", "off"), default="auto",
                   help="the residual GP: kept when cross-validation shows it helps (auto, default: what replay "
                        "--train does), always (on), never (off); as sea-daemon fit --gp")


@dataclass(frozen=True)
class Session:
    name: str
    scenario: object          # io.scenario.Scenario
    seed: int | None


def load_table(plant_dir: Path):
    """(calibration scenario, [Session]) of ``plant_dir/table.yaml``; every scenario must have
    the same nominal robot and the same hidden plant (one plant, several sessions)."""
    src = plant_dir / "table.yaml"
    if not src.is_file():
        raise ConfigError(str(src), "<file>", "table file not found (--plant names a directory with table.yaml)")
    d = load_yaml(src)
    check_keys(str(src), "", d, ["calibration", "sessions"], ["calibration", "sessions"])
    if not isinstance(d["sessions"], list) or not d["sessions"]:
        raise ConfigError(str(src), "sessions", "must be a non-empty list of {name, scenario[, seed]}")
    cal = load_scenario(plant_dir / str(d["calibration"]))
    if cal.human != "passive":
        raise ConfigError(str(src), "calibration", f"the calibration session must be passive, {cal.source} has "
                                                   f"human: {cal.human}")
    out, names = [], set()
    for i, s in enumerate(d["sessions"]):
        check_keys(str(src), f"sessions[{i}].", s, ["name", "scenario", "seed"], ["name", "scenario"])
        name = str(s["name"])
        if name in names:
            raise ConfigError(str(src), f"sessions[{i}].name", f"{name!r} named twice")
        names.add(name)
        seed = s.get("seed")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise ConfigError(str(src), f"sessions[{i}].seed", f"must be an integer >= 0, got {seed!r}")
        sc = load_scenario(plant_dir / str(s["scenario"]))
        if sc.model_path.resolve() != cal.model_path.resolve() or sc.plant != cal.plant:
            raise ConfigError(sc.source, "plant", f"not the plant of {cal.source} (the same model file and the "
                                                  "same hidden effects in every scenario of the table)")
        out.append(Session(name, sc, seed))
    return cal, out


def excitation_log(sc):
    """The calibration excitation (:func:`sea_daemon.apps.calibration.excitation_reference`: the
    moves ``calibrate --excitation`` drives over the configuration's working range) on the
    scenario's true plant, tracked by the scenario's PID gains, its noise seed."""
    ctl = sc.controller
    if not isinstance(ctl, PIDSpec):
        raise ConfigError(sc.source, "controller.type", "--calibration excitation tracks the moves with the "
                                                        "scenario's PID: needs controller.type pid")
    ref = excitation_reference(sc.nominal, ctl.q0)
    # the scenario's controller is its PID gains (PIDSpec is a PIDGains) and a trajectory
    return run_session(sc.true_config(), ref.duration, reference=ref, seed=sc.seed, gains=ctl,
                       substep_hz=sc.plant.substep_hz, sign_eps=sc.plant.sign_eps, torque_noise=sc.plant.torque_noise)


def run(args) -> int:
    est = choose(args.estimators, ESTIMATORS, "--estimators")
    plant_dir = Path(args.plant)
    cal_sc, sessions = load_table(plant_dir)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    out = check_output_dir("--out", args.out)
    (out / "logs").mkdir(exist_ok=True)
    print(f"bench newrobot: plant {plant_dir} (nominal robot {cal_sc.model_path.name}, {len(sessions)} sessions), "
          f"estimators {', '.join(est)}; {machine()}", flush=True)
    t0 = time.perf_counter()
    if args.calibration == "excitation":
        cal = excitation_log(cal_sc)
        cal_what = f"the calibration excitation over {cal_sc.model_path.name}'s calibration section"
    else:
        cal = simulate(cal_sc).training
        cal_what = cal_sc.description
    write_log(out / "logs" / "calibration.csv", cal)
    tests, kinds = {}, {}
    for s in sessions:
        tests[s.name] = simulate(s.scenario, seed=s.seed).estimation
        kinds[s.name] = "passive" if s.scenario.human == "passive" else "active"
        write_log(out / "logs" / f"{s.name}.csv", tests[s.name])
    print(f"simulated: calibration {len(cal)} samples ({cal_what}), sessions "
          f"{', '.join(f'{k} {len(v)}' for k, v in tests.items())} ({time.perf_counter() - t0:.0f} s)", flush=True)
    print(f"calibrating on the calibration log (the nominal robot model and the log only; --gp {args.gp}) ...",
          flush=True)
    t0 = time.perf_counter()
    res = calibrate_log(cal, cal_sc.nominal, load_yaml(cal_sc.model_path), gp=args.gp)
    cal_s = time.perf_counter() - t0
    crow = calibration_row(res.report)
    print(f"calibrated in {cal_s:.0f} s: effects {', '.join(crow['effects']) or 'none'}; GP "
          f"{'kept' if crow['gp_kept'] else 'not kept'}; q_tau {crow['q_tau']:.3g}", flush=True)

    def show(name, r):
        cells = "  ".join(f"{k} " + (f"{v['rmse']:.3f}" if "rmse" in v else ("FAULT" if "fault" in v else "ERROR"))
                          for k, v in r.items())
        print(f"  {name:10s} {cells}", flush=True)
    rows = run_sessions(res, cal_sc.nominal, cal_sc.true_config(), tests, est, do_bound=args.bound, on_session=show)
    table = []
    for s in sessions:
        r = rows[s.name]
        g = r.get("gp-akf", {})
        target = TARGET[kinds[s.name]]
        table.append({"session": s.name, "description": s.scenario.description, "kind": kinds[s.name],
                      "target": target, "met": ("rmse" in g and g["rmse"] <= target) if "gp-akf" in r else None,
                      **{k: r[k].get("rmse") for k in est}})
    _print_table(table, est, plant_dir, cal_what)
    result = {"plant": str(plant_dir), "gp": args.gp, "calibration_log": cal_what, "machine": machine(), "calibration_s": cal_s, "calibration": crow,
              "table": table, "sessions": rows}
    atomic_write_text(out / "results.json", json.dumps(result, indent=1, default=float))
    print(f"results: {out / 'results.json'}, logs: {out / 'logs'}  (load average {os.getloadavg()[0]:.2f})")
    return 0


def _print_table(table, est, plant_dir, cal_what) -> None:
    print(f"\nRMSE of tau_h_act_hat [N m], {plant_dir}, calibrated once on: {cal_what}")
    w = max(len(r["description"]) for r in table)
    print(f"| {'session':{w}s} | " + " | ".join(f"{k:9s}" for k in est) + " | target | met |")
    for r in table:
        cells = " | ".join(f"{r[k]:9.3f}" if r[k] is not None else f"{'fault':9s}" for k in est)
        met = "-" if r["met"] is None else ("yes" if r["met"] else "NO")
        print(f"| {r['description']:{w}s} | {cells} | {r['target']:6.2f} | {met:3s} |")
