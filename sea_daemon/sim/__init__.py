"""Offline physics simulation of the SEA exoskeleton with a human forearm (issue 2 item 3).

- :mod:`.plant`     the true plant: nominal model + hidden effects, RK4 at a fine substep
- :mod:`.sensors`   19-bit absolute encoders (quantisation, offsets), motor-torque noise
- :mod:`.scenario`  the scenario YAML schema (``configs/scenarios/*.yaml``)
- :mod:`.runner`    runs a scenario's training and estimation phases to measured logs
"""
from .plant import Plant
from .runner import SimResult, simulate
from .scenario import Scenario, load_scenario
from .sensors import Encoders, load_quantum, motor_quantum

__all__ = ["Plant", "Encoders", "load_quantum", "motor_quantum", "Scenario", "load_scenario",
           "SimResult", "simulate"]
