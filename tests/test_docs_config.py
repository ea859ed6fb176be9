"""docs/configuration.md documents every key the model-YAML loader accepts, in the section the
loader reads it from, and no key the loader refuses.

The keys come from the loader itself: each section's dataclass (``sea_daemon.core.config``,
``sea_daemon.core.hardware_config``) lists the keys its ``from_dict`` maps (``KEYS``; unknown
keys are refused by ``validate.check_keys`` against that list).  The doc's keys are the first
column of each section's table.
"""
from __future__ import annotations

import dataclasses
import re

import pytest

from _paths import repo_root
from sea_daemon.core import config as C
from sea_daemon.core.hardware_config import BusConfig, HardwareConfig

DOC = repo_root() / "docs" / "configuration.md"

#: the doc's section heading (its first `code` word) -> the dataclass whose KEYS the loader maps there
SECTIONS = {
    "model": C.SEAParams,
    "estimator": C.EstimatorConfig,
    "kinematics": C.KinematicsConfig,
    "learning": C.LearningConfig,
    "hardware": HardwareConfig,
    "hardware.bus": BusConfig,
    "assist": C.AssistConfig,
    "calibration": C.CalibrationConfig,
}


def loader_keys() -> dict[str, set[str]]:
    """Per section, the keys the loader accepts (a nested section's own key excluded: it has a
    section of its own)."""
    out = {"": set(C.ModelConfig.TOP_KEYS) - set(SECTIONS)}
    for name, cls in SECTIONS.items():
        out[name] = set(cls.KEYS) - {k for k in cls.KEYS if f"{name}.{k}" in SECTIONS}
    return out


def doc_keys(text: str) -> dict[str, set[str]]:
    """Per section of the doc (``## `name` ...`` / ``### `name` ...``; ``## Top level``: ""), the
    keys in the first column of its tables."""
    out: dict[str, set[str]] = {}
    section = None
    for line in text.splitlines():
        h = re.match(r"^#{2,3}\s+(.*)$", line)
        if h:
            title = h.group(1).strip()
            m = re.match(r"`([a-z_.]+)`", title)
            section = "" if title.lower().startswith("top level") else (m.group(1) if m else None)
            if section is not None:
                out.setdefault(section, set())
            continue
        row = re.match(r"^\|\s*`([A-Za-z_0-9]+)`\s*\|", line)
        if row and section is not None:
            out[section].add(row.group(1))
    return out


def test_every_dataclass_field_is_reachable_through_a_documented_key():
    # a field the loader fills must come from a key of its section (encoder_counts fills the two
    # per-side fields); a field with no key would be a setting no YAML can change
    keys = loader_keys()
    for name, cls in SECTIONS.items():
        fields = {f.name for f in dataclasses.fields(cls)}
        via = {"encoder_counts_load": "encoder_counts", "encoder_counts_motor": "encoder_counts",
               "P0": "P0", "joint_channel": "channel", "rigid": "urdf"}
        for f in fields:
            assert via.get(f, f) in set(cls.KEYS), f"{name}.{f} is a field the YAML cannot set"
    assert "P0_tau" in keys["estimator"] and "q_min_deg" in keys["calibration"]


def test_the_doc_reader_finds_sections_and_rows():
    text = ("## Top level\n| key | d |\n|---|---|\n| `joints` | x |\n"
            "## `model` — the model\n| `M` | x |\n### `hardware.bus` — bus\n| `channel` | x |\n")
    assert doc_keys(text) == {"": {"joints"}, "model": {"M"}, "hardware.bus": {"channel"}}


@pytest.mark.parametrize("section", [""] + list(SECTIONS))
def test_every_key_the_loader_accepts_is_documented(section):
    documented = doc_keys(DOC.read_text(encoding="utf-8"))
    assert section in documented, f"docs/configuration.md has no section for `{section or 'top level'}`"
    missing = loader_keys()[section] - documented[section]
    assert not missing, f"docs/configuration.md, section `{section or 'top level'}`: keys not documented: {sorted(missing)}"


@pytest.mark.parametrize("section", [""] + list(SECTIONS))
def test_the_doc_names_no_key_the_loader_refuses(section):
    documented = doc_keys(DOC.read_text(encoding="utf-8")).get(section, set())
    extra = documented - loader_keys()[section]
    assert not extra, f"docs/configuration.md, section `{section or 'top level'}`: keys the loader refuses: {sorted(extra)}"
