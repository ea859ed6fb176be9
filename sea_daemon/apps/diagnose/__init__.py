"""``diagnose``: find the effects a measured log holds that the model lacks.

    from sea_daemon.apps.diagnose import diagnose
    result = diagnose(log, cfg, out_dir="diag_out")      # docs/interfaces.md §4 JSON as a dict

The diagnosis itself is the analysis layer's (:mod:`sea_daemon.analysis.diagnose`: residuals,
candidates, selection, validation, the AKF before and after; :func:`run_diagnosis` returns a
:class:`Diagnosis` and writes nothing).  This module runs it, runs the model on other logs
(``apply``) and writes diagnosis.json, model_augmented.yaml, report.md and the plots
(:mod:`.report`).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.log import MeasuredLog
from sea_daemon.errors import ConfigError, InputError, shown
from sea_daemon.io.configfile import config_text, save_config
from sea_daemon.io.files import atomic_write_text
from sea_daemon.analysis.diagnose.apply import apply_model, claims
from sea_daemon.analysis.diagnose.engine import STEPS, Diagnosis, run_diagnosis
from sea_daemon.analysis.diagnose.select import SelectOptions
from sea_daemon.analysis.diagnose.summary import clean
from sea_daemon.apps.diagnose.report import write_report

__all__ = ["diagnose", "SelectOptions", "run_diagnosis", "Diagnosis"]


def diagnose(log: MeasuredLog, cfg: ModelConfig, out_dir: str | Path | None = None,
             options: SelectOptions | None = None, passive: bool | None = None,
             plots: bool = True, apply: list[MeasuredLog] | tuple = (),
             progress: Callable | None = None) -> dict:
    """Diagnose ``log`` against ``cfg``; return the docs/interfaces.md §4 dict.

    With ``out_dir``: write diagnosis.json, model_augmented.yaml, report.md and PNGs there.
    ``apply``: other logs (a person acting, no torque truth) to run the AKF on with the model
    before and after (:mod:`sea_daemon.analysis.diagnose.apply`); their summaries go to the
    dict's ``applied``.  ``progress(done, total, what)``: called before each step.
    """
    total = len(STEPS) + 2

    def report(done, _total=None, what=""):
        if progress is not None:
            progress(done, total, what)
    dg = run_diagnosis(log, cfg, options, passive, progress=report)
    dg.applied = []
    report(len(STEPS), what="the model on the other logs")
    if apply:
        _apply(dg, cfg, apply)
    report(len(STEPS) + 1, what="writing the report and plots")
    if out_dir is not None:
        _write(dg, Path(out_dir), log, cfg, plots)
    report(total, what="done")
    return dg.result


def _apply(dg: Diagnosis, cfg: ModelConfig, others) -> None:
    """The AKF with the model before and after on each of ``others``: ``dg.applied`` and the
    result's ``applied``."""
    v = dg.result.get("validation", {}).get("refit", {}).get("held_out_block", {})
    ref = {"all": dg.result["estimate_rmse_after"], "held_out": v.get("estimate_rmse_after")}
    for other in others:
        if other.n != cfg.joints:
            raise InputError(f"{other.path}: the log has {other.n} joint(s), the model {cfg.source} has {cfg.joints}")
        res = apply_model(other, cfg, dg.cfg_after)
        res["claims"] = claims(res["summary"], ref)
        dg.applied.append(res)
    dg.result["applied"] = [{"log": r["log"], "samples": r["samples"], "resampled": r["resampled"],
                             "summary": clean(r["summary"]), "claims": r["claims"]} for r in dg.applied]


def _write(dg: Diagnosis, out: Path, log: MeasuredLog, cfg: ModelConfig, plots: bool) -> None:
    """diagnosis.json, model_augmented.yaml, report.md and the plots into ``out``."""
    # never a model its own loader refuses (an effect fitted out of its range: the log does
    # not fit the nominal model, e.g. K_s off by a factor): refused before anything is written
    try:
        config_text(dg.cfg_after, out / "model_augmented.yaml")
    except ConfigError as e:
        raise InputError(f"{shown(log.path)}: the effects found make a configuration the loader refuses "
                         f"({e.key}: {e.problem}); the log does not fit the nominal model of "
                         f"{shown(cfg.source)} (check its model section); nothing written") from None
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "diagnosis.json", json.dumps(dg.result, indent=2, ensure_ascii=False) + "\n")
    save_config(dg.cfg_after, out / "model_augmented.yaml",
                header=f"sea-daemon diagnose: {cfg.source} with the effects found in {log.path}")
    write_report(dg, out, log, cfg, plots=plots)
