"""``sea-daemon bench faults``: fault injection over the device model, in lock-step.

For each fault of the single fault policy (docs/safety.md) one run of ``--cycles`` loop
cycles: the daemon's :class:`FixedRateLoop` with :class:`CanopenHardware`, the AKF (with its
health checks) and a PID tracking a sine, against the device model on a virtual CAN bus,
lock-step (the plant steps once per SYNC).  The fault is injected at seeded random cycles
(gaps of ``--gap`` cycles after the previous recovery); after it latched, its cause is
removed and an operator reset is requested (``FixedRateLoop.request_reset``), and the run
goes on to the next injection.

Measured per injection, at the device (``_rig.DriveProbe``: frame barrier, then the drive's
state machine and 0x6071):

* **detected**: the fault latched is the injected type, not before the injection;
* **latency**: cycles from the injection to the latch (includes what the fault's
  definition takes: k missed cycles, the heartbeat timeout in paced cycles, the
  stuck-encoder run);
* **reaction**: cycles from the cycle in which the fault's condition is met (per its
  definition, from an independent observer: the injection cycle for EMCY / jump / bus-off /
  send failure / estimator state; the k-th missed TPDO; the first cycle past the last
  heartbeat seen on the bus + timeout; the stuck run recomputed from the recorded counts;
  the 5th consecutive overrun) to the first cycle after which the drive applies zero torque
  and keeps doing so until the reset.  0 = in the same cycle;
* **held**: cycles in which the drive applied non-zero torque while the fault was latched.

Then ``--fault-free-cycles`` cycles without injection: every latch there is a false alarm.

Every run logs through the daemon's off-loop log writer (a temporary file), and the log is
checked afterwards (``log rows / cycles``, ``ok`` when all hold): a row for every cycle the
loop ran (cycle column 0..N−1, time increasing, no row lost), ``fault`` non-zero exactly in
the latched cycles, ``valid`` 0 and the torque 0 in them.

The loop's clock is virtual (advanced by its sleeps and by the injected stall only), so the
lock-step run is deterministic in loop time; heartbeats, SDO and PDO timeouts run on the
real clock.  A lock-step cycle takes whatever wall time the machine gives it, so while a
heartbeat loss is pending the run paces its cycles to one period of wall time each (as the
loop runs in production): the heartbeat timeout is then a number of cycles independent of the
machine's load, and ``max_wait`` cycles are always longer than it.  The bus sniffer and the
driver date a heartbeat by the same frame timestamp.  Bus-off is the driver's controller reporting bus-off (error frame); the
virtual bus still carries the quick stop, a real bus-off controller would not — then the
drive's own watch of the daemon's heartbeat (0x1016, quick stop) stops it within
``heartbeat_timeout_ms``.  A send failure is one refused frame (transient).
"""
from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from sea_daemon.apps.bench import add_choice_argument, add_json_argument, choose, json_output, machine
from sea_daemon.apps.bench._fault_run import BUS, FAULTS, OVERRUN_STREAK, FaultRun, record_heartbeats
from sea_daemon.errors import InputError

DESCRIPTION = __doc__


def run_suite(cycles: int = 10000, seed: int = 0, fault_free_cycles: int = 100000, kinds=None,
              gap: tuple[int, int] = (100, 400), max_wait: int = 400, warmup: int = 200, progress=None) -> dict:
    """Run every fault kind (and the fault-free run); returns the figures as a dict."""
    kinds = list(kinds or FAULTS)
    out = {"cycles_per_kind": cycles, "seed": seed, "kinds": {}, "fault_free": None}
    logs = tempfile.TemporaryDirectory(prefix="sea-bench-faults-")
    try:
        _run_kinds(out, kinds, cycles, seed, gap, max_wait, warmup, progress, Path(logs.name))
        if fault_free_cycles:
            t0 = time.monotonic()
            r = FaultRun(None, fault_free_cycles, seed + 99991, gap, max_wait, warmup,
                         log_path=Path(logs.name) / "fault_free.csv").run()
            out["fault_free"] = {"cycles": fault_free_cycles, "false_alarms": r.false_alarms,
                                 "reset_failed": r.reset_failed, "host_stalls": r.host_stalls, "log": r.log_check,
                                 "barrier_misses": r.probe.barrier_misses, "wall_s": time.monotonic() - t0}
    finally:
        logs.cleanup()
    return out


