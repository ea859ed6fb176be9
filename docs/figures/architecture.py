"""Draws docs/figures/architecture.png: the layers (imports point down only, checked by
``lint-imports``) and the two data paths, every cycle on the exoskeleton and offline from a log.

``python docs/figures/architecture.py`` (matplotlib) rewrites the PNG beside this file.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyBboxPatch  # noqa: E402

#: (name, one line of what it holds, colour); top to bottom as in .importlinter.  A row of two
#: is a pair of independent layers (neither imports the other).
LAYERS = [
    [("benchmarks/", "research benchmarks: accuracy, assist, bounds, loggp, sim, can_hil (not installed)", "#f0f0f0")],
    [("sea_daemon.apps", "cli (a table of commands; only the chosen one is imported), commands/*,\n"
      "calibration/ (the procedure), diagnose/ (report, plots, files), bench/ (target benchmarks)", "#fde7c8")],
    [("sea_daemon.runtime", "loop: read -> control (write) -> estimate -> fault policy -> publish -> record -> pace;\n"
      "safety, logwriter (own process), bound worker (own process), controller, rig, service", "#e2efd9")],
    [("sea_daemon.hw", "interface (HardwareInterface, Measurement), canopen_hw/_setup/_rx/_positions,\n"
      "sim_hw, bus (virtual | socketcan | remote | ipc), device_model/ (CiA 402, CiA 406)", "#dae8f5")],
    [("sea_daemon.client", "wire formats of the published estimate,\nSubscriber (standard library only)", "#eee")],
    [("sea_daemon.io", "configfile, logcsv (one CSV format),\nmodelfile, gpmodel, scenario, files", "#e9dff0"),
     ("sea_daemon.analysis", "diagnose engine (residuals, candidates,\nselect by stages), noise identification (ALS)", "#f3e3d3")],
    [("sea_daemon.core", "dynamics (the SEA equations once, compiled), model, effects, log schema, kinematics,\n"
      "gp/ (exact, loggp, pack), estimators/ (akf, gpakf, StepRecord), bounds/ (Theorem 1), sim/ (plant, sampling)", "#f7dcdc")],
    [("sea_daemon.errors", "one exception tree; every\nexception carries its Fault", "#ececec"),
     ("sea_daemon.data", "package data: configs/, EDS files,\nthe systemd unit", "#ececec")],
]

CYCLE = [
    "SYNC (0x80) at the absolute deadline",
    "TPDOs: drive 0x6041/0x6077/0x6064, encoder 0x6004",
    "hw.canopen_hw.read() -> Measurement\n(counts -> rad, joint side; fault checks)",
    "runtime.controller.update() -> tau_m;  hw.write() -> RPDO",
    "core estimator.update(q, theta_m, tau_m) -> Estimate\n(tau_h_act_hat, rho_k, sigma, valid)",
    "AKF.step -> StepRecord -> bound worker (shared memory)\n-> Theorem-1 bound_step -> rho_k",
    "fault policy: any fault latches zero torque this cycle",
    "publish: TPDOs of the daemon node, local datagrams",
    "row (core.log schema) -> logwriter (own process) -> run-*.csv",
]
OFFLINE = [
    "LOG.csv -> io.logcsv.read_log -> core.log.MeasuredLog",
    "replay: core estimators over the samples -> EST.csv + JSON",
    "diagnose: analysis.diagnose (residuals -> candidates\n-> selection) -> apps: diagnosis.json, model_augmented.yaml, report",
    "fit / calibrate --fit: apps.calibration (analysis noise,\ndiagnose, residual GP, process noise) -> model.yaml + .npz",
]


def box(ax, x, y, w, h, title, body, colour):
    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.004,rounding_size=0.01",
                                fc=colour, ec="#555", lw=1.0))
    ax.text(x + 0.008, y + h - 0.012, title, fontsize=11, fontweight="bold", va="top")
    ax.text(x + 0.008, y + h - 0.040, body, fontsize=7.6, family="monospace", va="top")


def steps(ax, x, y, items, colour, dy=0.062, arrows=True):
    for i, s in enumerate(items):
        lines = s.count("\n") + 1
        ax.text(x, y, s, fontsize=7.6, family="monospace", va="top",
                bbox=dict(boxstyle="round,pad=0.3", fc=colour, ec="#777"))
        y -= dy + 0.018 * (lines - 1)
        if arrows and i < len(items) - 1:
            ax.annotate("", xy=(x + 0.012, y + 0.012), xytext=(x + 0.012, y + dy - 0.022),
                        arrowprops=dict(arrowstyle="->", color="#555", lw=0.8))
    return y


def main() -> None:
    fig = plt.figure(figsize=(15, 8.4))
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.axis("off")
    x0, w, h, gap = 0.035, 0.52, 0.092, 0.012
    y = 0.95
    for row in LAYERS:
        y -= h
        width = (w - gap * (len(row) - 1)) / len(row)
        for i, (title, body, colour) in enumerate(row):
            box(ax, x0 + i * (width + gap), y, width, h, title, body, colour)
        y -= gap
    ax.annotate("", xy=(0.02, y + gap), xytext=(0.02, 0.95),
                arrowprops=dict(arrowstyle="->", color="#555", lw=1.2))
    ax.text(0.01, (0.95 + y) / 2, "imports point down only (lint-imports)", rotation=90,
            va="center", ha="center", fontsize=9, color="#555")
    ax.text(0.58, 0.95, "Every cycle on the exoskeleton", fontsize=12, fontweight="bold", va="top")
    yb = steps(ax, 0.585, 0.90, CYCLE, "#e2efd9", dy=0.056)
    ax.text(0.58, yb - 0.01, "Offline, from a measured log", fontsize=12, fontweight="bold", va="top")
    steps(ax, 0.585, yb - 0.06, OFFLINE, "#fde7c8", dy=0.06, arrows=False)
    out = Path(__file__).with_suffix(".png")
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
