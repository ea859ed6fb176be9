"""benchmarks/tau_model.py: the steady-state bounds of the two τ_h,act models, checked against the
floor no bound can go below (core/bounds/floor.py), computed independently."""
import json

import pytest

from benchmarks import tau_model
from benchmarks._cli import main


def test_each_models_best_bound_is_above_its_floor_and_the_integrated_walk_is_tighter(tmp_path, capsys):
    out = tmp_path / "t.json"
    assert main(tau_model, ["--rates", "100,1000", "--json", str(out)]) == 0
    rows = {(r["rate_hz"], r["model"]): r for r in json.loads(out.read_text())["rows"]}
    assert len(rows) == 4
    for r in rows.values():
        assert r["bound"] >= r["floor"]                 # no filter's guaranteed bound beats the floor
        assert r["lag"] > 0 and r["gaussian"] > 0
    for rate in (100.0, 1000.0):
        assert rows[(rate, "irw")]["bound"] < rows[(rate, "rw")]["bound"]
        # but a held load-side torque error (GP error, friction range) reaches τ_h,act's error with
        # an ℓ1 gain of about 1 through the walk and 2-3 through the integrated walk
        assert 1.0 <= rows[(rate, "rw")]["torque_error_gain"] < 1.5
        assert rows[(rate, "irw")]["torque_error_gain"] > 1.8
    # at 100 Hz a change within a step reaches the angles only through the velocity it builds:
    # the random walk's lag term is at least about r·dt/2 (docs/bounds.md §9)
    assert rows[(100.0, "rw")]["lag"] >= 0.5 * 40.0 * 0.01 * 0.9
    assert "floor" in capsys.readouterr().out


def test_bad_options_are_one_clear_line(capsys):
    assert main(tau_model, ["--rates", "0"]) == 2
    assert "--rates 0" in capsys.readouterr().err
