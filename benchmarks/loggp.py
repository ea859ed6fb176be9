"""``python -m benchmarks.loggp``: LoG-GP update/predict latency vs ``lgrt4gps``, same data, same run.

Streams a smooth SEA-like residual ``f(z)`` along a quasi-periodic joint trajectory
``z = [q, q̇, q̈]`` (100 Hz) into :class:`sea_daemon.core.gp.loggp.LoGGP` and into the reference
implementation ``lgrt4gps`` (``LGRTN``, its built-in GP engine) with the same N̄, split rule
('center') and overlap.  At each checkpoint N (10³ … 10⁶ points) it times, call by call,
the ``window`` updates that bring the model to N points, then ``window`` predictions at the
following (not yet trained) inputs.  lgrt4gps is given a wall-time budget; checkpoints it does
not reach are reported as not measured (no extrapolation).
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from sea_daemon.apps.bench import machine, summarize
from sea_daemon.core.config import LearningConfig
from sea_daemon.core.gp.hyper import AdamHyper
from sea_daemon.core.gp.loggp import LoGGP
from sea_daemon.errors import InputError

NAME = "loggp"
HELP = "LoG-GP update/predict latency and memory vs lgrt4gps at 1e3..1e6 points"


def add_arguments(p) -> None:
    p.add_argument("--sizes", nargs="+", type=float, default=[1e3, 1e4, 1e5, 1e6],
                   help="checkpoints in training points (default 1e3 1e4 1e5 1e6)")
    p.add_argument("--quick", action="store_true",
                   help="small run (< 30 s): checkpoints 1e3 1e4, short windows, lgrt4gps budget 8 s")
    p.add_argument("--window", type=int, default=1000, help="timed calls per op and checkpoint")
    p.add_argument("--max-points", type=int, default=100, help="N̄, points per leaf (default 100)")
    p.add_argument("--overlap", type=float, default=None,
                   help="relative overlap width (default: the configuration default)")
    p.add_argument("--max-leaves", type=int, default=0,
                   help="LoG-GP leaf limit (0 = unbounded, the default, so the tree really grows)")
    p.add_argument("--lgrt-budget", type=float, default=300.0,
                   help="wall-time budget for lgrt4gps in seconds (default 300)")
    p.add_argument("--no-lgrt", action="store_true", help="skip lgrt4gps")
    p.add_argument("--seed", type=int, default=0)


# ---------------------------------------------------------------------------- data

def residual(Z: np.ndarray) -> np.ndarray:
    """Smooth SEA-like load-side residual f(z) [N m]: gravity, human visco-elasticity,
    viscous and (smoothed) Coulomb friction, an inertia error."""
    q, dq, ddq = Z[:, 0], Z[:, 1], Z[:, 2]
    return (2.9 * np.sin(q) + 1.2 * (q - 0.6) + 0.25 * dq + 0.35 * np.tanh(dq / 0.05)
            + 0.02 * ddq)


def trajectory(n: int, seed: int = 0, rate_hz: float = 100.0):
    """``(Z, y)``: n inputs z = [q, q̇, q̈] along a quasi-periodic elbow motion, noisy targets."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    w = np.array([0.9, 2.3, 5.7])
    a = np.array([0.5, 0.25, 0.08])
    ph = np.array([0.0, 1.0, 2.0])
    arg = np.outer(t, w) + ph
    q = 0.7 + np.sin(arg) @ a
    dq = np.cos(arg) @ (a * w)
    ddq = -np.sin(arg) @ (a * w * w)
    Z = np.column_stack([q, dq, ddq])
    Z += rng.normal(size=Z.shape) * np.array([1e-4, 5e-3, 5e-2])     # differentiation noise
    y = residual(Z) + 0.02 * rng.normal(size=n)
    return Z, y


# ---------------------------------------------------------------------------- runners

class _Ours:
    name = "sea_daemon LoGGP"

    def __init__(self, d, max_points, overlap, max_leaves, seed):
        self.m = LoGGP(d, max_points, max_leaves=max_leaves, overlap=overlap,
                       lengthscales=[0.3, 1.0, 5.0], sigma_f=1.0, sigma_n=0.05, seed=seed)

    def update(self, x, y, i):
        self.m.update(x, y)

    def predict(self, x, i):
        return self.m.predict(x)[0]

    def predict_grad(self, x, i):
        return self.m.predict_with_grad(x)[0]


