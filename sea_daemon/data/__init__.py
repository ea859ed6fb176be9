"""The package data of sea-daemon: the example model configurations and scenarios
(``configs/``), the CANopen EDS files (``configs/eds/``) and the systemd unit (``systemd/``).

Found with :mod:`importlib.resources`, so they are there in a wheel as in a checkout (where the
top-level ``configs`` and ``systemd`` are links to these folders).
"""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def path(*parts: str) -> Path:
    """The file or folder ``parts`` below the package data, e.g. ``path("configs", "exo_1dof.yaml")``."""
    return Path(str(files(__name__).joinpath(*parts)))
