"""Hostile input that aims at termination and size: a forged model file whose LoG-GP tree loops
or points outside itself, configuration values beyond their ranges (effect parameters, learning
and calibration sizes).  Each is refused with exit status 2 and one line naming the value and
its range, never a hang or an exhausted memory.  (docs/safety.md, "Bad input")"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from _cli import passive_log, refused, run
from _paths import repo_root
from sea_daemon.core.excitation import Coverage, WorkingRange
from sea_daemon.core.learning import ResidualGP
from sea_daemon.errors import ModelFileError
from sea_daemon.io.configfile import load_config
from sea_daemon.io.gpmodel import load_gp_model, save_gp_model
from sea_daemon.io.modelfile import load_model, save_model

CFG = str(repo_root() / "configs" / "exo_1dof.yaml")
ROBOT = "joints: 1\nrate_hz: 100\nmodel: {M: 0.12, J: 0.08, D_m: 0.6, K_s: 110.0, D_s: 0.25, effects: [%s]}\n"


def _calibrated_model(path):
    """A calibrated model file (what ``sea-daemon fit`` writes) whose LoG-GP has split."""
    cfg = load_config(CFG)
    res = ResidualGP(1, cfg.learning, hyperopt=False)
    rng = np.random.default_rng(0)
    for _ in range(3 * res.gps[0].max_points):
        res.update(rng.uniform(-1, 1, 3), np.array([0.1]))
    assert res.gps[0].n_nodes >= 3
    cal = {"gp_used": True, "coverage": Coverage(WorkingRange(-1.0, 1.0)).to_dict(),
           "gp_v_gate": 0.03, "gp_var_ref": 1e-12}
    save_gp_model(path, cfg, res, {"calibration": cal})
    return path


def _forge(path, edit):
    """Rewrite joint 1's tree of a model file with ``edit(tree)``, the checksum made valid again."""
    arrays, meta = load_model(path)
    edit(meta["residual"]["gps"][0]["tree"])
    save_model(path, arrays, {k: v for k, v in meta.items() if k not in ("format", "version", "sha256")})
    return path


def _loop(t):
    t["left"][0] = t["right"][0] = 0


def _child_outside(t):
    t["left"][0] = 10 ** 9


def _shared_child(t):
    t["right"][0] = t["left"][0]


def _leaf_with_children(t):
    leaf = t["dim"].index(-1)
    t["left"][leaf] = 1


def _dimension_outside(t):
    t["dim"][0] = 7


def _overlap_nan(t):
    t["lo"][0] = float("nan")


@pytest.mark.parametrize("edit,expect", [
    (_loop, r"node 0 has child 0; allowed 1\.\.\d+"),
    (_child_outside, r"node 0 has child 1000000000; allowed 1\.\.\d+"),
    (_shared_child, r"reached twice"),
    (_leaf_with_children, r"leaf node \d+ has children"),
    (_dimension_outside, r"node 0 splits dimension 7; allowed -1 \(a leaf\) or 0\.\.2"),
    (_overlap_nan, r"node 0 has the overlap \[nan"),
])
def test_a_forged_tree_is_refused_on_load_naming_the_file(tmp_path, edit, expect):
    p = _forge(_calibrated_model(tmp_path / "m.npz"), edit)
    with pytest.raises(ModelFileError, match=expect) as e:
        load_gp_model(p, load_config(CFG))
    assert str(p) in str(e.value)


def test_a_model_whose_tree_loops_ends_replay_quickly_with_exit_2(tmp_path):
    """The forged model of the attack: ``left[0] = right[0] = 0`` with a valid checksum made
    ``replay --model`` spin for ever; it is refused at load."""
    p = _forge(_calibrated_model(tmp_path / "m.npz"), _loop)
    log = passive_log(tmp_path / "log.csv")
    r = subprocess.run([sys.executable, "-m", "sea_daemon", "replay", str(log), "--config", CFG, "--model", str(p),
                        "--out", str(tmp_path / "e.csv")], capture_output=True, text=True, timeout=300,
                       env=dict(os.environ, PYTHONPATH=str(repo_root())), cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert "node 0 has child 0" in r.stderr and str(p) in r.stderr
    assert not (tmp_path / "e.csv").exists()


_ROUTE_LOOP = """
import numpy as np
from sea_daemon.core.gp.routing import Tree, route
tree = Tree.of([0, -1, -1], [-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [{left}, -1, -1], [{right}, -1, -1])
try:
    route(np.array([[{x}]]), tree.links, tree.span, False)
except ValueError as e:
    print("refused:", e)
"""


@pytest.mark.parametrize("left,right,x", [(0, 0, -1.0), (0, 0, 0.0), (5, 2, -1.0), (-7, 2, 0.0)])
def test_the_compiled_routing_bounds_a_walk_by_the_node_count(left, right, x):
    """A tree built in memory with a loop or a link outside it (the fast path and the overlap's
    branching): route raises instead of running for ever or reading outside the tree."""
    code = _ROUTE_LOOP.format(left=left, right=right, x=x)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env=dict(os.environ, PYTHONPATH=str(repo_root())))
    assert r.returncode == 0, r.stderr
    assert "refused: LoG-GP tree: a walk leaves the tree or outlasts its node count" in r.stdout


