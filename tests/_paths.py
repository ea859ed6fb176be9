"""Where the tests find the checkout they run from (the tests' data and the package's)."""
from pathlib import Path


def repo_root() -> Path:
    """The checkout: ``tests/`` lives in it, ``configs`` and ``systemd`` link to the package data."""
    return Path(__file__).resolve().parent.parent
