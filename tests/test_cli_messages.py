"""What the command line shows: plain-text help, the version and licence, messages with levels
(the ``sea_daemon`` logger; syslog priorities when stderr is the journal), progress of long
commands, the warning about the remote bus."""
from __future__ import annotations

import logging
import os
import re
import subprocess
import sys

import pytest

try:
    import tomllib
except ImportError:              # Python 3.10
    tomllib = pytest.importorskip("tomli")

from _cli import run as cli
from _paths import repo_root
from sea_daemon.apps import console
from sea_daemon.apps.commands import COMMANDS, plain
from sea_daemon.apps.commands.bench import BENCHMARKS
from sea_daemon.apps.progress import Progress

ROOT = repo_root()
ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
MARKUP = ("``", ":mod:", ":class:", ":func:", ":data:", ":meth:")
HELPS = [[]] + [[c.name] for c in COMMANDS] + [["bench", b.name] for b in BENCHMARKS]


@pytest.mark.parametrize("argv", HELPS, ids=lambda a: " ".join(a) or "sea-daemon")
def test_help_is_plain_text(argv, capsys):
    code, out, err = cli([*argv, "--help"], capsys)
    assert code == 0 and out.startswith("usage: sea-daemon"), err
    assert not [m for m in MARKUP if m in out], out


def test_plain_turns_rst_into_text():
    assert plain("``run --model`` see :mod:`sea_daemon.client`, :func:`~sea_daemon.core.replay.replay` "
                 "and **this**::") == "run --model see sea_daemon.client, replay and this:"


def test_version_from_the_package_metadata_and_the_licence():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    r = subprocess.run([sys.executable, "-m", "sea_daemon", "--version"], capture_output=True, text=True, env=ENV)
    assert r.returncode == 0 and r.stdout == f"sea-daemon {meta['version']}\n"
    assert meta["license"] == "MIT" and "LICENSE" in meta["license-files"]
    assert any(c.startswith("Programming Language :: Python :: 3") for c in meta["classifiers"])
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "Copyright (c) 2026 the sea-daemon developers" in text


def _watch_nothing(tmp_path, *extra, journal=False):
    """``sea-daemon watch`` on an empty state directory for 0.3 s: an INFO line (waiting) and the
    exit-2 refusal; stderr into a file (the journal's stream when ``journal``)."""
    err_path = tmp_path / "err.txt"
    with open(err_path, "w") as err:
        env = dict(ENV)
        env.pop("JOURNAL_STREAM", None)
        if journal:
            st = os.fstat(err.fileno())
            env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
        r = subprocess.run([sys.executable, "-m", "sea_daemon", "watch", "--state-dir", str(tmp_path / "none"),
                            "--timeout", "0.3", *extra], stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    return r.returncode, err_path.read_text().splitlines()


def test_messages_carry_the_syslog_priority_when_stderr_is_the_journal(tmp_path):
    code, lines = _watch_nothing(tmp_path, journal=True)
    assert code == 2 and len(lines) == 2, lines
    assert lines[0].startswith("<6>sea-daemon watch: waiting for a daemon")               # info
    assert lines[1].startswith("<3>sea-daemon watch: error: no sea-daemon publishes")     # the refusal
    code, lines = _watch_nothing(tmp_path)                                              # a terminal or file
    assert code == 2 and lines[0].startswith("sea-daemon watch: waiting") and lines[1].startswith("sea-daemon")


@pytest.mark.parametrize("flags", [["-q"], ["--log-level", "warning"], ["--log-level", "error"]])
def test_quiet_and_log_level_leave_the_refusal_alone(tmp_path, flags):
    code, lines = _watch_nothing(tmp_path, *flags)
    assert code == 2 and len(lines) == 1 and lines[0].startswith("sea-daemon watch: error: no sea-daemon"), lines


def test_formatter_levels_and_journal_prefix():
    rec = logging.LogRecord("sea_daemon.run", logging.WARNING, __file__, 1, "a\nb", None, None)
    assert console.Formatter("sea-daemon run", False).format(rec) == "sea-daemon run: warning: a\nb"
    assert console.Formatter("sea-daemon run", True).format(rec) == "<4>sea-daemon run: warning: a\n<4>b"
    rec = logging.LogRecord("sea_daemon", logging.INFO, __file__, 1, "step %d", (3,), None)
    assert console.Formatter("sea-daemon fit", True).format(rec) == "<6>step 3"
    assert console.level_of(None) is None and console.level_of("debug", 0, 2) == logging.DEBUG
    assert console.level_of(None, 1) == logging.DEBUG and console.level_of(None, 0, 1) == logging.WARNING


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_progress_off_a_terminal_plain_lines_at_most_every_interval(capsys):
    console.setup("sea-daemon fit", logging.INFO)
    clock = _Clock()
    p = Progress("fit", total=6, interval=5.0, clock=clock)
    for k in range(30):                     # a call every second for 30 s
        clock.t = float(k)
        p(k % 6, what=f"step {k % 6}")
    p.close()
    lines = capsys.readouterr().err.splitlines()
    # none in the first 5 s (a short command prints none), then one per 5 s, no carriage returns
    assert [ln.split("(")[-1] for ln in lines] == ["5 s)", "10 s)", "15 s)", "20 s)", "25 s)"]
    assert lines[0] == "fit: 5/6 step 5 (5 s)" and not any("\r" in ln for ln in lines)
    console.setup("sea-daemon fit", logging.WARNING)            # -q: no progress
    q = Progress("fit", total=6, interval=0.0, clock=clock)
    q(1)
    assert capsys.readouterr().err == "" and not q.enabled


def test_diagnose_reports_its_steps_to_a_progress_callback():
    from diagnose_sim import passive_log

    from sea_daemon.analysis.diagnose.engine import STEPS
    from sea_daemon.apps.diagnose import diagnose
    log, cfg = passive_log(moves=1)
    calls = []
    diagnose(log, cfg, progress=lambda done, total, what: calls.append((done, total, what)))
    total = len(STEPS) + 2
    assert [c[0] for c in calls] == list(range(total + 1)) and {c[1] for c in calls} == {total}
    assert calls[0][2] == STEPS[0] and calls[-1][2] == "done"


def test_run_on_the_remote_bus_warns_and_recommends_ipc(tmp_path, capsys):
    code, out, err = cli(["run", "--config", ROOT / "configs" / "exo_1dof_sim.yaml", "--model", tmp_path / "none.npz",
                          "--bus", "remote", "--channel", "ws://127.0.0.1:1/", "--log-dir", tmp_path], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2, err
    assert re.match(r"sea-daemon run: warning: the remote bus .*not the real-time loop.*--bus ipc", lines[0])
    assert "none.npz" in lines[1]                           # the refusal itself, one line, unchanged
