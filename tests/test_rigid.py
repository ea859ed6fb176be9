"""core.rigid: M(q), b(q, q̇), ABA and its derivatives of a URDF against a hand-derived 2-link
planar arm and finite differences; scaled descriptions; refused descriptions."""
import numpy as np
import pytest

from sea_daemon.core.rigid import RigidBody, fit_factors, link_masses, random_factors, scaled_urdf
from sea_daemon.errors import ConfigError

G = 9.81
# two links hanging along −z at q = 0, both rotating about y (a planar arm in the x–z plane)
m1, m2, l1, c1, c2, I1, I2 = 2.0, 1.2, 0.30, 0.14, 0.11, 0.021, 0.009


def arm_urdf(joint2="revolute"):
    return f"""<robot name="arm2">
  <link name="base"/>
  <link name="upper"><inertial><origin xyz="0 0 {-c1}"/><mass value="{m1}"/>
    <inertia ixx="0.01" iyy="{I1}" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="fore"><inertial><origin xyz="0 0 {-c2}"/><mass value="{m2}"/>
    <inertia ixx="0.004" iyy="{I2}" izz="0.004" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="2" effort="50" velocity="5"/></joint>
  <joint name="elbow" type="{joint2}"><parent link="upper"/><child link="fore"/>
    <origin xyz="0 0 {-l1}"/><axis xyz="0 1 0"/><limit lower="0" upper="2.5" effort="30" velocity="5"/></joint>
</robot>"""


def hand_M(q):
    c = np.cos(q[1])
    M11 = I1 + I2 + m1 * c1 ** 2 + m2 * (l1 ** 2 + c2 ** 2 + 2 * l1 * c2 * c)
    M12 = I2 + m2 * (c2 ** 2 + l1 * c2 * c)
    return np.array([[M11, M12], [M12, I2 + m2 * c2 ** 2]])


def hand_bias(q, dq):
    h = m2 * l1 * c2 * np.sin(q[1])
    cor = np.array([-h * (2 * dq[0] * dq[1] + dq[1] ** 2), h * dq[0] ** 2])
    s1, s12 = np.sin(q[0]), np.sin(q[0] + q[1])
    grav = np.array([(m1 * c1 + m2 * l1) * G * s1 + m2 * c2 * G * s12, m2 * c2 * G * s12])
    return cor + grav


@pytest.fixture(scope="module")
def arm():
    return RigidBody(arm_urdf())


STATES = [(np.array([0.3, 0.5]), np.array([0.2, -0.4])), (np.array([-0.8, 1.9]), np.array([-1.5, 2.0])),
          (np.zeros(2), np.zeros(2))]


