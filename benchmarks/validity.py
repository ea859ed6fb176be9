"""``python -m benchmarks.validity``: the start-up gate — samples until ``valid`` and the bound when valid.

For each scenario (simulated training and estimation logs) and each configuration, the GP-AKF
(trained on the training log, frozen, Theorem-1 bound) is reset at several samples of the
estimation log — at its start and mid-run, where the subject may push (the active scenario:
τ_h,act = −4 N m at samples 500 and 1500) — and run to the end.  Printed per reset: the
sample (counted from the reset, which is sample 0) at which ``Estimate.valid`` first becomes
1, how many of the invalid samples were outside the bound (what the gate hides), and over the
valid samples the share outside the bound and the largest |error| / bound.
"""
from __future__ import annotations

import argparse

import numpy as np

from sea_daemon.core.estimators import make_estimator
from sea_daemon.io.configfile import load_config, data_root
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.sim_runner import simulate

SCENARIOS = ("passive", "active", "unseen_load", "unseen_range")
CONFIGS = ("exo_1dof.yaml", "exo_1dof_sim.yaml")


def gate_run(est, log, start: int) -> dict:
    e = est.reset(log.q[start], log.theta_m[start], log.tau_m[start])
    valid, outside, ratio = [e.valid], [], []
    for k in range(start + 1, len(log)):
        e = est.update(log.q[k], log.theta_m[k], log.tau_m[k], log.t[k] - log.t[k - 1])
        err = np.abs(e.tau_h_act_hat - log.tau_h_act[k])
        valid.append(e.valid)
        outside.append(bool(np.any(err > e.tau_h_act_bound)))
        ratio.append(float(np.max(err / e.tau_h_act_bound)))
    valid = np.array(valid[1:])
    outside, ratio = np.array(outside), np.array(ratio)
    first = int(np.argmax(valid)) + 1 if valid.any() else None
    return {"start": start, "tau_h_act": float(log.tau_h_act[start, 0]), "first_valid": first,
            "invalid_outside": int(np.sum(outside[~valid])), "invalid": int(np.sum(~valid)),
            "valid": int(valid.sum()), "valid_outside": int(np.sum(outside[valid])),
            "worst_ratio_valid": float(ratio[valid].max()) if valid.any() else None}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.validity", description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", default=",".join(SCENARIOS))
    p.add_argument("--configs", default=",".join(CONFIGS))
    p.add_argument("--starts", default="0,500,1500", help="reset samples of the estimation log")
    args = p.parse_args(argv)
    root = data_root()
    starts = [int(s) for s in args.starts.split(",")]
    print(f"{'scenario':<13}{'config':<19}{'reset at':>9}{'tau_h':>7}{'valid from':>11}"
          f"{'invalid (outside)':>19}{'valid (outside)':>17}{'worst |err|/bound':>19}")
    for name in args.scenarios.split(","):
        sim = simulate(load_scenario(root / "configs" / "scenarios" / f"{name}.yaml"))
        for c in args.configs.split(","):
            cfg = load_config(root / "configs" / c)
            try:
                est = make_estimator("gp-akf", cfg, dt=sim.estimation.dt, train=sim.training)
            except Exception as e:  # noqa: BLE001 - a training log the filter cannot follow: say so
                print(f"{name:<13}{c:<19}  training refused: {type(e).__name__}: {str(e)[:90]}")
                continue
            for s in starts:
                r = gate_run(est, sim.estimation, s)
                print(f"{name:<13}{c:<19}{s:>9}{r['tau_h_act']:>7.2f}{r['first_valid']!s:>11}"
                      f"{r['invalid']:>12} ({r['invalid_outside']:>3}){r['valid']:>10} ({r['valid_outside']:>3})"
                      f"{r['worst_ratio_valid']:>19.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
