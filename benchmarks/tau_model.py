"""``python -m benchmarks.tau_model``: how tight a bound each model of the wearer's torque allows.

The daemon's filter models τ_h,act as a random walk and its bound holds the lag with the declared
rate |τ̇_h,act| ≤ r (docs/bounds.md §6).  This benchmark asks what a bound could be with that
model, and with an integrated random walk (the state also carries τ̇_h,act, its own random walk;
the bound then holds the lag with |τ̈_h,act| ≤ a), on a configuration's robot linearised at rest
(:mod:`sea_daemon.core.bounds.floor`'s model: inertia, spring, gravity), with the two angles
measured through the encoders' quantisation (variance Δ²/12) and nothing else unknown: no GP or
model error, no friction.  For each model and rate it scans the walk's intensity and prints the
steady-state filter whose bound is smallest, split into

* the worst-case lag: the declared r (or a) times the ℓ1 norm of the τ_h,act error's response to
  the held input (the set of means' τ half-width in steady state, exact for a linear plant), and
* the Gaussian part: z_{1−δ/2} √P_g,ττ, the quantisation noise through the filter alone,

and, for the bound's other inputs, the torque-error gain: the ℓ1 norm of the τ_h,act error's
response to a held load-side torque error of 1 N m (a GP error, a declared friction's range:
every bounded torque error of the real bound enters the set of means with this factor; the
random walk's is about 1, the integrated walk's, which turns the error into a rate as well, 2–3),
next to the floor (:func:`~sea_daemon.core.bounds.floor.bound_floor`) for the same declaration.
r and a come from the declared wearer (``--band``, ``--rms``: r = 2π f_max √2 RMS, a = (2π f_max)²
√2 RMS) unless given.  Steady-state linear algebra: seconds, one core.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy.special import ndtri

from sea_daemon.analysis.passive_noise import l1_response, lyapunov_sum, steady_filter

from sea_daemon.core.bounds.floor import bound_floor, rest_jacobian, wearer_accel, wearer_rate
from sea_daemon.core.linalg import discretize
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import data_root, load_config

NAME = "tau_model"
HELP = "the tightest bound a random-walk and an integrated-random-walk τ_h,act model allow"
DESCRIPTION = __doc__


def add_arguments(p) -> None:
    p.add_argument("--config", default=str(data_root() / "configs" / "exo_1dof.yaml"),
                   help="model YAML (default configs/exo_1dof.yaml; one joint)")
    p.add_argument("--rates", default="100,1000", help="comma list of rates [Hz] (default 100,1000)")
    p.add_argument("--band", default="0.1,3", help="the wearer's band [Hz] (default 0.1,3: bench generalize's)")
    p.add_argument("--rms", type=float, default=1.5, help="the wearer's torque RMS [N m] (default 1.5)")
    p.add_argument("--q-deg", type=float, default=40.0, help="rest angle [deg] (default 40)")
    p.add_argument("--delta", type=float, default=0.05, help="the bound's δ (default 0.05)")
    p.add_argument("--json", default=None, help="write the table as JSON here")


def steady_bound(A5: np.ndarray, dt: float, model: str, q_walk: float, amp: float, R: np.ndarray, z: float):
    """(worst-case lag, Gaussian part [N m], torque-error gain) of the steady-state KF with walk
    intensity ``q_walk`` (of τ_h,act for ``rw``, of τ̇_h,act for ``irw``), or None where the filter
    does not settle."""
    if model == "rw":
        n, walk = 5, 4
        Ac = A5
    else:
        n, walk = 6, 5
        Ac = np.zeros((6, 6))
        Ac[:5, :5] = A5
        Ac[4, 5] = 1.0                       # dτ/dt = τ̇
    Bt = np.zeros(n)
    Bt[:5] = A5[:, 4]                        # a load-side torque error enters as τ_h,act does
    F, G = discretize(Ac, np.column_stack([np.eye(n)[walk], Bt]), dt)
    H = np.zeros((2, n))
    H[0, 0] = 1.0                            # θ_m
    H[1, 0] = H[1, 1] = 1.0                  # q = θ_m + θ_s
    Q = np.zeros((n, n))
    Q[walk, walk] = q_walk * dt
    kf = steady_filter(F, H, Q + 1e-18 * np.eye(n), R)
    if kf is None:
        return None
    K, IKH, T = kf
    l1 = l1_response(T, IKH @ G, 4, slice(None))        # the τ error's responses to the held inputs
    Pg = lyapunov_sum(T, K @ R @ K.T)                     # the noise alone through the filter
    return amp * l1[0], z * math.sqrt(max(Pg[4, 4], 0.0)), l1[1]


def run(args) -> int:
    cfg = load_config(args.config)
    if cfg.joints != 1:
        raise InputError(f"--config {args.config}: {cfg.joints} joints; this benchmark takes a one-joint model")
    try:
        rates = [float(v) for v in args.rates.split(",")]
        band = [float(v) for v in args.band.split(",")]
    except ValueError:
        raise InputError(f"--rates {args.rates!r} / --band {args.band!r}: comma lists of numbers") from None
    if not all(1.0 <= r <= 100000.0 for r in rates):
        raise InputError(f"--rates {args.rates}: each rate in 1..100000 Hz")
    if len(band) != 2 or not 0 < band[0] < band[1] <= 100 or not 0 < args.rms <= 100 or not 0 < args.delta < 1:
        raise InputError(f"--band {args.band} (two increasing numbers in (0, 100] Hz), --rms {args.rms:g} (in (0, 100] N m), "
                         f"--delta {args.delta:g} (in (0, 1))")
    r, a = wearer_rate(band, args.rms), wearer_accel(band, args.rms)
    q0 = np.array([math.radians(args.q_deg)])
    A5 = rest_jacobian(cfg, q0)
    dq, dth = cfg.hardware.encoder_resolution(1)
    R = np.diag([dth[0] ** 2 / 12.0, dq[0] ** 2 / 12.0])
    z = float(ndtri(1.0 - args.delta / 2.0))
    floors = {"rw": bound_floor(cfg, rate=r, q=q0).rho[0], "irw": bound_floor(cfg, rate=r, accel=a, q=q0).rho[0]}
    print(f"{args.config}: rest at {args.q_deg:g} deg, encoders {dq[0]:.3g} / {dth[0]:.3g} rad; wearer {band[0]:g}-{band[1]:g} Hz "
          f"at {args.rms:g} N m RMS: r = {r:.3g} N m/s, a = {a:.4g} N m/s^2; Gaussian factor z = {z:.3g}")
    print(f"{'rate':>7} {'model':>5} {'walk':>10} {'lag':>8} {'Gaussian':>9} {'bound':>8} {'floor':>7} {'torque-error gain':>18}")
    table = []
    grids = {"rw": np.geomspace(1e-3, 1e5, 33), "irw": np.geomspace(1e-1, 1e9, 41)}
    for rate in rates:
        for model in ("rw", "irw"):
            best = None
            for qw in grids[model]:
                b = steady_bound(A5, 1.0 / rate, model, float(qw), r if model == "rw" else a, R, z)
                if b is not None and (best is None or b[0] + b[1] < best[1][0] + best[1][1]):
                    best = (float(qw), b)
            if best is None:
                print(f"{rate:7g} {model:>5} no walk intensity of the grid settles")
                continue
            qw, (lag, g, gain) = best
            row = {"rate_hz": rate, "model": model, "walk": qw, "lag": lag, "gaussian": g, "bound": lag + g,
                   "floor": float(floors[model]), "torque_error_gain": float(gain)}
            table.append(row)
            print(f"{rate:7g} {model:>5} {qw:10.3g} {lag:8.4f} {g:9.4f} {lag + g:8.4f} {row['floor']:7.4f} {gain:18.2f}",
                  flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"config": args.config, "r": r, "a": a, "rows": table}, indent=1))
    return 0


if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