@pytest.mark.parametrize("q,dq", STATES)
def test_matches_the_hand_derived_two_link_arm(arm, q, dq):
    assert arm.n == 2 and arm.joint_names == ("shoulder", "elbow")
    np.testing.assert_allclose(arm.mass_matrix(q), hand_M(q), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(arm.bias(q, dq), hand_bias(q, dq), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(arm.gravity(q), hand_bias(q, np.zeros(2)), rtol=1e-12, atol=1e-12)
    tau = np.array([1.5, -0.7])
    ddq = np.linalg.solve(hand_M(q), tau - hand_bias(q, dq))
    np.testing.assert_allclose(arm.forward(q, dq, tau), ddq, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(arm.inverse(q, dq, ddq), tau, rtol=1e-10, atol=1e-12)


def fd(fun, x, h=1e-6):
    cols = [(fun(x + h * e) - fun(x - h * e)) / (2 * h) for e in np.eye(len(x))]
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("q,dq", STATES)
def test_forward_derivatives_match_finite_differences(arm, q, dq):
    tau = np.array([0.9, 2.1])
    ddq, d_q, d_v, Minv = arm.forward_derivatives(q, dq, tau)
    np.testing.assert_allclose(ddq, arm.forward(q, dq, tau), rtol=1e-12)
    np.testing.assert_allclose(d_q, fd(lambda x: arm.forward(x, dq, tau), q), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(d_v, fd(lambda x: arm.forward(q, x, tau), dq), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(Minv, np.linalg.inv(hand_M(q)), rtol=1e-10)
    np.testing.assert_allclose(Minv, fd(lambda x: arm.forward(q, dq, x), tau), rtol=1e-6, atol=1e-6)
    b_q, b_v = arm.bias_derivatives(q, dq)
    np.testing.assert_allclose(b_q, fd(lambda x: hand_bias(x, dq), q), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(b_v, fd(lambda x: hand_bias(q, x), dq), rtol=1e-6, atol=1e-6)


def test_configuration_dependent_inertia_enters_the_q_derivative(arm):
    """∂q̈/∂q holds −M⁻¹ (∂M/∂q) q̈: it differs from −M⁻¹ ∂b/∂q when q̈ ≠ 0."""
    q, dq, tau = np.array([0.2, 0.9]), np.zeros(2), np.array([5.0, 3.0])
    ddq, d_q, _, Minv = arm.forward_derivatives(q, dq, tau)
    b_q, _ = arm.bias_derivatives(q, dq)
    dM = fd(lambda x: hand_M(x).ravel(), q).reshape(2, 2, 2)           # dM[i, j, k] = ∂M_ij/∂q_k
    expected = -Minv @ (b_q + np.einsum("ijk,j->ik", dM, ddq))
    np.testing.assert_allclose(d_q, expected, rtol=1e-6, atol=1e-8)
    assert np.max(np.abs(d_q - (-Minv @ b_q))) > 1e-2


def test_scaled_masses_and_lengths(arm):
    heavy = arm.scaled(mass={"upper": 2.0, "fore": 2.0})
    q, dq = np.array([0.4, 0.7]), np.array([0.3, -0.2])
    np.testing.assert_allclose(heavy.mass_matrix(q), 2 * arm.mass_matrix(q), rtol=1e-12)
    np.testing.assert_allclose(heavy.bias(q, dq), 2 * arm.bias(q, dq), rtol=1e-12)
    assert link_masses(scaled_urdf(arm.urdf, mass={"fore": 1.5}))["fore"] == pytest.approx(1.5 * m2)
    # a longer upper arm: elbow further out, its centre of mass further out, inertia × s²
    s = 1.2
    longer = arm.scaled(length={"upper": s})
    M = longer.mass_matrix(np.array([0.0, 0.0]))
    M11 = s ** 2 * I1 + I2 + m1 * (s * c1) ** 2 + m2 * ((s * l1) ** 2 + c2 ** 2 + 2 * s * l1 * c2)
    assert M[0, 0] == pytest.approx(M11, rel=1e-12)
    assert M[1, 1] == pytest.approx(I2 + m2 * c2 ** 2, rel=1e-12)


@pytest.mark.parametrize("text,needle", [
    ("<robot", "not a URDF"),
    ("<link name='a'/>", "root element"),
    (arm_urdf(joint2="continuous"), "'elbow' has type 'continuous'"),
    (arm_urdf().replace(f'<mass value="{m2}"/>', '<mass value="0"/>').replace(f'iyy="{I2}"', 'iyy="0"'),
     "joint(s) elbow move no mass"),
    ('<robot name="r"><link name="a"/></robot>', "no revolute or prismatic"),
])
def test_refused_descriptions_name_the_problem(text, needle):
    with pytest.raises(ConfigError, match="model.urdf") as err:
        RigidBody(text, source="arm.urdf")
    assert needle in str(err.value) and "arm.urdf" in str(err.value)


def test_scaling_refuses_unknown_links_and_bad_factors(arm):
    with pytest.raises(ConfigError, match="no link of that name"):
        scaled_urdf(arm.urdf, mass={"hand": 2.0})
    with pytest.raises(ConfigError, match="factor > 0"):
        scaled_urdf(arm.urdf, length={"upper": -1.0})


def test_armature_adds_to_the_diagonal_and_copies_rebuild(arm):
    import copy
    import pickle
    q, dq, tau = np.array([0.3, 0.8]), np.array([0.1, 0.2]), np.array([1.0, -1.0])
    heavy = arm.with_armature([0.05, 0.0])
    np.testing.assert_allclose(heavy.mass_matrix(q), arm.mass_matrix(q) + np.diag([0.05, 0.0]), rtol=1e-12)
    np.testing.assert_allclose(heavy.forward(q, dq, tau),
                               np.linalg.solve(heavy.mass_matrix(q), tau - heavy.bias(q, dq)), rtol=1e-10)
    for twin in (pickle.loads(pickle.dumps(heavy)), copy.deepcopy(heavy)):
        assert twin.data is not heavy.data
        np.testing.assert_array_equal(twin.forward(q, dq, tau), heavy.forward(q, dq, tau))


def test_random_factors_scale_every_body_within_the_spread(arm):
    mass, length = random_factors(arm.urdf, np.random.default_rng(7), spread=0.3)
    assert set(mass) == set(length) == {"upper", "fore"}
    assert all(0.7 <= v <= 1.3 for v in (*mass.values(), *length.values()))
    assert mass != random_factors(arm.urdf, np.random.default_rng(8), spread=0.3)[0]
    assert random_factors(arm.urdf, np.random.default_rng(7), spread=0.3) == (mass, length)
    plant = arm.scaled(mass, length)
    assert link_masses(plant.urdf)["upper"] == pytest.approx(m1 * mass["upper"])


def test_fit_factors_recovers_a_corrected_body(arm):
    """Torques of a body whose forearm is 30 % heavier and 15 % longer and whose upper arm is 20 %
    lighter: the fit of the declared (nominal) body finds those factors and explains the torques."""
    true = arm.scaled(mass={"fore": 1.3, "upper": 0.8}, length={"fore": 1.15})
    rng = np.random.default_rng(11)
    Q = rng.uniform(-1.0, 2.0, (120, 2))
    DQ = rng.normal(0, 1.5, (120, 2))
    DDQ = rng.normal(0, 8.0, (120, 2))
    TAU = np.array([true.inverse(q, v, a) for q, v, a in zip(Q, DQ, DDQ)])
    fit = fit_factors(arm, ["upper", "fore"], Q, DQ, DDQ, TAU)
    assert fit.mass == pytest.approx({"upper": 0.8, "fore": 1.3}, rel=1e-5)
    assert fit.length == pytest.approx({"upper": 1.0, "fore": 1.15}, rel=1e-5)
    assert np.all(fit.rms_before > 0.1) and np.all(fit.rms_after < 1e-6)
    np.testing.assert_allclose(fit.body.mass_matrix(Q[0]), true.mass_matrix(Q[0]), rtol=1e-5)
    with pytest.raises(ValueError, match="no mass to correct"):
        fit_factors(arm, ["base"], Q, DQ, DDQ, TAU)


def test_fit_factors_fits_nuisance_torques_beside_the_factors(arm):
    """Torques of a scaled body plus viscous friction on each joint: with the friction's regressors
    as nuisance the factors and the friction coefficients are found and the error before is the
    description's with its best friction."""
    true = arm.scaled(mass={"fore": 1.3}, length={"upper": 1.2})
    rng = np.random.default_rng(12)
    Q, DQ, DDQ = rng.uniform(-1.0, 2.0, (120, 2)), rng.normal(0, 1.5, (120, 2)), rng.normal(0, 8.0, (120, 2))
    b = np.array([0.3, 0.2])
    TAU = np.array([true.inverse(q, v, a) for q, v, a in zip(Q, DQ, DDQ)]) + b * DQ
    X = np.zeros((120, 2, 2))
    X[:, 0, 0], X[:, 1, 1] = DQ[:, 0], DQ[:, 1]
    fit = fit_factors(arm, ["upper", "fore"], Q, DQ, DDQ, TAU, nuisance=X)
    assert fit.mass == pytest.approx({"upper": 1.0, "fore": 1.3}, rel=1e-4)
    assert fit.length == pytest.approx({"upper": 1.2, "fore": 1.0}, rel=1e-4)
    np.testing.assert_allclose(fit.coefficients, b, rtol=1e-4)
    assert np.all(fit.rms_before > 0.05) and np.all(fit.rms_after < 1e-6)
    with pytest.raises(ValueError, match="nuisance"):
        fit_factors(arm, ["upper"], Q, DQ, DDQ, TAU, nuisance=X[:10])
