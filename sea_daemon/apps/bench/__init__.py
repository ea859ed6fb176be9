"""Benchmarks run by ``sea-daemon bench NAME``, one module each (discovered).

A module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Every benchmark prints what it measured, on what (machine, data), with how many runs, as
medians and percentiles.  :func:`summarize` gives the figures in one place.
"""
from __future__ import annotations

import os
import platform

import numpy as np


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


def choose(text: str | None, allowed, flag: str) -> list[str]:
    """Labels named in a comma-separated option (all of ``allowed`` when empty), validated.

    An unknown label is an InputError naming the flag, the value and the allowed ones.
    """
    from sea_daemon.errors import InputError
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
    import json

    from sea_daemon.io.files import atomic_write_text, check_outputs
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
    import dataclasses
    if settings is None:
        return cfg
    return dataclasses.replace(cfg, estimator=settings.estimator, kinematics=settings.kinematics,
                               learning=settings.learning)


def start_simulated(args):
    """Start of a benchmark on simulated scenarios (accuracy, bounds): creates ``args.out``,
    loads ``--settings`` (None: each scenario's own config) and prints the machine and the
    settings.  Returns ``(out directory, settings)``."""
    from pathlib import Path

    from sea_daemon.io.configfile import load_config, repo_root
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = args.settings or str(repo_root() / "configs" / "exo_1dof_sim.yaml")
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