class _Lgrt:
    name = "lgrt4gps LGRTN"

    def __init__(self, d, max_points, overlap, Z, Y):
        # local: lgrt4gps is optional (the bench extra), needed only when it is compared
        from lgrt4gps.lgrtn import LGRTN
        warnings.filterwarnings("ignore", module="lgrt4gps")
        self.m = LGRTN(d, 1, max_pts=max_points, div_method="center",
                       wo_ratio=(1.0 / overlap if overlap > 0 else 1e12))
        self.Z2, self.Y2 = Z, Y.reshape(-1, 1)

    def update(self, x, y, i):
        self.m.add_data(self.Z2[i:i + 1], self.Y2[i:i + 1])

    def predict(self, x, i):
        return float(self.m.predict(self.Z2[i:i + 1])[0][0, 0])


def _fmt(t) -> str:
    """summarize() plus the minimum, the figure least disturbed by other load on the machine."""
    return f"{summarize(t)}; min {np.min(t) * 1e6:.1f} us"


def _time(fn, Z, Y, idx) -> tuple[np.ndarray, np.ndarray]:
    out = np.empty(len(idx))
    pred = np.empty(len(idx))
    pc = time.perf_counter_ns
    for k, i in enumerate(idx):
        x = Z[i]
        t0 = pc()
        r = fn(x, Y[i], i) if Y is not None else fn(x, i)
        out[k] = pc() - t0
        pred[k] = r if r is not None else np.nan
    return out * 1e-9, pred