# ------------------------------------------------------------------ ranges
@pytest.mark.parametrize("effect,section,expect", [
    ("{type: delay, side: motor, seconds: 100}", "", r"effects\[0\]\.seconds: must be in \[0, 1\] s, got 100"),
    ("{type: delay, side: motor, seconds: 1.0e+9}", "", r"effects\[0\]\.seconds: must be in \[0, 1\] s, got 1e\+09"),
    ("{type: coulomb, side: load, F_c: 1.0e+6}", "", r"effects\[0\]\.F_c: must be in \[0, 1000\] N m, got 1e\+06"),
    ("{type: torque_scale, kappa: 50}", "", r"effects\[0\]\.kappa: must be in \(0, 10\], got 50"),
    ("{type: spring_backlash, width: 3}", "", r"effects\[0\]\.width: must be in \[0, 1\] rad, got 3"),
    ("", "learning: {max_points: 100000}", r"learning\.max_points: must be an integer in 2\.\.1000, got 100000"),
    ("", "learning: {max_leaves: 10000000}", r"learning\.max_leaves: must be an integer in 2\.\.100000"),
    ("", "learning: {seed: 100000000000}", r"learning\.seed: must be an integer in 0\.\.4294967295"),
    ("", "calibration: {duration_s: 1.0e+8}", r"calibration\.duration_s: must be in \(0, 3600\], got 1e\+08"),
])
def test_a_value_beyond_its_range_is_refused_naming_it(tmp_path, capsys, effect, section, expect):
    """An effect parameter or a size setting beyond its range (a delay of 10⁹ s ended in
    MemoryError, 10⁶ s took 4.2 GB): exit 2 with the key and the range."""
    cfg = tmp_path / "m.yaml"
    cfg.write_text(ROBOT % effect + section + "\n")
    log = passive_log(tmp_path / "log.csv")
    code, _, err = run(["identify-noise", log, "--config", cfg], capsys)
    refused(code, err, expect)


# ------------------------------------------------------------------ bench generalize's cache
class _Plant:
    """Unpickling this touches ``marker``: what a planted cache file could run."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        from pathlib import Path
        return Path.touch, (Path(self.marker),)


def _stub_sessions(monkeypatch):
    """generalize's simulation replaced by a small log per session; the calls counted."""
    from sea_daemon.apps.bench import generalize
    from sea_daemon.core.log import MeasuredLog
    calls = []

    def session(true, duration_s, reference=None, hold_q=None, human=None, seed=0, **_):
        calls.append(seed)
        t = np.arange(50) * 0.01
        x = np.sin(t + seed)[:, None]
        return MeasuredLog(t, x, 0.9 * x, 0.1 * x, None, {"q_true": x[:, 0].copy()}, f"<session {seed}>")
    monkeypatch.setattr(generalize, "run_session", session)
    return generalize, calls


def test_generalize_never_unpickles_what_is_in_its_cache(tmp_path, monkeypatch):
    import pickle
    generalize, calls = _stub_sessions(monkeypatch)
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    marker = tmp_path / "ran"
    (cache / "plant_420_2.pkl").write_bytes(pickle.dumps(_Plant(marker)))
    np.savez(cache / "plant_420_2.npz", __meta__=np.array([_Plant(marker)], dtype=object))
    pd, cal, tests = generalize.plant_logs(420, 2.0, cache)
    assert not marker.exists()
    assert calls and len(cal) == 50 and set(tests) == {s.name for s in generalize.sessions(pd)}


def test_generalize_reads_its_own_cache_back_and_only_for_its_key(tmp_path, monkeypatch):
    generalize, calls = _stub_sessions(monkeypatch)
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    _, cal, tests = generalize.plant_logs(420, 2.0, cache)
    n = len(calls)
    _, cal2, tests2 = generalize.plant_logs(420, 2.0, cache)
    assert len(calls) == n                                       # nothing simulated again
    np.testing.assert_array_equal(cal2.q, cal.q)
    assert list(tests2) == list(tests) and tests2["slow"].extra.keys() == tests["slow"].extra.keys()
    np.testing.assert_array_equal(tests2["slow"].extra["q_true"], tests["slow"].extra["q_true"])
    (cache / "plant_421_2.npz").write_bytes((cache / "plant_420_2.npz").read_bytes())
    generalize.plant_logs(421, 2.0, cache)                       # another plant's entry: simulated
    assert len(calls) > n


def test_a_cache_directory_others_can_write_is_not_used(tmp_path):
    from sea_daemon.apps.bench._logcache import private_dir
    d = tmp_path / "cache"
    d.mkdir(mode=0o700)
    assert private_dir(d) is None
    d.chmod(0o777)
    assert "writable by group or others" in private_dir(d)
    link = tmp_path / "link"
    link.symlink_to(d)
    assert private_dir(link) == "not a directory"
