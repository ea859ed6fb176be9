"""Helpers of the hostile-input tests: run the CLI in-process, check a refusal, a small valid log."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from sea_daemon.apps.cli import main


def run(argv, capsys):
    """(exit status, stdout, stderr) of ``sea-daemon ARGV``."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def refused(code, err, *patterns):
    """Exit 2 with one line on stderr, no traceback, no internal error, matching every pattern."""
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err and "internal error" not in err, err
    for p in patterns:
        assert re.search(p, lines[0]), (p, lines[0])


def passive_log(p: Path, samples: int = 300) -> Path:
    """A valid passive log of ``samples`` samples at 100 Hz."""
    t = np.arange(samples) * 0.01
    q = 0.3 * np.sin(t)
    rows = "\n".join(f"{a:.4f},{b:.6f},{b - 0.001:.6f},{0.5 * np.cos(a):.5f}" for a, b in zip(t, q))
    p.write_text("t,q,theta_m,tau_m\n" + rows + "\n")
    return p
