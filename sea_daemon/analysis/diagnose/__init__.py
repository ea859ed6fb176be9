"""The diagnose engine: residuals, candidate effects, their selection and evaluation (no I/O).

:mod:`sea_daemon.apps.diagnose` runs it on a log and writes diagnosis.json,
model_augmented.yaml, report.md and the plots (docs/diagnose.md).
"""
