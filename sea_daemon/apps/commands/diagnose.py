"""``sea-daemon diagnose LOG.csv --config MODEL.yaml --out DIR`` (docs/interfaces.md §3, §4)."""
from __future__ import annotations

from pathlib import Path
from sea_daemon.apps.commands import add_log_and_config

NAME = "diagnose"
HELP = "find effects the model lacks in a measured log; write diagnosis.json, model_augmented.yaml, report.md"
ORDER = 40
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
                   help="smallest RMS [N m] of an effect's share worth a model term (default 0.01)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")


def run(args) -> int:
    from sea_daemon.io.configfile import load_config
    from sea_daemon.apps.diagnose import SelectOptions, diagnose
    from sea_daemon.errors import InputError
    from sea_daemon.io.logcsv import read_log

    cfg = load_config(args.config)
    log = read_log(args.log, n=cfg.joints)
    opts = SelectOptions()
    for name, attr in (("min_fraction", "min_fraction"), ("min_effect_rms", "min_effect_rms")):
        v = getattr(args, name)
        if v is not None:
            if not (v >= 0 and v == v and v != float("inf")):
                raise InputError(f"--{name.replace('_', '-')}: must be a finite number >= 0, got {v}")
            setattr(opts, attr, v)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a directory")
    res = diagnose(log, cfg, out, options=opts, passive=args.passive, plots=not args.no_plots)
    print(f"diagnose {args.log}: {res['samples']} samples, residual RMS {res['residual_rms_before']:.4g} -> "
          f"{res['residual_rms_after']:.4g} N m")
    if res["effects_added"]:
        for d in res["effects_added"]:
            ps = ", ".join(f"{k}={v:.4g}" for k, v in d["params"].items())
            print(f"  + {d['type']} ({d['side']}): {ps}  explains {100 * d['explained_fraction']:.1f} %  "
                  f"[{d['confidence']} confidence]")
    else:
        print("  no undeclared effect found")
    for s in res["statements"][1:]:
        print(f"  ! {s}")
    eb, ea = res["estimate_rmse_before"], res["estimate_rmse_after"]
    if eb is not None and ea is not None:
        print(f"  AKF estimation RMSE {eb:.4g} -> {ea:.4g} N m")
    print(f"  wrote {out}/diagnosis.json, model_augmented.yaml, report.md")
    return 0
