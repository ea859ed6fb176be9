"""The LoG-GP library face (docs/interfaces.md): ``from sea_daemon.loggp import LoGGP``.

The implementation is :mod:`sea_daemon.core.gp.loggp`.
"""
from sea_daemon.core.gp.loggp import LoGGP

__all__ = ["LoGGP"]
