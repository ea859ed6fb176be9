"""``python -m benchmarks.can_hil``: does the CAN stack change the estimate? Offline vs through CAN.

For each embedded scenario: the offline simulator + ``replay`` (AKF), against the same scenario
run through device model, virtual CAN bus and driver (:func:`sea_daemon.runtime.hil_session.run_scenario`)
with the AKF online in the cycle — with the torque RPDO actuated on reception (default) and
at the next SYNC.  Prints AKF RMSE of τ_h,act over the estimation phase, the RMS difference of
the load angle between the two runs, the jitter of the motor torque (std of Δτ_m) and the
cycle time.
"""
from __future__ import annotations

import time

import numpy as np

from sea_daemon.apps.bench import machine, summarize
from sea_daemon.core.estimators import make_estimator
from sea_daemon.core.replay import replay
from sea_daemon.io.configfile import data_root
from sea_daemon.io.scenario import load_scenario
from sea_daemon.runtime.hil_session import run_scenario
from sea_daemon.runtime.sim_runner import simulate

NAME = "can-hil"
HELP = "offline simulator vs the same scenarios through the CAN stack (AKF RMSE, tracking, cycle time)"


def add_arguments(p) -> None:
    p.add_argument("--scenario", action="append", choices=("passive", "active"), default=None)


def run(args) -> int:
    def rms(x):
        return float(np.sqrt(np.mean(np.square(x))))

    print(f"can-hil on {machine()}")
    for name in args.scenario or ("passive", "active"):
        sc = load_scenario(data_root() / "configs" / "scenarios" / f"{name}.yaml")
        dt = sc.nominal.dt
        off = simulate(sc)
        r_off = replay(off.estimation, make_estimator("akf", sc.nominal, dt=dt))
        e_off = r_off.tau_h_act_hat[:, 0] - off.estimation.tau_h_act[:, 0]
        print(f"{name}: {sc.training_samples} + {sc.estimation_samples} samples at {1 / dt:g} Hz")
        print(f"  offline simulator + replay       AKF RMSE {rms(e_off):.4f} N m, "
              f"std dtau_m {np.std(np.diff(off.estimation.tau_m[:, 0])):.3f} N m")
        for sync in (False, True):
            t0 = time.perf_counter()
            hil = run_scenario(sc, estimator=make_estimator("akf", sc.nominal, dt=dt), sync_rpdo=sync)
            wall = time.perf_counter() - t0
            est = hil.estimation
            e = est.extra["tau_h_act_hat"] - est.tau_h_act[:, 0]
            print(f"  CAN, RPDO {'at next SYNC  ' if sync else 'on reception  '}    AKF RMSE {rms(e):.4f} N m, "
                  f"std dtau_m {np.std(np.diff(est.tau_m[:, 0])):.3f} N m, "
                  f"q vs offline {rms(est.q - off.estimation.q):.2e} rad RMS; {wall:.1f} s wall")
            print(f"    cycle (read + control + write + AKF): {summarize(hil.cycle_s)}")
    return 0


if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
