"""Benchmarks run by ``sea-daemon bench NAME``, one module each, named in
:data:`sea_daemon.apps.commands.bench.BENCHMARKS`.

A module defines ``add_arguments(parser)`` and ``run(args) -> int`` (optional ``DESCRIPTION``).
Every benchmark prints what it measured, on what (machine, data), with how many runs, as
medians and percentiles.  :func:`summarize` gives the figures in one place.
"""
from __future__ import annotations

import dataclasses
import json
import os
import platform
import struct
import time
from pathlib import Path

import numpy as np

from sea_daemon.errors import InputError
from sea_daemon.io.configfile import data_root, load_config
from sea_daemon.io.files import atomic_write_text, check_outputs


def machine() -> str:
    """One line naming the machine the figures were measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}"


_REF_FRAME = struct.Struct("<IBB2x8sd")


def _reference_work(a: np.ndarray, b: np.ndarray, table: dict, buf: bytearray) -> float:
    """A fixed piece of work of the kind a cycle is made of (Python calls, dict lookups, small
    numpy operations, struct packing); not the daemon's code, so that its cost describes the
    host, not a change of the daemon."""
    s = 0.0
    for i in range(40):
        a[1:4] = b[2:5]
        np.multiply(a, 1.5, out=b)
        b -= a
        _REF_FRAME.pack_into(buf, 0, 0x180 + (i & 7), 0, 8, b"\x01\x02\x03\x04\x05\x06\x07\x08", s)
        s += table.get(i & 15, 0.0) + float(a[1]) * 1e-9 + len(buf)
    return s


def host_wake(period: float, samples: int = 100, clock=time.thread_time, sleep=time.sleep) -> dict:
    """What a cycle that starts after sleeping costs on this host, against the same work hot.

    A fixed-rate loop sleeps between its cycles: the CPU may idle (and, in a virtual machine,
    the host run something else on it) and the cycle starts with cold caches and predictors.
    :func:`_reference_work` (fixed, not the daemon's code) is timed with the thread's CPU clock
    ``samples`` times right after sleeping ``period`` and, in the same round, after running it
    twice more back to back (hot).  Returns the medians [µs] and their ratio, a property of the
    host at the time (printed so that runs at different times can be compared); a cycle of the
    daemon, with more code and data than the reference and a second wake for its TPDOs, shows a
    larger factor."""
    if not period > 0 or samples < 1:
        raise ValueError(f"host_wake: period must be > 0 s and samples >= 1, got {period!r}, {samples!r}")
    a, b = np.zeros(8), np.linspace(0.0, 1.0, 8)
    table = {i: 0.5 * i for i in range(16)}
    buf = bytearray(_REF_FRAME.size)
    cold, hot = np.empty(samples), np.empty(samples)
    for i in range(samples):
        sleep(period)
        c0 = clock()
        _reference_work(a, b, table, buf)
        c1 = clock()
        _reference_work(a, b, table, buf)
        c2 = clock()
        _reference_work(a, b, table, buf)
        c3 = clock()
        cold[i], hot[i] = c1 - c0, c3 - c2
    c, h = float(np.median(cold)) * 1e6, float(np.median(hot)) * 1e6
    return {"period_s": float(period), "samples": int(samples), "after_sleep_us": c, "hot_us": h,
            "factor": c / h if h > 0 else float("nan")}


def describe_host_wake(w: dict) -> str:
    """:func:`host_wake`'s figures in words."""
    return (f"median {w['after_sleep_us']:.0f} us after sleeping {w['period_s'] * 1e3:g} ms, "
            f"{w['hot_us']:.0f} us hot (x{w['factor']:.2f}, {w['samples']} rounds)")


def choose(text: str | None, allowed, flag: str) -> list[str]:
    """Labels named in a comma-separated option (all of ``allowed`` when empty), validated.

    An unknown label is an InputError naming the flag, the value and the allowed ones.
    """
    allowed = list(allowed)
    labels = [s.strip() for s in (text or "").split(",") if s.strip()] or allowed
    unknown = [s for s in labels if s not in allowed]
    if unknown:
        raise InputError(f"{flag} {','.join(unknown)}: unknown; allowed: {', '.join(allowed)}")
    return labels


def summarize(samples_s, scale: float = 1e6, unit: str = "us") -> str:
    """'median …, p99 …, p99.9 …, max … (n runs)' of times given in seconds."""
    a = np.asarray(samples_s, dtype=float) * scale
    if a.size == 0:
        return "no samples"
    p50, p99, p999 = np.percentile(a, [50, 99, 99.9])
    return (f"median {p50:.1f} {unit}, p99 {p99:.1f} {unit}, p99.9 {p999:.1f} {unit}, "
            f"max {a.max():.1f} {unit} ({a.size} runs)")


def add_choice_argument(p, flag: str, allowed) -> None:
    """``FLAG a,b,...``: a comma-separated subset of ``allowed`` (default all; :func:`choose`)."""
    allowed = list(allowed)
    p.add_argument(flag, default=",".join(allowed), help=f"comma-separated subset of {', '.join(allowed)}")


def add_json_argument(p, what: str = "the figures") -> None:
    """``--json PATH``: also write ``what`` as JSON there (checked before the run, atomic)."""
    p.add_argument("--json", default=None, help=f"also write {what} as JSON here")


def json_output(args):
    """A writer of ``args.json`` (a no-op without it), the path checked now, before the run."""
    check_outputs([("--json", args.json)])

    def write(data) -> None:
        if args.json:
            atomic_write_text(args.json, json.dumps(data, indent=1, default=str))
    return write


def add_settings_argument(p) -> None:
    """``--settings MODEL.yaml|scenario``: the estimator settings every estimator of a simulated
    benchmark uses (accuracy, bounds)."""
    p.add_argument("--settings", default=None, metavar="MODEL.yaml",
                   help="estimator settings (estimator, kinematics, learning sections) used by EVERY "
                        "estimator (default: configs/exo_1dof_sim.yaml, R identified for the simulated "
                        "sensors); 'scenario': each scenario's own model config (the paper's R, Sigma_nom)")


def apply_settings(cfg, settings):
    """``cfg`` with the estimator, kinematics and learning sections of ``settings`` (the model,
    i.e. what the estimator knows of the plant, is kept): one setting for every estimator."""
    if settings is None:
        return cfg
    return dataclasses.replace(cfg, estimator=settings.estimator, kinematics=settings.kinematics,
                               learning=settings.learning)


def start_simulated(args):
    """Start of a benchmark on simulated scenarios (accuracy, bounds): creates ``args.out``,
    loads ``--settings`` (None: each scenario's own config) and prints the machine and the
    settings.  Returns ``(out directory, settings)``."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = args.settings or str(data_root() / "configs" / "exo_1dof_sim.yaml")
    settings = None if path == "scenario" else load_config(path)
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.2f} at start")
    print(_describe_settings(path, settings))
    return out, settings


def _describe_settings(path: str, settings) -> str:
    """One line naming the estimator settings of a run."""
    if settings is None:
        return "estimator settings: each scenario's own model config"
    e = settings.estimator
    return (f"estimator settings (all estimators): {path}: R diag {np.diag(e.R).tolist()}, "
            f"Sigma_nom diag {np.diag(e.Sigma_nom).tolist()}"
            + (f" per {e.Sigma_nom_dt} s" if e.Sigma_nom_dt > 0 else " per step")
            + (f" + motor-torque noise {e.tau_m_noise} N m through Gamma_u" if e.tau_m_noise > 0 else "")
            + ("; GP-AKF Q with sigma^2 + sigma_on^2" if e.gp_noise_in_Q else "")
            + ("; start with measured velocities" if e.init_after_kinematics else "")
            + f", kinematics {settings.kinematics.method} "
            f"W={settings.kinematics.window} d={settings.kinematics.degree}")