def _run_kinds(out, kinds, cycles, seed, gap, max_wait, warmup, progress, log_dir: Path) -> None:
    for i, kind in enumerate(kinds):
        t0 = time.monotonic()
        r = FaultRun(kind, cycles, seed + 1000 * i, gap, max_wait, warmup, log_path=log_dir / f"{kind}.csv")
        record_heartbeats(r)
        r.run()
        inj = r.injections
        out["kinds"][kind] = {
            "injected": len(inj),
            "detected": sum(x.detected for x in inj),
            "latched_as": sorted({x.latched or "none" for x in inj}),
            "latency": [x.latency for x in inj],
            "reaction": [x.reaction for x in inj],
            "held": sum(x.held for x in inj),
            "false_alarms": r.false_alarms,
            "reset_failed": r.reset_failed,
            "host_stalls": r.host_stalls,
            "barrier_misses": r.probe.barrier_misses,
            "log": r.log_check,
            "wall_s": time.monotonic() - t0,
            "injections": [dataclasses.asdict(x) | {"detected": x.detected} for x in inj],
        }
        if progress:
            progress(kind, out["kinds"][kind])


def _stat(xs) -> str:
    xs = [x for x in xs if x >= 0]
    if not xs:
        return "-"
    return f"{int(np.median(xs))} / {max(xs)}"


def _log(c: dict | None) -> str:
    """'rows / cycles' of a run's log, with 'ok' when every check of FaultRun._check_log held."""
    if not c:
        return "-"
    return f"{c['rows']}/{c['cycles']} {'ok' if c['ok'] else 'FAIL'}"


def table(res: dict) -> str:
    lines = [f"{'fault':<22}{'injected':>9}{'detected':>9}  {'latched as':<28}{'latency med/max':>16}"
             f"{'reaction med/max':>18}{'held':>6}{'false':>7}{'reset failed':>14}{'log rows / cycles':>19}"]
    for kind, r in res["kinds"].items():
        lines.append(f"{kind:<22}{r['injected']:>9}{r['detected']:>9}  {','.join(r['latched_as']):<28}"
                     f"{_stat(r['latency']):>16}{_stat(r['reaction']):>18}{r['held']:>6}{len(r['false_alarms']):>7}"
                     f"{len(r.get('reset_failed', [])):>14}{_log(r.get('log')):>19}")
    tot_i = sum(r["injected"] for r in res["kinds"].values())
    tot_d = sum(r["detected"] for r in res["kinds"].values())
    lines.append(f"detected / injected: {tot_d} / {tot_i}"
                 + (f" = {100.0 * tot_d / tot_i:.1f} %" if tot_i else ""))
    ff = res.get("fault_free")
    if ff:
        lines.append(f"log of the fault-free run: {_log(ff.get('log'))}")
        lines.append(f"false alarms in {ff['cycles']} fault-free cycles: {len(ff['false_alarms'])}"
                     f" (failed resets after them: {len(ff.get('reset_failed', []))})"
                     + (f"  ({'; '.join(f'cycle {k}: {d}' for k, d in ff['false_alarms'][:5])})"
                        if ff["false_alarms"] else ""))
    fails = [x for r in res["kinds"].values() for x in r.get("reset_failed", [])]
    if fails:
        lines.append("failed operator resets (the fault stayed latched, reset again): "
                     + "; ".join(f"cycle {k}: {d}" for k, d in fails[:5]))
    return "\n".join(lines)


def add_arguments(p) -> None:
    p.add_argument("--cycles", type=int, default=10000, help="loop cycles per fault kind (default 10000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the injection times and choices")
    p.add_argument("--fault-free-cycles", type=int, default=100000,
                   help="cycles of the fault-free run for false alarms (default 100000; 0: skip)")
    add_choice_argument(p, "--kinds", FAULTS)
    add_json_argument(p, "every injection's record")


def run(args) -> int:
    save = json_output(args)
    kinds = choose(args.kinds, FAULTS, "--kinds")
    if args.cycles < 1000 or args.fault_free_cycles < 0:
        raise InputError(f"--cycles {args.cycles}: must be >= 1000; --fault-free-cycles >= 0")
    print(f"# sea-daemon bench faults on {machine()}")
    print(f"# FixedRateLoop + CanopenHardware + AKF + PID vs device model, virtual CAN bus, lock-step, "
          f"{args.cycles} cycles per kind, seed {args.seed}; bus {BUS}, overrun streak {OVERRUN_STREAK}")
    print("# latency: injection -> latch; reaction: fault condition met -> zero torque at the drive "
          "(cycles, 0 = same cycle); held: cycles with torque while latched", flush=True)

    def progress(kind, r):
        print(f"#   {kind}: {r['detected']}/{r['injected']} detected, {r['wall_s']:.0f} s", flush=True)
    res = run_suite(args.cycles, args.seed, args.fault_free_cycles, kinds, progress=progress)
    print(table(res))
    save(res)
    return 0
