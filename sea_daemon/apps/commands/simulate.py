"""``sea-daemon simulate SCENARIO.yaml --out LOG.csv``: offline physics simulation to measured logs."""
from __future__ import annotations

from pathlib import Path

from sea_daemon.errors import InputError
from sea_daemon.io.files import check_outputs
from sea_daemon.io.logcsv import write_log
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.sim_runner import simulate

DESCRIPTION = (
    "Simulate the exoskeleton with a human forearm (true plant = nominal model + hidden effects) "
    "for a scenario YAML (configs/scenarios/*.yaml).  Writes the estimation phase to --out and the "
    "training phase (passive subject) to --train-out, both as measured logs (docs/interfaces.md §1) with the "
    "ground-truth column tau_h_act and debug columns (q_ref, tau_des, q_true, theta_m_true, dq_true, "
    "dtheta_m_true, tau_s_true, tau_m_applied) that readers ignore.")


def add_arguments(p) -> None:
    p.add_argument("scenario", metavar="SCENARIO.yaml", help="scenario file, e.g. configs/scenarios/passive.yaml")
    p.add_argument("--out", required=True, metavar="LOG.csv", help="estimation-phase log to write")
    p.add_argument("--train-out", metavar="TRAIN.csv",
                   help="training-phase log to write (default: LOG path with .train.csv, e.g. p.csv -> p.train.csv)")
    p.add_argument("--seed", type=int, default=None, help="seed of the torque noise (default: the scenario's)")


def train_path_for(out: Path) -> Path:
    """p.csv -> p.train.csv (any other suffix: append .train.csv)."""
    if out.suffix.lower() == ".csv":
        return out.with_suffix(".train.csv")
    return out.with_name(out.name + ".train.csv")


def run(args) -> int:

    sc = load_scenario(args.scenario)
    if args.seed is not None and args.seed < 0:
        raise InputError(f"--seed: must be an integer >= 0, got {args.seed}")
    out = Path(args.out)
    train_out = Path(args.train_out) if args.train_out else train_path_for(out)
    check_outputs([("--out", out), ("--train-out", train_out)], inputs=[args.scenario, sc.model_path])
    res = simulate(sc, seed=args.seed)
    write_log(out, res.estimation)
    write_log(train_out, res.training)
    print(f"estimation log: {out} ({len(res.estimation)} samples)")
    print(f"training log:   {train_out} ({len(res.training)} samples)")
    return 0
