"""``sea-daemon bench NAME``: benchmarks (see :mod:`sea_daemon.apps.bench`)."""
from __future__ import annotations

from sea_daemon.apps.commands import Command, add_commands

#: the benchmarks, one module each in :mod:`sea_daemon.apps.bench`, in the order ``sea-daemon bench
#: --help`` lists them; only the chosen one's module is imported
BENCHMARKS = (
    Command("assist", "assist",
            "assistance on plants of the generalisation family by the README flow alone: effort, engaged share, faults"),
    Command("capstone", "capstone",
            "a measured log with torque truth (the real SEA bench) fold by fold: diagnose's effects and the "
            "GP-AKF calibrated on one block, scored on the others"),
    Command("can-cycle", "can_cycle", "CANopen cycle round trip (RPDO + SYNC + TPDOs) against the device model"),
    Command("faults", "faults",
            "fault injection over the device model: detection, cycles to zero torque, false alarms"),
    Command("generalize", "generalize", "calibrate random plants once on a passive session, test on unlike sessions"),
    Command("latency", "latency", "time per estimator step (median, p99, p99.9) on a simulated or given log"),
    Command("loop", "loop",
            "fixed-rate loop: jitter, overruns, CPU per cycle, device answer latency, CAN bus load (100 Hz / 1 kHz)"),
    Command("newrobot", "newrobot",
            "calibrate one plant of scenario files once on a passive session, estimate on its other sessions"),
    Command("record", "record",
            "the measured log through faults: device model stopped, disk full, service killed and restarted"),
    Command("soak", "soak",
            "long run: loop + CAN + device model + GP-AKF learning online + log writer; memory, overruns, rows"),
)


def add_arguments(p) -> None:
    add_commands(p, BENCHMARKS, "sea_daemon.apps.bench", dest="bench", metavar="NAME")


def run(args) -> int:
    """Without a benchmark's name (a named benchmark's ``run`` takes this one's place)."""
    names = ", ".join(b.name for b in BENCHMARKS)
    print(f"sea-daemon bench: name a benchmark: {names}")
    return 2
