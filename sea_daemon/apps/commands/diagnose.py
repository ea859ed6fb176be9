"""``sea-daemon diagnose LOG.csv --config MODEL.yaml --out DIR`` (docs/interfaces.md §3, §4)."""
from __future__ import annotations

from pathlib import Path

from sea_daemon.analysis.sufficiency import check_columns
from sea_daemon.apps.commands import add_log_and_config
from sea_daemon.apps.diagnose import SelectOptions, diagnose
from sea_daemon.analysis.diagnose.summary import fmt
from sea_daemon.apps.progress import Progress
from sea_daemon.errors import InputError
from sea_daemon.io.configfile import load_config
from sea_daemon.io.files import check_output_dir, check_outputs
from sea_daemon.io.logcsv import read_log

#: the files diagnose writes into --out besides its PNG plots
OUTPUTS = ("diagnosis.json", "model_augmented.yaml", "report.md")
DESCRIPTION = ("Closes the loop on measured data: computes the load- and motor-side model residuals of the "
               "log, traces them to effects of the vocabulary (docs/interfaces.md §2), writes DIR/diagnosis.json, "
               "DIR/model_augmented.yaml (the config plus the effects found), DIR/report.md and PNG plots, "
               "and reports residual RMS and the AKF's estimation error before and after.")


def add_arguments(p) -> None:
    add_log_and_config(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created)")
    p.add_argument("--passive", action="store_true",
                   help="ignore a tau_h_act column in the residuals (passive subject assumed)")
    p.add_argument("--min-fraction", type=float, default=None, metavar="F",
                   help="smallest share of the residual's mean square an effect must explain (default 0.05)")
    p.add_argument("--min-effect-rms", type=float, default=None, metavar="NM",
                   help="smallest RMS [N m] of an effect's share worth a model term (default: a tenth of the "
                        "log's RMS commanded torque, at most 0.01)")
    p.add_argument("--holdout", type=float, default=None, metavar="F",
                   help="share of the log at its end kept back and scored separately (time-blocked "
                        "validation; default 0.25, 0: none)")
    p.add_argument("--cv-blocks", type=int, default=None, metavar="K",
                   help="contiguous time blocks of the cross-validation that decides which effects are kept "
                        "(each fitted on the others, scored on itself; default 4, 0: none, every effect found is kept)")
    p.add_argument("--cv-selection", action="store_true",
                   help="the cross-validation also repeats the whole selection without each block and scores "
                        "it there, in and out of sample (slower)")
    p.add_argument("--gp-akf", action="store_true",
                   help="the validation also scores the GP-AKF, learned on the fit block (slower)")
    p.add_argument("--apply", action="append", default=[], metavar="OTHER.csv",
                   help="also run the AKF with the model before and after on OTHER.csv (repeatable): "
                        "τ̂_h,act with its bound next to the spring torque, in the report")
    p.add_argument("--max-rows", type=int, default=None, metavar="N",
                   help="a longer log is diagnosed on ten segments of N/10 rows spread over it (memory and "
                        "time bounded; default 100000, 0: the whole log)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")


def run(args) -> int:

    # before any work: DIR can be written and none of its files is an input
    inputs = [args.log, args.config, *args.apply]
    out = check_output_dir("--out", args.out, inputs)
    check_outputs([("--out", out / name) for name in OUTPUTS], inputs)
    for i in map(Path, inputs):
        if i.suffix.lower() == ".png" and i.resolve().parent == out.resolve():
            raise InputError(f"--out {out}: holds the input {i}, and diagnose writes its plots there")
    cfg = load_config(args.config)
    log = read_log(args.log, n=cfg.joints)
    opts = SelectOptions()
    for name, attr in (("min_fraction", "min_fraction"), ("min_effect_rms", "min_effect_rms")):
        v = getattr(args, name)
        if v is not None:
            if not (v >= 0 and v == v and v != float("inf")):
                raise InputError(f"--{name.replace('_', '-')}: must be a finite number >= 0, got {v}")
            setattr(opts, attr, v)
    if args.holdout is not None:
        if not (0.0 <= args.holdout <= 0.5):
            raise InputError(f"--holdout: must be in [0, 0.5] (a share of the log), got {args.holdout}")
        opts.holdout = args.holdout
    if args.cv_blocks is not None:
        if not (args.cv_blocks == 0 or 2 <= args.cv_blocks <= 20):
            raise InputError(f"--cv-blocks: must be 0 (none) or between 2 and 20, got {args.cv_blocks}")
        opts.cv_blocks = args.cv_blocks
    opts.validate_gp_akf = bool(args.gp_akf)
    opts.cv_repeat_selection = bool(args.cv_selection)
    if args.max_rows is not None:
        if args.max_rows < 0:
            raise InputError(f"--max-rows: must be >= 0 (0: the whole log), got {args.max_rows}")
        opts.max_rows = args.max_rows or None
    others = [read_log(p, n=cfg.joints) for p in args.apply]
    for other in others:
        check_columns(other, torque=False)    # an encoder column that reports nothing
    with Progress("diagnose") as progress:
        res = diagnose(log, cfg, out, options=opts, passive=args.passive, plots=not args.no_plots, apply=others,
                       progress=progress)
    print(f"diagnose {log.path}: {res['samples']} samples, residual RMS {fmt(res['residual_rms_before'], '.4g')} -> "
          f"{fmt(res['residual_rms_after'], '.4g')} N m")
    if res["effects_added"]:
        for d in res["effects_added"]:
            ps = ", ".join(f"{k}={fmt(v, '.4g')}" for k, v in d["params"].items())
            share = d["explained_fraction"]
            print(f"  + {d['type']} ({d['side']}): {ps}  explains "
                  f"{fmt(None if share is None else 100 * share, '.1f')} %  [{d['confidence']} confidence]")
    else:
        print("  no undeclared effect found")
    for s in res["statements"][1:]:
        print(f"  ! {s}")
    eb, ea = res["estimate_rmse_before"], res["estimate_rmse_after"]
    print(f"  AKF estimation RMSE {fmt(eb, '.4g')} -> {fmt(ea, '.4g')} N m")
    print(f"  wrote {out}/diagnosis.json, model_augmented.yaml, report.md")
    return 0