def _time_slices(m, max_points: int, count: int = 200) -> dict | None:
    """Cost of the two phases of a hyperparameter slice on the fullest leaves of ``m``."""
    min_n = int(0.9 * max_points)
    leaves = [m.leaf(i) for i in m.leaves() if m.leaf(i).n_ >= min_n][:count]
    if not leaves:
        return None
    hyp = AdamHyper(m.input_dim)
    tp, ta, th = [], [], []
    pc = time.perf_counter_ns
    for leaf in leaves:
        st = hyp.new_state()
        t0 = pc()
        hyp.propose(leaf, hyp.new_state(), points=max_points // 2)
        th.append((pc() - t0) * 1e-9)
        t0 = pc()
        _, theta = hyp.propose(leaf, st)
        t1 = pc()
        if theta is not None:
            hyp.apply(leaf, theta)
        t2 = pc()
        tp.append((t1 - t0) * 1e-9)
        ta.append((t2 - t1) * 1e-9)
    return {"n": len(leaves), "min_n": min_n, "propose": tp, "apply": ta, "propose_half": th,
            "half": max_points // 2}


def run(args) -> int:
    sizes = sorted({int(s) for s in args.sizes})
    window, budget = args.window, args.lgrt_budget
    if args.quick:
        sizes, window, budget = [1000, 10000], min(window, 300), min(budget, 8.0)
    if not sizes or sizes[0] < 2 or window < 1:
        raise InputError(f"--sizes must be >= 2 and --window >= 1, got {args.sizes}, {args.window}")
    window = min(window, sizes[0] // 2)
    overlap = LearningConfig().overlap if args.overlap is None else args.overlap
    max_leaves = args.max_leaves or None
    n_total = sizes[-1] + window
    Z, Y = trajectory(n_total, seed=args.seed)
    f_true = residual(Z)

    print(f"bench loggp: {machine()}")
    print(f"data: quasi-periodic z = [q, dq, ddq] at 100 Hz, smooth SEA-like residual, "
          f"target noise 0.02 N m, {n_total} points, seed {args.seed}")
    print(f"models: N̄ = {args.max_points} points per leaf, split at the centre of the widest "
          f"dimension, overlap {overlap} of the width; LoG-GP max_leaves "
          f"{max_leaves or 'unbounded'}; per checkpoint {window} timed calls per op")
    print("timing: each call timed alone (perf_counter_ns); 'update' = the window of updates "
          "ending at the checkpoint, 'predict' = the next window of inputs (not trained)")

    results: dict[str, dict[int, dict]] = {}
    runners = [("ours", lambda: _Ours(3, args.max_points, overlap, max_leaves, args.seed))]
    if not args.no_lgrt:
        try:
            # local: lgrt4gps is optional (the bench extra); without it the comparison is skipped
            import lgrt4gps  # noqa: F401
            runners.append(("lgrt", lambda: _Lgrt(3, args.max_points, overlap, Z, Y)))
        except ImportError:
            print("lgrt4gps: not installed (pip install lgrt4gps) -- skipped")

    for key, make in runners:
        model = make()
        results[key] = _checkpoints(key, model, sizes, window, budget, Z, Y, f_true)
        if key == "ours":
            results["slices"] = _time_slices(model.m, args.max_points)

    print()
    _print_results(results, sizes)
    return 0


def _checkpoints(key: str, model, sizes: list, window: int, budget: float, Z, Y, f_true) -> dict:
    """``model`` filled with the stream (Z, Y) up to each checkpoint of ``sizes``, the ``window``
    updates before and predictions after each timed; lgrt4gps (``key`` 'lgrt') stops when its
    wall-time ``budget`` is spent.  Returns checkpoint -> figures."""
    res = {}
    start = time.perf_counter()
    filled = 0
    stopped = None
    for c in sizes:
        # untimed fill up to the window before the checkpoint
        while filled < c - window:
            model.update(Z[filled], Y[filled], filled)
            filled += 1
            if key == "lgrt" and filled % 200 == 0 and time.perf_counter() - start > budget:
                stopped = filled
                break
        if stopped is not None:
            break
        tu, _ = _time(model.update, Z, Y, range(filled, c))
        filled = c
        tp, mu = _time(model.predict, Z, None, range(c, c + window))
        row = {"update": tu, "predict": tp,
               "rmse": float(np.sqrt(np.mean((mu - f_true[c:c + window]) ** 2)))}
        if hasattr(model, "predict_grad"):
            row["predict_grad"] = _time(model.predict_grad, Z, None, range(c, c + window))[0]
            m = model.m
            row["leaves"], row["depth"], row["bytes"] = m.n_leaves, m.depth, m.memory_bytes()
            row["route"] = float(np.mean([len(m.route(Z[i]))
                                          for i in range(c, c + window)]))
        res[c] = row
        el = time.perf_counter() - start
        print(f"  [{model.name}] reached {c} points after {el:.1f} s", flush=True)
        if key == "lgrt" and el > budget and c != sizes[-1]:
            stopped = c
            break
    if stopped is not None:
        print(f"  [{model.name}] stopped at {stopped} points: wall-time budget {budget:.0f} s "
              f"spent; larger checkpoints NOT measured")
    return res


def _print_results(results: dict, sizes: list) -> None:
    """The slices' cost and, per checkpoint, both models' figures and their ratio."""
    sl = results.get("slices")
    if sl:
        print(f"hyperparameter slice on {sl['n']} leaves holding >= {sl['min_n']} points "
              f"(one Adam step of the LML; the loop runs the two phases on consecutive updates):")
        print(f"  phase 1 propose (LML gradient + Adam): {_fmt(sl['propose'])}")
        print(f"  phase 1 with hyper_points={sl['half']}        : {_fmt(sl['propose_half'])}")
        print(f"  phase 2 apply (rebuild + swap)       : {_fmt(sl['apply'])}")
    for c in sizes:
        print(f"== {c} training points ==")
        o = results["ours"].get(c)
        if o:
            print(f"  LoG-GP   update              : {_fmt(o['update'])}")
            print(f"  LoG-GP   predict (mu, var)   : {_fmt(o['predict'])}")
            print(f"  LoG-GP   predict_with_grad   : {_fmt(o['predict_grad'])}")
            print(f"  LoG-GP   leaves {o['leaves']}, depth {o['depth']}, leaves per prediction "
                  f"{o['route']:.2f}, memory {o['bytes'] / 1e6:.1f} MB, predict RMSE {o['rmse']:.4f} N m")
        g = results.get("lgrt", {}).get(c)
        if g:
            print(f"  lgrt4gps update              : {_fmt(g['update'])}")
            print(f"  lgrt4gps predict (mu, var)   : {_fmt(g['predict'])}")
            print(f"  lgrt4gps predict RMSE {g['rmse']:.4f} N m (its built-in GP: fixed σ_f = l = σ_n = 1)")
            if o:
                ru = np.median(g["update"]) / np.median(o["update"])
                rp = np.median(g["predict"]) / np.median(o["predict"])
                rg = np.median(g["predict"]) / np.median(o["predict_grad"])
                print(f"  speed ratio (median lgrt4gps / LoG-GP): update {ru:.1f}x, predict {rp:.1f}x, "
                      f"predict vs our predict_with_grad {rg:.1f}x")
        elif "lgrt" in results:
            print("  lgrt4gps: not measured at this size (budget)")
        if o:
            step = np.median(o["update"]) + np.median(o["predict_grad"])
            print(f"  LoG-GP predict_with_grad + update, sum of medians: {step * 1e6:.1f} us")

if __name__ == "__main__":
    import sys

    from benchmarks._cli import main
    sys.exit(main(sys.modules[__name__]))
