"""The thresholds of the selection (:mod:`.select`) and the default size floor."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sea_daemon.analysis.diagnose.prepare import MAX_ROWS

#: [N m] the size floor's cap (an effect of 0.01 N m RMS is worth a term on any hardware)
DEFAULT_MIN_EFFECT_RMS = 0.01
#: the size floor relative to the RMS commanded torque of the log
MIN_EFFECT_RMS_REL = 0.1


def size_floor(tau_m: np.ndarray) -> float:
    """Default ``min_effect_rms`` [N m]: a tenth of the RMS commanded torque, at most 0.01 N m
    (an effect much smaller than what the motor applies is not worth a model term; 0.01 N m
    is on an exoskeleton applying newton metres, a tenth of that on a bench applying 0.03)."""
    r = float(np.sqrt(np.mean(np.square(tau_m)))) if np.size(tau_m) else 0.0
    return min(DEFAULT_MIN_EFFECT_RMS, MIN_EFFECT_RMS_REL * r) if r > 0 else DEFAULT_MIN_EFFECT_RMS


@dataclass
class SelectOptions:
    """Thresholds of the selection (see :mod:`.select`)."""

    min_fraction: float = 0.05      # of the initial mean square, per accepted effect ...
    min_fraction_current: float = 0.3   # ... or of the mean square still unexplained
    min_cv_gain: float = 0.05       # relative decrease of the held-out mean square
    folds: int = 5                  # blocked CV segments
    max_effects: int = 6
    #: [N m] smallest effect worth a model term (RMS of its share); None: scaled to the
    #: hardware, a tenth of the RMS commanded torque of the log, at most DEFAULT_MIN_EFFECT_RMS
    min_effect_rms: float | None = None
    ambiguity: float = 0.9          # alternatives explaining ≥ this share of the best's ΔRSS
    ambiguity_bic: float = 10.0     # ... and with a BIC within this of the best's
    structure_threshold: float = 0.10   # structured unexplained share that triggers the warning
    edge: int | None = None         # samples dropped at each end (default: the smoothing window)
    #: samples with |q̇| or |θ̇_m| below this [rad/s] are left out of the fit (stiction: the
    #: smoothed sign of the model cannot follow sticking); default 3 × the model's sign_eps
    v_min: float | None = None
    max_masked: float = 0.5         # never leave out more than this share of the samples
    #: a longer log is diagnosed on segments of it (prepare.segment_log); None: never
    max_rows: int | None = MAX_ROWS
    #: the linear stage fits at most this many samples: a longer log every k-th (Selector.fit_stride)
    max_fit_rows: int | None = 20000
    #: try friction on every sample, set-valued while a side sticks (:mod:`.lowspeed`)
    low_speed: bool = True
    #: an undetermined effect whose parameters correlate beyond this with another chosen one:
    #: the pair is reported and only the sensible one kept
    max_correlation: float = 0.9
    #: share of the log at its end kept back from the fit and scored separately (time-blocked
    #: validation); 0: fit and score the whole log
    holdout: float = 0.25
    #: the validation also repeats the whole selection on the fit block (slower, stricter)
    validate_selection: bool = True
    #: the validation also scores the GP-AKF (learned on the fit block; slower)
    validate_gp_akf: bool = False
    #: contiguous time blocks of the cross-validation that decides which effects are kept
    #: (:mod:`.crossval`); < 2: no cross-validation, every effect found is kept
    cv_blocks: int = 4
    #: the cross-validation also repeats the whole selection (candidates, selection, refinement,
    #: pruning over the remaining blocks) without each block and scores it there (slower)
    cv_repeat_selection: bool = False
