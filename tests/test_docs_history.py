"""The documentation describes the software as it is, for its users: no issue numbers, no
sessions of its development, no "before this change", no remarks about the machine it was
developed on.  Checked over the docs, the README, the package (code, docstrings, comments, the
example configurations and the service unit) and the research benchmarks.

A measurement names its host in docs/benchmarks.md ("2 vCPUs, AMD EPYC, virtual machine"), not
as "this machine".
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from _paths import repo_root

ROOT = repo_root()

#: what development history looks like in text, each with what to write instead
PATTERNS = {
    r"\bissue\s+#?[0-9]+": "an issue number: say what the software does",
    r"\bissue's\b": "an issue's target: state the target itself",
    r"\bsession\s+[0-9]+\b": "a development session: say what the software does",
    r"\bbefore this (work|change|setting)\b": "development history: compare with a named setting",
    r"\bthis machine\b": "the development machine: name the host of a measurement (docs/benchmarks.md)",
    r"\bthe development machine\b": "the development machine: name the host of a measurement",
    r"\b[0-9]-core test machine\b": "the test machine: name the host (\"2 vCPUs, AMD EPYC, virtual machine\")",
    r"\bthe quiet machine\b": "the development machine: say \"with no other work on the host\"",
    r"\btest merge\b": "development history",
    r"\bat the time of writing\b": "development history: give the date of a measurement",
    r"/tmp/bb\b": "a developer's scratch path: use a named output directory",
}
SUFFIXES = {".md", ".py", ".yaml", ".yml", ".service", ".eds", ".toml"}


def files() -> list[Path]:
    out = [ROOT / "README.md", ROOT / "pyproject.toml"]
    out += sorted((ROOT / "docs").glob("*.md"))
    for top in ("sea_daemon", "benchmarks"):
        out += sorted(p for p in (ROOT / top).rglob("*")
                      if p.is_file() and p.suffix in SUFFIXES and "__pycache__" not in p.parts)
    return out


def hits(text: str) -> list[tuple[int, str, str]]:
    found = []
    for n, line in enumerate(text.splitlines(), 1):
        for pat, why in PATTERNS.items():
            m = re.search(pat, line, flags=re.IGNORECASE)
            if m:
                found.append((n, m.group(0), why))
    return found


def test_the_checked_files_exist():
    paths = files()
    assert ROOT / "README.md" in paths and ROOT / "docs" / "configuration.md" in paths
    assert any(p.parts[-2:] == ("configs", "exo_1dof_robot.yaml") for p in paths)   # the configs, through the package
    assert len(paths) > 100


@pytest.mark.parametrize("text, n", [
    ("Closing the loop on measured data (issue 6):", 1),
    ("Speed work (issue 3's latency target)", 1),
    ("the issue's target", 1),
    ("On the 2-core test machine, under load", 1),
    ("the kernel has no SocketCAN (this machine's has none)", 1),
    ("Before this work (same bench)", 1),
    ("python -m benchmarks.bounds --out /tmp/bb", 1),
    ("the tissue 3.5 N m/rad; a passive session; 2 vCPUs, AMD EPYC, virtual machine", 0),
])
def test_the_patterns_find_history_and_only_history(text, n):
    assert len(hits(text)) == n


def test_no_development_history_in_docs_configs_or_code():
    found = []
    for p in files():
        for n, what, why in hits(p.read_text(encoding="utf-8", errors="replace")):
            found.append(f"{p.relative_to(ROOT)}:{n}: {what!r} — {why}")
    assert not found, "development history in the docs or the code:\n" + "\n".join(found)
