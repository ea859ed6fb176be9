"""What the selection records: a candidate's fit, a step's table, the selection's result."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sea_daemon.analysis.diagnose.candidates import Candidate


@dataclass
class CandidateFit:
    """One candidate fitted at one step: θ, coefficients, RSS, its design, BIC and CV score."""

    cand: Candidate
    theta: float | None
    beta: np.ndarray               # coefficients of [selected X ..., this X]
    rss: float
    o: np.ndarray | None
    X: np.ndarray
    bic: float = math.inf
    cv: float = math.inf
    params: dict = field(default_factory=dict)
    frac_all: float = 0.0          # share of the initial mean square (whole log) it removes
    #: chosen by the low-speed stage: its parameters are held (``params``) until the refinement
    fixed: bool = False



@dataclass
class SelectionStep:
    """The candidate table of one selection step and the decision taken."""

    step: int
    rows: list[dict]               # one per candidate tried at this step
    chosen: str | None
    reason: str


@dataclass
class Selection:
    """What the selection found: effects with parameters, CIs and shares, and the record."""

    chosen: list[tuple[Candidate, dict]]          # (candidate, natural params)
    ci: list[dict]                                # per chosen: {param: (lo, hi)}
    explained: list[float]
    unexplained: float
    steps: list[SelectionStep]
    alternatives: list[list[str]]
    tau_int: float
    structure: dict
    rss0: float
    rss_final: float
    r_final: np.ndarray
    dropped: list = field(default_factory=list)   # (candidate name, params, CI, why or None) not determined
    corr: np.ndarray | None = None                # correlation of the refined parameters
    param_index: list = field(default_factory=list)   # (effect index, name) per row of corr
    correlated: list = field(default_factory=list)    # pairs resolved (see :func:`.conflict.find_conflict`)
    profiled: set = field(default_factory=set)    # (effect index, param) with a profile interval
