"""Rigid-body dynamics of n coupled joints from a robot description (URDF), with Pinocchio.

The load side of the paper (eq:loadside, Sec. III) for n joints,

    M(q) q̈ + C(q, q̇) + N(q, q̇) + τ_s = τ_ext,

takes its rigid part — the inertia matrix M(q) and the bias b(q, q̇) = C(q, q̇) q̇ + g(q)
(Coriolis, centrifugal and gravitational torques; the paper's C(q, q̇) ∈ R^n) — from the links,
joints, masses and inertias a URDF names.  :class:`RigidBody` wraps a Pinocchio model built from
the URDF's text (the io layer reads the file: this module does no I/O) and gives

* :meth:`~RigidBody.mass_matrix` M(q) (CRBA), :meth:`~RigidBody.bias` b(q, q̇) and
  :meth:`~RigidBody.gravity` g(q);
* :meth:`~RigidBody.inverse` τ = M(q) q̈ + b(q, q̇) (RNEA: the load torque τ_l(z) of
  eq:loadsidewmotor);
* :meth:`~RigidBody.forward` q̈ = M(q)⁻¹ (τ − b(q, q̇)) (ABA: eq:loadside solved for q̈, τ the
  sum of the torques on the load side other than the rigid body's own);
* :meth:`~RigidBody.forward_derivatives` q̈ with ∂q̈/∂q, ∂q̈/∂q̇ and M(q)⁻¹ = ∂q̈/∂τ in one call
  (Pinocchio's analytical ABA derivatives; the filter's linearisation F_k, eq:linearization,
  needs the q and q̇ columns, and G_μ = I_μ M⁻¹ the last);
* :meth:`~RigidBody.bias_derivatives` ∂b/∂q, ∂b/∂q̇ (RNEA derivatives at q̈ = 0).

Joint conventions: the movable joints in the URDF's tree order are the n joints (``revolute``
or ``prismatic``; ``fixed`` joints merge their child link into the parent, so a body strapped to
a link — the human's upper arm on the exoskeleton's — is a link on a fixed joint); ``continuous``
and ``floating`` joints are refused (their configuration is not one angle).  Gravity is −9.81 m/s²
along the URDF's z axis unless given.  :func:`scaled_urdf` gives the same description with link
masses and lengths scaled (a plant that differs from the nominal model; a corrected body),
:func:`random_factors` draws such factors and :func:`fit_factors` finds the factors of declared
bodies (the wearer's arm from anthropometric tables) that explain measured torques.

Pure numerics: no I/O, no clock, no threads.  Each call costs a few µs in Pinocchio plus the
Python call (``sea-daemon bench latency`` measures the filter step that uses them).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from typing import Mapping, NamedTuple

import numpy as np
import pinocchio

from sea_daemon.errors import ConfigError

#: standard gravity [m/s²] along −z of the URDF's base frame
STANDARD_GRAVITY = 9.81

#: URDF joint types that are one of the n joints (one coordinate each)
MOVABLE = ("revolute", "prismatic")


def _symmetric(A: np.ndarray) -> np.ndarray:
    """A full symmetric matrix from one whose upper triangle holds the values (Pinocchio fills
    only the upper triangle of M and M⁻¹ in some versions)."""
    return np.triu(A) + np.triu(A, 1).T


class RigidBody:
    """The rigid multibody of a URDF: M(q), b(q, q̇) = C(q, q̇) q̇ + g(q), ABA and its derivatives.

    ``urdf``: the URDF's text; ``source``: the file it came from (named in errors); ``gravity``:
    the gravity vector [m/s²] in the base frame (default (0, 0, −9.81)); ``armature``: (n,) inertia
    [kg m² or kg] added on the diagonal of M(q) (a declared ``inertia`` effect on the load side).  Raises
    :class:`~sea_daemon.errors.ConfigError` (key ``model.urdf``) for text that is not a URDF, for
    a description without movable joints or with a joint that is not ``revolute``/``prismatic``,
    and for one whose M(q) is singular at q = 0 (a joint that moves no mass).

    Vectors are joint vectors of length :attr:`n` in the order of :attr:`joint_names`.  The
    methods return new arrays (Pinocchio's workspace is reused between calls).
    """

    def __init__(self, urdf: str, *, source: str = "model.urdf", gravity=None, armature=None):
        self.source = source
        self.urdf = urdf
        check_joints(urdf, source)
        try:
            model = pinocchio.buildModelFromXML(urdf)
        except (ValueError, RuntimeError) as exc:
            raise ConfigError(source, "model.urdf", f"not a URDF robot description ({exc})") from None
        if model.nv == 0:
            raise ConfigError(source, "model.urdf", "names no revolute or prismatic joint")
        if gravity is not None:
            g = np.asarray(gravity, dtype=float).reshape(3)
            if not np.all(np.isfinite(g)):
                raise ConfigError(source, "gravity", f"must be 3 finite numbers, got {gravity!r}")
            model.gravity.linear = g
        if armature is not None:
            arm = np.asarray(armature, dtype=float).reshape(-1)
            if arm.shape != (model.nv,) or not np.all(np.isfinite(arm)):
                raise ConfigError(source, "armature", f"must be {model.nv} finite numbers, got {armature!r}")
            model.armature = np.array(model.armature) + arm
        self.model = model
        self.data = model.createData()
        self._pool = None                  # the batched ABA's model and data (forward_columns), made at first use
        #: number of joints n
        self.n = int(model.nv)
        #: the joints' names in the order of the joint vectors
        self.joint_names = tuple(model.names[1:])
        #: position limits [rad or m] of the URDF (±inf where it gives none)
        self.q_min = np.array(model.lowerPositionLimit, dtype=float)
        self.q_max = np.array(model.upperPositionLimit, dtype=float)
        # whether this Pinocchio's bindings return M and M⁻¹ whole (else only their upper triangles)
        probe = np.linspace(0.3, 0.9, self.n)
        Mp = np.array(pinocchio.crba(model, self.data, probe))
        Mi = np.array(pinocchio.computeABADerivatives(model, self.data, probe, probe, probe)[2])
        self._whole = bool(np.array_equal(Mp, Mp.T) and np.array_equal(Mi, Mi.T))
        M0 = self.mass_matrix(np.zeros(self.n))
        if not np.all(np.isfinite(M0)) or np.min(np.linalg.eigvalsh(M0)) <= 1e-12 * max(1.0, np.max(np.abs(M0))):
            weak = [self.joint_names[j] for j in range(self.n) if M0[j, j] <= 0.0] or list(self.joint_names)
            raise ConfigError(source, "model.urdf",
                              f"the inertia matrix M(q) is singular at q = 0: joint(s) {', '.join(weak)} move no mass "
                              "(every movable joint needs a link with mass and inertia beyond it)")

    def __getstate__(self) -> dict:
        """Pickled (and copied) as its description: the copy builds its own Pinocchio model and workspace."""
        return {"urdf": self.urdf, "source": self.source, "gravity": self.gravity_vector, "armature": self.armature}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["urdf"], source=state["source"], gravity=state["gravity"], armature=state["armature"])

    def _q(self, q) -> np.ndarray:
        if type(q) is np.ndarray and q.dtype == np.float64 and q.shape == (self.n,):
            return q
        return np.asarray(q, dtype=float).reshape(self.n)

    def _sym(self, A) -> np.ndarray:
        """A copy of M or M⁻¹ from Pinocchio, whole (:func:`_symmetric` where the bindings give a triangle)."""
        return np.array(A) if self._whole else _symmetric(np.array(A))

    # ------------------------------------------------------------------ the terms of eq:loadside

    def mass_matrix(self, q) -> np.ndarray:
        """M(q) (n, n), symmetric positive definite (CRBA; eq:loadside)."""
        return self._sym(pinocchio.crba(self.model, self.data, self._q(q)))

    def bias(self, q, dq) -> np.ndarray:
        """b(q, q̇) = C(q, q̇) q̇ + g(q) (n,): Coriolis, centrifugal and gravity torques (eq:loadside)."""
        return np.array(pinocchio.nonLinearEffects(self.model, self.data, self._q(q), self._q(dq)))

    def gravity(self, q) -> np.ndarray:
        """g(q) (n,): the gravity torques, b(q, 0)."""
        return np.array(pinocchio.computeGeneralizedGravity(self.model, self.data, self._q(q)))

    def inverse(self, q, dq, ddq) -> np.ndarray:
        """τ_l = M(q) q̈ + b(q, q̇) (n,) (RNEA; τ_l(z) of eq:loadsidewmotor)."""
        return np.array(pinocchio.rnea(self.model, self.data, self._q(q), self._q(dq), self._q(ddq)))

    def forward(self, q, dq, tau) -> np.ndarray:
        """q̈ = M(q)⁻¹ (τ − b(q, q̇)) (n,) (ABA; eq:loadside solved for q̈, τ the other load-side torques)."""
        return np.array(pinocchio.aba(self.model, self.data, self._q(q), self._q(dq), self._q(tau)))

    def forward_many(self, Q, DQ, TAU) -> np.ndarray:
        """:meth:`forward` at each row of the (N, n) arrays Q, DQ, TAU: q̈ (N, n)."""
        Q, DQ, TAU = (np.ascontiguousarray(a, dtype=float).reshape(-1, self.n) for a in (Q, DQ, TAU))
        out = np.empty_like(Q)
        model, data = self.model, self.data
        for i in range(Q.shape[0]):
            out[i] = pinocchio.aba(model, data, Q[i], DQ[i], TAU[i])
        return out

    def forward_columns(self, Q, DQ, TAU, out: np.ndarray) -> np.ndarray:
        """:meth:`forward` at every column of the (n, N) arrays Q, DQ, TAU in one call, into ``out``
        ((n, N), Fortran order: its transpose is q̈ (N, n)); returns ``out``.  Pinocchio's batched
        ABA (``abaInParallel`` on one thread, no thread started): one Python call instead of N,
        in Pinocchio's WORLD convention, equal to :meth:`forward` to rounding."""
        if self._pool is None:
            self._pool = pinocchio.ModelPool(self.model, 1)
        pinocchio.abaInParallel(1, self._pool, Q, DQ, TAU, out)
        return out

    # ------------------------------------------------------------------ derivatives

    def forward_derivatives(self, q, dq, tau):
        """(q̈, ∂q̈/∂q, ∂q̈/∂q̇, M(q)⁻¹) of :meth:`forward` at fixed τ: (n,), (n, n), (n, n), (n, n).

        M⁻¹ is ∂q̈/∂τ; a torque that depends on the state enters through the chain rule,
        ∂q̈/∂x = ∂q̈/∂q ∂q/∂x + ∂q̈/∂q̇ ∂q̇/∂x + M⁻¹ ∂τ/∂x (the filter's F_k, eq:linearization).
        ∂q̈/∂q holds the term −M⁻¹ (∂M/∂q) q̈ of a configuration-dependent inertia.
        """
        q, dq, tau = self._q(q), self._q(dq), self._q(tau)
        ddq_dq, ddq_dv, Minv = pinocchio.computeABADerivatives(self.model, self.data, q, dq, tau)
        return np.array(self.data.ddq), np.array(ddq_dq), np.array(ddq_dv), self._sym(Minv)

    def bias_derivatives(self, q, dq):
        """(∂b/∂q, ∂b/∂q̇), each (n, n), of :meth:`bias` (RNEA derivatives at q̈ = 0)."""
        q, dq = self._q(q), self._q(dq)
        dtau_dq, dtau_dv, _ = pinocchio.computeRNEADerivatives(self.model, self.data, q, dq, np.zeros(self.n))
        return np.array(dtau_dq), np.array(dtau_dv)

    # ------------------------------------------------------------------ the description

    def link_masses(self) -> dict[str, float]:
        """Each link's mass [kg] as the URDF declares it (links without ``<inertial>``: none)."""
        return link_masses(self.urdf)

    def scaled(self, mass: Mapping[str, float] | None = None, length: Mapping[str, float] | None = None) -> "RigidBody":
        """The same body with link masses and lengths scaled (:func:`scaled_urdf`), same gravity."""
        return RigidBody(scaled_urdf(self.urdf, mass, length), source=self.source, gravity=self.gravity_vector,
                         armature=self.armature)

    @property
    def gravity_vector(self) -> np.ndarray:
        """The gravity vector [m/s²] in the base frame."""
        return np.array(self.model.gravity.linear)

    @property
    def armature(self) -> np.ndarray:
        """(n,) the inertia added on the diagonal of M(q) (zeros unless given)."""
        return np.array(self.model.armature)

    def with_armature(self, armature) -> "RigidBody":
        """The same body with ``armature`` (n,) added on the diagonal of M(q)."""
        return RigidBody(self.urdf, source=self.source, gravity=self.gravity_vector,
                         armature=self.armature + np.asarray(armature, dtype=float).reshape(self.n))


# ------------------------------------------------------------------ the URDF's text


def _parse(urdf: str, source: str) -> ET.Element:
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as exc:
        raise ConfigError(source, "model.urdf", f"not a URDF robot description ({exc})") from None
    if root.tag != "robot":
        raise ConfigError(source, "model.urdf", f"not a URDF robot description (root element <{root.tag}>)")
    return root


def check_joints(urdf: str, source: str = "model.urdf") -> list[str]:
    """The movable joints' names in document order; refuses a joint type other than fixed,
    revolute or prismatic, and a number of a link's ``<inertial>`` or of a joint that is not what
    it must be (:func:`_check_inertial`, :func:`_check_joint`): a :class:`~sea_daemon.errors.ConfigError`
    naming the link or joint, the element and the allowed values.  Pinocchio's URDF parser drops
    an ``<inertial>`` it cannot read (a mass of "nan", a missing ``ixz``) and builds the robot
    without that mass, with only a message on the console; it takes a negative mass as given."""
    root = _parse(urdf, source)
    for link in root.iter("link"):
        inertial = link.find("inertial")
        if inertial is not None:
            _check_inertial(inertial, f"link {link.get('name', '')!r}", source)
    names = []
    for j in root.iter("joint"):
        kind = j.get("type", "")
        if kind == "fixed":
            _check_joint(j, False, source)
            continue
        if kind not in MOVABLE:
            raise ConfigError(source, "model.urdf",
                              f"joint {j.get('name')!r} has type {kind!r}: allowed fixed, revolute, prismatic")
        _check_joint(j, True, source)
        names.append(j.get("name", ""))
    return names


def _numbers(el: ET.Element, attr: str, count: int, where: str, source: str, required: bool = True,
             allowed: str = ""):
    """The ``count`` finite numbers of attribute ``attr`` of element ``el`` (None if absent and not
    ``required``), or a ConfigError naming ``where``, the element, the text and ``allowed`` (what
    the numbers must be; default "N finite numbers")."""
    allowed = allowed or f"{count} finite number{'s' if count > 1 else ''}"
    text = el.get(attr)
    if text is None:
        if not required:
            return None
        raise ConfigError(source, "model.urdf", f"{where}: <{el.tag}> has no {attr}=\"...\" (allowed {allowed})")
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ConfigError(source, "model.urdf", f"{where}: <{el.tag} {attr}=\"{text}\">: allowed {allowed}")
    return values


def _check_origin(parent: ET.Element, where: str, source: str) -> None:
    origin = parent.find("origin")
    if origin is not None:
        for attr, unit in (("xyz", "m"), ("rpy", "rad")):
            _numbers(origin, attr, 3, where, source, required=False, allowed=f"3 finite numbers [{unit}]")


INERTIA = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")


def _check_inertial(inertial: ET.Element, where: str, source: str) -> None:
    """A link's ``<inertial>``: a mass >= 0 [kg], the six entries of a positive semi-definite
    inertia tensor [kg m²], an origin of finite numbers."""
    _check_origin(inertial, where, source)
    mass, inertia = inertial.find("mass"), inertial.find("inertia")
    for tag, el in (("mass", mass), ("inertia", inertia)):
        if el is None:
            raise ConfigError(source, "model.urdf", f"{where}: <inertial> has no <{tag}> (a URDF inertial needs "
                                                    "both <mass> and <inertia>)")
    kg = "a finite number >= 0 [kg]"
    if _numbers(mass, "value", 1, where, source, allowed=kg)[0] < 0.0:
        raise ConfigError(source, "model.urdf", f"{where}: <mass value=\"{mass.get('value')}\">: allowed {kg}")
    xx, xy, xz, yy, yz, zz = (_numbers(inertia, a, 1, where, source, allowed="a finite number [kg m^2]")[0]
                              for a in INERTIA)
    tensor = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    if np.min(np.linalg.eigvalsh(tensor)) < -1e-9 * max(1e-12, float(np.max(np.abs(tensor)))):
        raise ConfigError(source, "model.urdf", f"{where}: <inertia> ixx={xx:g} ixy={xy:g} ixz={xz:g} iyy={yy:g} "
                                                f"iyz={yz:g} izz={zz:g} [kg m^2] is not a physical inertia "
                                                "(allowed: a positive semi-definite tensor)")


def _check_joint(joint: ET.Element, movable: bool, source: str) -> None:
    """A joint's numbers: its origin finite; a movable joint's axis finite and not 0, and its
    ``<limit>`` (which the URDF requires of it) with effort and velocity >= 0 and lower <= upper."""
    where = f"joint {joint.get('name', '')!r}"
    _check_origin(joint, where, source)
    if not movable:                       # the URDF parser reads a fixed joint's origin only
        return
    axis = joint.find("axis")
    xyz = None if axis is None else _numbers(axis, "xyz", 3, where, source, required=False,
                                              allowed="3 finite numbers, not all 0")
    if xyz is not None and not any(xyz):
        raise ConfigError(source, "model.urdf", f"{where}: <axis xyz=\"{axis.get('xyz')}\">: allowed 3 finite "
                                                "numbers, not all 0")
    limit = joint.find("limit")
    if limit is None:
        raise ConfigError(source, "model.urdf", f"{where}: has no <limit> (a revolute or prismatic joint "
                                                "needs lower, upper, effort and velocity)")
    values = {a: _numbers(limit, a, 1, where, source, required=a in ("effort", "velocity"),
                          allowed="a finite number" + (" >= 0" if a in ("effort", "velocity") else ""))
              for a in ("lower", "upper", "effort", "velocity")}
    for a in ("effort", "velocity"):
        if values[a][0] < 0.0:
            raise ConfigError(source, "model.urdf", f"{where}: <limit {a}=\"{limit.get(a)}\">: allowed a finite "
                                                    "number >= 0")
    lo, hi = (values[a][0] if values[a] else 0.0 for a in ("lower", "upper"))
    if lo > hi:
        raise ConfigError(source, "model.urdf", f"{where}: <limit lower=\"{limit.get('lower')}\" "
                                                f"upper=\"{limit.get('upper')}\">: allowed lower <= upper")


def link_masses(urdf: str, source: str = "model.urdf") -> dict[str, float]:
    """Each link's declared mass [kg] by name (links with an ``<inertial><mass>``)."""
    out = {}
    for link in _parse(urdf, source).iter("link"):
        m = link.find("inertial/mass")
        if m is not None:
            out[link.get("name", "")] = float(m.get("value", "nan"))
    return out


def _scale_xyz(el: ET.Element | None, s: float) -> None:
    if el is not None and el.get("xyz") is not None:
        el.set("xyz", " ".join(repr(float(v) * s) for v in el.get("xyz").split()))


def scaled_urdf(urdf: str, mass: Mapping[str, float] | None = None, length: Mapping[str, float] | None = None,
                source: str = "model.urdf") -> str:
    """The URDF text with link masses and lengths scaled.

    ``mass``: link name → factor on its mass and inertia tensor (a body of the same shape, heavier);
    ``length``: link name → factor on its length: the centre of mass and the origins of the joints
    it carries move out by the factor, its inertia about the centre of mass by the factor squared
    (a longer body of the same mass).  Factors must be positive; unknown link names are refused.
    """
    root = _parse(urdf, source)
    links = {link.get("name"): link for link in root.iter("link")}
    for what, table in (("mass", mass or {}), ("length", length or {})):
        for name, s in table.items():
            if name not in links:
                raise ConfigError(source, f"{what}[{name}]", f"no link of that name; links: {', '.join(links)}")
            if not (math.isfinite(float(s)) and float(s) > 0.0):
                raise ConfigError(source, f"{what}[{name}]", f"must be a factor > 0, got {s!r}")
    for name, s in (mass or {}).items():
        inertial = links[name].find("inertial")
        if inertial is None:
            continue
        m = inertial.find("mass")
        m.set("value", repr(float(m.get("value")) * float(s)))
        _scale_inertia(inertial.find("inertia"), float(s))
    for name, s in (length or {}).items():
        inertial = links[name].find("inertial")
        if inertial is not None:
            _scale_xyz(inertial.find("origin"), float(s))
            _scale_inertia(inertial.find("inertia"), float(s) ** 2)
        for j in root.iter("joint"):
            parent = j.find("parent")
            if parent is not None and parent.get("link") == name:
                _scale_xyz(j.find("origin"), float(s))
    return ET.tostring(root, encoding="unicode")


def random_factors(urdf: str, rng: np.random.Generator, spread: float = 0.3,
                   source: str = "model.urdf") -> tuple[dict[str, float], dict[str, float]]:
    """(mass, length) factors, uniform in [1 − spread, 1 + spread], one each for every link with a
    mass (document order, two draws per link from ``rng``): a random plant around the description
    for :func:`scaled_urdf` / :meth:`RigidBody.scaled` (e.g. link lengths and masses ±30 %)."""
    if not 0.0 <= spread < 1.0:
        raise ValueError(f"spread must be in [0, 1), got {spread!r}")
    mass, length = {}, {}
    for name in link_masses(urdf, source):
        mass[name], length[name] = (float(v) for v in rng.uniform(1.0 - spread, 1.0 + spread, 2))
    return mass, length


class BodyFit(NamedTuple):
    """What :func:`fit_factors` found: the factors per link, the RMS torque error [N m] per joint
    of the description as given and of the corrected one, and the corrected body."""

    mass: dict[str, float]
    length: dict[str, float]
    rms_before: np.ndarray
    rms_after: np.ndarray
    body: "RigidBody"
    #: the coefficients of the ``nuisance`` regressors fitted with the factors (empty without)
    coefficients: np.ndarray = np.zeros(0)


def fit_factors(body: RigidBody, links, Q, DQ, DDQ, TAU, *, lengths: bool = True,
                limits: tuple[float, float] = (0.5, 2.0), nuisance: np.ndarray | None = None) -> BodyFit:
    """Correct a declared body from data: the mass (and, with ``lengths``, length) factors of
    :func:`scaled_urdf` for the named ``links`` that best explain the torques on the rigid body,
    least squares over the samples of τ = M(q) q̈ + C(q, q̇) q̇ + g(q) (eq:loadside; RNEA).

    ``Q, DQ, DDQ, TAU``: (N, n) joint angles, velocities, accelerations and the torque on the rigid
    body at each sample (e.g. eq:loadsidewmotor's τ_l from the motor side with a passive subject).
    Each factor stays within ``limits``; a mass and length of one link are told apart by its
    gravity (∝ m l) and inertia (∝ m l²), so the data must move the link with some acceleration;
    links on one moving body (fixed to each other: the wearer's forearm on the exoskeleton's) act
    as one, so name one of them.
    ``nuisance``: (N, n, p) regressors of torques the body does not hold (e.g. each joint's
    viscous and Coulomb friction, ``q̇_j`` and ``sign(q̇_j)`` in joint j's row), their p
    coefficients fitted with the factors (linear, unbounded), so that they do not bend the
    factors; the RMS errors before and after both include them at their best coefficients.
    Raises ValueError for a link without a mass or data of the wrong shape.
    """
    # local import: scipy.optimize loads in 0.2 s; only a correction of the body needs it
    from scipy.optimize import least_squares
    masses = link_masses(body.urdf, body.source)
    for name in links:
        if name not in masses:
            raise ValueError(f"link {name!r} has no mass to correct; links with one: {', '.join(masses)}")
    Q, DQ, DDQ, TAU = (np.ascontiguousarray(a, dtype=float).reshape(-1, body.n) for a in (Q, DQ, DDQ, TAU))
    if not (Q.shape == DQ.shape == DDQ.shape == TAU.shape) or not np.all(np.isfinite([Q, DQ, DDQ, TAU])):
        raise ValueError(f"Q, DQ, DDQ, TAU must be finite (N, {body.n}) arrays of one N")
    links = list(links)
    k = len(links)
    m = 2 * k if lengths else k
    X = np.zeros((*Q.shape, 0)) if nuisance is None else np.asarray(nuisance, dtype=float)
    if X.ndim != 3 or X.shape[:2] != Q.shape or not np.all(np.isfinite(X)):
        raise ValueError(f"nuisance must be a finite (N, {body.n}, p) array of the samples' N = {Q.shape[0]}")
    X = X.reshape(Q.size, -1)

    def scaled(p):
        f = np.exp(p[:m])
        return body.scaled(dict(zip(links, f[:k])), dict(zip(links, f[k:m])) if lengths else None)

    def residual(p):
        b = scaled(p)
        r = np.concatenate([b.inverse(Q[i], DQ[i], DDQ[i]) - TAU[i] for i in range(Q.shape[0])])
        return r + X @ p[m:]

    lo, hi = np.log(limits[0]), np.log(limits[1])
    p0 = np.zeros(m + X.shape[1])
    if X.shape[1]:
        # the nuisance's best coefficients for the description as given: the error before
        p0[m:] = np.linalg.lstsq(X, -residual(p0), rcond=None)[0]
    bounds = (np.r_[np.full(m, lo), np.full(X.shape[1], -np.inf)], np.r_[np.full(m, hi), np.full(X.shape[1], np.inf)])
    sol = least_squares(residual, p0, bounds=bounds, x_scale=1.0)
    f = np.exp(sol.x[:m])
    fitted = scaled(sol.x)

    def rms(r):
        return np.sqrt(np.mean(r.reshape(-1, body.n) ** 2, axis=0))
    return BodyFit(dict(zip(links, map(float, f[:k]))), dict(zip(links, map(float, f[k:]))) if lengths else {},
                   rms(residual(p0)), rms(sol.fun), fitted, sol.x[m:].copy())


def _scale_inertia(el: ET.Element | None, s: float) -> None:
    if el is None:
        return
    for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
        if el.get(k) is not None:
            el.set(k, repr(float(el.get(k)) * s))
