"""``python -m benchmarks.sim``: speed of the exoskeleton simulator on the shipped scenarios."""
from __future__ import annotations

import time

from sea_daemon.apps.bench import machine, summarize
from sea_daemon.io.configfile import data_root
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.sim_runner import simulate

NAME = "sim"
HELP = "simulator speed: wall time per scenario and per 10 ms sample (real-time factor)"


def add_arguments(p) -> None:
    p.add_argument("--runs", type=int, default=3, help="runs per scenario (default 3)")


def run(args) -> int:
    print(f"machine: {machine()}")
    for name in ("passive", "active"):
        sc = load_scenario(data_root() / "configs" / "scenarios" / f"{name}.yaml")
        n = sc.training_samples + sc.estimation_samples
        walls, cpus = [], []
        for r in range(max(1, args.runs)):
            t0, c0 = time.perf_counter(), time.process_time()
            simulate(sc, seed=r)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        per = [w / n for w in walls]
        sim_s = n * sc.nominal.dt
        best = min(walls)
        print(f"{name}: {n} samples ({sim_s:.1f} s simulated, substep {sc.plant.substep_hz:g} Hz), "
              f"{len(walls)} runs: wall per run {summarize(walls, 1.0, 's')}; CPU per run {summarize(cpus, 1.0, 's')}; "
              f"wall per sample {summarize(per)}; "
              f"real-time factor (best run) {sim_s / best:.1f}x")
    return 0


if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
