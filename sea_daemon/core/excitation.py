"""The calibration motion and its coverage of the GP input z = [q, q̇, q̈].

:class:`MoveSequence` — a reference made of minimum-jerk moves between waypoints with dwells
(the paper's Sec. V-B protocol is the special case of one repeated move).
:func:`excitation` — the calibration motion of ``sea-daemon calibrate``: moves whose
amplitudes, durations (hence speeds and accelerations) and dwell positions are spread over the
joint's declared working range, drawn from a seeded generator (not one repeated move).
:class:`PerJoint` and :func:`excitation_joints` — the same for n joints: one reference per
joint, each joint's moves drawn on its own, so that their combinations spread over the box of
the joints' working ranges.
:class:`Coverage` — an occupancy grid of the (q, q̇, q̈) box of the working range: what share
of it a log's data visit, and, at estimation time, whether a sample's z lies in a visited
cell (or its neighbours).
:class:`JointsCoverage` — the coverage of n joints: one occupancy grid per joint.

Pure: no I/O, no clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sea_daemon.core.control import min_jerk

#: a minimum-jerk move over Δq in T seconds peaks at 1.875 Δq/T (velocity) and 5.774 Δq/T² (accel.)
MJ_PEAK_VEL = 1.875
MJ_PEAK_ACC = 10.0 / math.sqrt(3.0)


@dataclass(frozen=True)
class MoveSequence:
    """Minimum-jerk moves through ``targets`` (rad), move i lasting ``durations[i]`` s and
    followed by a dwell of ``dwells[i]`` s; starts at ``q0``.  ``cyclic``: repeat forever."""

    q0: float
    targets: tuple[float, ...]
    durations: tuple[float, ...]
    dwells: tuple[float, ...]
    cyclic: bool = False
    _t: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        seg = [d + w for d, w in zip(self.durations, self.dwells)]
        object.__setattr__(self, "_t", np.concatenate([[0.0], np.cumsum(seg)]))

    @property
    def duration(self) -> float:
        return float(self._t[-1])

    def reference(self, t: float) -> tuple[float, float, float]:
        """(q_ref, q̇_ref, q̈_ref) at time t [s]."""
        if t <= 0.0:
            return self.q0, 0.0, 0.0
        T = self.duration
        if self.cyclic and t >= T:
            t = math.fmod(t, T)
        if t >= T:
            return self.targets[-1], 0.0, 0.0
        i = int(np.searchsorted(self._t, t, side="right") - 1)
        a = self.q0 if i == 0 else self.targets[i - 1]
        b = self.targets[i]
        tau = t - self._t[i]
        D = self.durations[i]
        if tau >= D:
            return b, 0.0, 0.0
        s, ds, dds = min_jerk(tau / D)
        d = b - a
        return a + d * s, d * ds / D, d * dds / D**2


def paper_moves(q_start: float, q_end: float, move_s: float, moves: int, cyclic: bool = True) -> MoveSequence:
    """The Sec. V-B protocol: ``moves`` minimum-jerk moves q_start → q_end → q_start …"""
    targets = tuple(q_end if i % 2 == 0 else q_start for i in range(moves))
    return MoveSequence(q_start, targets, (move_s,) * moves, (0.0,) * moves, cyclic=cyclic)


@dataclass(frozen=True)
class WorkingRange:
    """The joint's declared working range (calibration section): angles [rad], the fastest
    speed [rad/s] and the largest acceleration [rad/s²] the calibration may use."""

    q_min: float
    q_max: float
    v_max: float = 2.0
    a_max: float = 15.0

    @property
    def width(self) -> float:
        return self.q_max - self.q_min


def excitation(wr: WorkingRange, duration_s: float, seed: int = 0, dwell_share: float = 0.15,
               v_min_share: float = 0.25, q0: float | None = None) -> MoveSequence:
    """The calibration motion: random minimum-jerk moves covering the working range.

    Each move goes to a target drawn uniformly over [q_min, q_max] (every third one to an end
    of the range, so the edges are reached), with a peak speed drawn log-uniformly in
    [v_min_share, 1] × v_max and capped so the peak acceleration stays ≤ a_max (a min-jerk move
    over Δq in T s peaks at 1.875 Δq/T and 5.77 Δq/T²); a share ``dwell_share`` of the time is
    spent at rest (dwells of 0.3–1.5 s), where static friction and gravity are seen alone.
    Moves shorter than 2 % of the range are skipped.  Starts at ``q0`` (default mid-range), e.g.
    where the joint rests.  Seeded: the same seed, the same motion.
    """
    rng = np.random.default_rng(seed)
    q = 0.5 * (wr.q_min + wr.q_max) if q0 is None else float(q0)
    q0 = q
    targets, durs, dwells = [], [], []
    t = 0.0
    k = 0
    while t < duration_s:
        if k % 3 == 2:
            tgt = wr.q_max if q < 0.5 * (wr.q_min + wr.q_max) else wr.q_min
        else:
            tgt = float(rng.uniform(wr.q_min, wr.q_max))
        k += 1
        dq = abs(tgt - q)
        if dq < 0.02 * wr.width:
            continue
        v_peak = wr.v_max * math.exp(rng.uniform(math.log(v_min_share), 0.0))
        T = MJ_PEAK_VEL * dq / v_peak
        T = max(T, math.sqrt(MJ_PEAK_ACC * dq / wr.a_max))       # acceleration cap
        dw = float(rng.uniform(0.3, 1.5)) if rng.random() < dwell_share * 2.5 else 0.0
        targets.append(float(tgt))
        durs.append(float(T))
        dwells.append(dw)
        t += T + dw
        q = tgt
    return MoveSequence(q0, tuple(targets), tuple(durs), tuple(dwells), cyclic=False)


@dataclass(frozen=True)
class PerJoint:
    """The reference of n joints from one reference per joint: ``reference(t) -> (q, q̇, q̈)``, each (n,)."""

    joints: tuple

    @property
    def duration(self) -> float:
        return max(float(getattr(j, "duration", 0.0)) for j in self.joints)

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r = [j.reference(t) for j in self.joints]
        return tuple(np.array([v[i] for v in r]) for i in range(3))


def excitation_joints(ranges, duration_s: float, seed: int = 0, dwell_share: float = 0.15,
                      v_min_share: float = 0.25, q0=None) -> PerJoint:
    """The calibration motion of n joints: :func:`excitation` for each joint's
    :class:`WorkingRange` in ``ranges``, each from its own random stream of ``seed``
    (numpy's SeedSequence spawned per joint), so the joints move and dwell at different times
    and their angles, speeds and accelerations meet in combinations over the whole box of the
    ranges (what couples them: M(q), C(q, q̇) of a URDF).  ``q0``: (n,) start angles (default
    mid-range).  Seeded: the same seed, the same motion."""
    n = len(ranges)
    starts = [None] * n if q0 is None else [float(v) for v in np.broadcast_to(np.asarray(q0, dtype=float), (n,))]
    streams = np.random.SeedSequence(seed).spawn(n)
    return PerJoint(tuple(excitation(wr, duration_s, seed=int(ss.generate_state(1)[0]), dwell_share=dwell_share,
                                     v_min_share=v_min_share, q0=q) for wr, ss, q in zip(ranges, streams, starts)))


class Coverage:
    """Occupancy grid of z = [q, q̇, q̈] over the box of a working range (one joint).

    ``bins`` per axis; velocities over [−v_max, v_max], accelerations over [−a_max, a_max].
    :meth:`add` counts samples; :meth:`report` gives the share of the 3-D box and of the
    (q, q̇) plane that holds at least ``min_count`` samples; :meth:`covered` says whether z
    lies in a visited cell or a neighbour of one (the GP's data reach a length scale or so
    beyond the samples) — what estimation flags when it is false.
    """

    def __init__(self, wr: WorkingRange, bins: int = 10, min_count: int = 3):
        self.wr = wr
        self.bins = int(bins)
        self.min_count = int(min_count)
        self.lo = np.array([wr.q_min, -wr.v_max, -wr.a_max])
        self.hi = np.array([wr.q_max, wr.v_max, wr.a_max])
        self.counts = np.zeros((self.bins,) * 3, dtype=np.int64)
        self._reach = None
        self._lo = [float(v) for v in self.lo]
        self._iw = [1.0 / float(h - l) for l, h in zip(self.lo, self.hi)]

    def _cell(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = (np.atleast_2d(Z)[:, :3] - self.lo) / (self.hi - self.lo)
        inside = np.all((u >= 0.0) & (u < 1.0), axis=1)
        idx = np.clip((u * self.bins).astype(int), 0, self.bins - 1)
        return idx, inside

    def add(self, Z: np.ndarray) -> None:
        idx, inside = self._cell(Z)
        np.add.at(self.counts, tuple(idx[inside].T), 1)
        self._reach = None

    def report(self) -> dict:
        occ = self.counts >= self.min_count
        plane = occ.any(axis=2)
        return {"box_share": float(occ.mean()), "q_qdot_share": float(plane.mean()),
                "q_share": float(plane.any(axis=1).mean()), "bins": self.bins,
                "box": {"q": [float(self.lo[0]), float(self.hi[0])], "dq": [float(self.lo[1]), float(self.hi[1])],
                        "ddq": [float(self.lo[2]), float(self.hi[2])]}}

    def reach(self) -> np.ndarray:
        """Visited cells dilated by one cell in every direction (3×3×3 neighbourhood)."""
        if self._reach is None:
            occ = self.counts >= self.min_count
            r = occ.copy()
            for ax in range(3):
                r = r | np.roll(r, 1, axis=ax) & _edge_mask(r.shape, ax, 1) | np.roll(r, -1, axis=ax) & _edge_mask(r.shape, ax, -1)
            self._reach = r
        return self._reach

    def covered(self, z) -> bool:
        """z (≥ 3 entries [q, q̇, q̈]) in a visited cell or next to one (inside the box).
        Scalar arithmetic: the estimator calls it every step."""
        r = self._reach if self._reach is not None else self.reach()
        b = self.bins
        ijk = []
        for a in range(3):
            u = (float(z[a]) - self._lo[a]) * self._iw[a]
            if not 0.0 <= u < 1.0:
                return False
            ijk.append(min(int(u * b), b - 1))
        return bool(r[ijk[0], ijk[1], ijk[2]])

    def to_dict(self) -> dict:
        return {"q_min": self.wr.q_min, "q_max": self.wr.q_max, "v_max": self.wr.v_max, "a_max": self.wr.a_max,
                "bins": self.bins, "min_count": self.min_count, "counts": self.counts.ravel().tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Coverage":
        c = cls(WorkingRange(d["q_min"], d["q_max"], d["v_max"], d["a_max"]), d["bins"], d["min_count"])
        c.counts = np.asarray(d["counts"], dtype=np.int64).reshape((c.bins,) * 3)
        return c


def _edge_mask(shape, axis: int, shift: int) -> np.ndarray:
    """False where np.roll wrapped around (no wrap-around in the dilation)."""
    m = np.ones(shape, dtype=bool)
    sl = [slice(None)] * len(shape)
    sl[axis] = 0 if shift > 0 else -1
    m[tuple(sl)] = False
    return m


class JointsCoverage:
    """:class:`Coverage` of n joints: one grid per joint over its own (q_j, q̇_j, q̈_j) box.

    ``add(Z)`` takes the pairs z = [q, q̇, q̈] (N, 3n); :meth:`covered` is true when every
    joint's (q_j, q̇_j, q̈_j) lies in a visited cell or next to one; :meth:`report` gives each
    joint's shares (``joints``) and the smallest of them at the top level."""

    def __init__(self, wrs, bins: int = 10, min_count: int = 3):
        self.per_joint = [Coverage(wr, bins, min_count) for wr in wrs]
        self.n = len(self.per_joint)
        self._zj = np.zeros(3)

    def _cols(self, j: int) -> list[int]:
        return [j, self.n + j, 2 * self.n + j]

    def add(self, Z: np.ndarray) -> None:
        Z = np.atleast_2d(Z)
        for j, c in enumerate(self.per_joint):
            c.add(Z[:, self._cols(j)])

    def covered(self, z) -> bool:
        zj = self._zj
        for j, c in enumerate(self.per_joint):
            zj[0], zj[1], zj[2] = z[j], z[self.n + j], z[2 * self.n + j]
            if not c.covered(zj):
                return False
        return True

    def report(self) -> dict:
        per = [c.report() for c in self.per_joint]
        out = {k: min(p[k] for p in per) for k in ("box_share", "q_qdot_share", "q_share")}
        return {**out, "bins": per[0]["bins"], "joints": per}

    def to_dict(self) -> dict:
        return {"joints": [c.to_dict() for c in self.per_joint]}

    @classmethod
    def from_dict(cls, d: dict) -> "JointsCoverage":
        per = [Coverage.from_dict(x) for x in d["joints"]]
        out = cls([c.wr for c in per], per[0].bins, per[0].min_count)
        out.per_joint = per
        return out


def coverage_from_dict(d: dict):
    """:class:`Coverage` or, for n joints (a ``joints`` list), :class:`JointsCoverage` from its ``to_dict``."""
    return JointsCoverage.from_dict(d) if "joints" in d else Coverage.from_dict(d)
