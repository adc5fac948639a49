"""MuJoCo spacecraft: conservation, agreement with Euler's equations, agility, limits, snapshots."""

import pickle

import mujoco
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from envs.spacecraft import Spacecraft, pyramid_wheel_axes
from startracker.rotations import quat_angle_between, quat_multiply, quat_normalize, quat_to_matrix

DEG = np.pi / 180.0

FULL_INERTIA = np.array([[6.0, 0.3, -0.2], [0.3, 5.0, 0.1], [-0.2, 0.1, 4.5]])


def euler_rhs(inertia, axes, i_s, torques):
    """Independent rigid body + wheels equations (body frame), state [q(4), ω(3), Ω(n)].

    J ω̇ + I_s A Ω̇ = -ω × (J ω + I_s A Ω);   I_s (a_iᵀ ω̇ + Ω̇_i) = τ_i;   q̇ = ½ q ⊗ (0, ω).
    """
    a = np.asarray(axes).T  # (3, n)
    n = a.shape[1]
    mass = np.block([[inertia, i_s * a], [i_s * a.T, i_s * np.eye(n)]])

    def rhs(_t, y):
        q, w, om = y[:4], y[4:7], y[7:]
        h = inertia @ w + i_s * a @ om
        acc = np.linalg.solve(mass, np.concatenate([-np.cross(w, h), torques]))
        qdot = 0.5 * quat_multiply(q, np.concatenate([[0.0], w]))
        return np.concatenate([qdot, acc])

    return rhs


@pytest.mark.parametrize(
    "kwargs",
    [dict(), dict(n_wheels=3), dict(inertia_kg_m2=FULL_INERTIA), dict(wheel_viscous_Nm_s=1e-4, wheel_friction_Nm=2e-3)],
    ids=["pyramid", "three", "full-inertia", "friction"],
)
def test_angular_momentum_conserved_60s_with_internal_torques(kwargs):
    sc = Spacecraft(**kwargs)
    rng = np.random.default_rng(1)
    n = sc.n_wheels
    sc.set_state(quat_normalize([0.9, 0.1, -0.3, 0.2]), [0.1, -0.2, 0.05], rng.uniform(-300, 300, n))
    h0 = sc.total_angular_momentum_world
    worst = 0.0
    for _ in range(600):
        sc.apply_wheel_torque(rng.uniform(-0.5, 0.5, n))
        sc.step(0.1)
        worst = max(worst, np.linalg.norm(sc.total_angular_momentum_world - h0) / np.linalg.norm(h0))
    assert worst < 1e-9
    # the torques really did something: the momentum moved between bus and wheels
    assert np.linalg.norm(sc.total_angular_momentum_body - (sc.inertia_kg_m2 @ sc.omega_body)) > 0.5
    assert abs(sc.time_s - 60.0) < 1e-9


def test_angular_momentum_matches_mujoco_subtree():
    """Our H = R (J ω + I_s A Ω) agrees with MuJoCo's own subtree angular momentum."""
    sc = Spacecraft(inertia_kg_m2=FULL_INERTIA)
    sc.set_state(quat_normalize([0.3, -0.5, 0.7, 0.1]), [0.2, 0.1, -0.3], [100.0, -50.0, 400.0, -250.0])
    mujoco.mj_forward(sc.model, sc.data)
    mujoco.mj_subtreeVel(sc.model, sc.data)
    np.testing.assert_allclose(sc.total_angular_momentum_world, sc.data.subtree_angmom[1], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs,torques",
    [
        (dict(), np.zeros(4)),
        (dict(inertia_kg_m2=FULL_INERTIA), np.zeros(4)),
        (dict(n_wheels=3), np.array([0.05, -0.1, 0.02])),
        (dict(inertia_kg_m2=FULL_INERTIA), np.array([0.1, -0.05, 0.02, 0.08])),
    ],
    ids=["free-pyramid", "free-full-inertia", "torqued-three", "torqued-full-inertia"],
)
def test_accessors_match_independent_euler_integration(kwargs, torques):
    sc = Spacecraft(**kwargs)
    q0 = quat_normalize([0.2, 0.5, -0.4, 0.7])
    w0 = np.array([0.3, -0.25, 0.4])
    om0 = np.linspace(-200.0, 150.0, sc.n_wheels)
    sc.set_state(q0, w0, om0)
    sc.apply_wheel_torque(torques)
    t_end = 20.0
    sc.step(t_end)
    rhs = euler_rhs(sc.inertia_kg_m2, sc.wheel_axes_body, sc.wheel_inertia_kg_m2, torques)
    sol = solve_ivp(rhs, (0, t_end), np.concatenate([q0, w0, om0]), method="DOP853", rtol=1e-12, atol=1e-12)
    y = sol.y[:, -1]
    assert quat_angle_between(sc.q_body_to_icrs, y[:4] / np.linalg.norm(y[:4])) < 1e-8
    np.testing.assert_allclose(sc.omega_body, y[4:7], atol=1e-8)
    np.testing.assert_allclose(sc.wheel_speeds_rad_s, y[7:], atol=1e-6)
    # the body really tumbled (not a trivial pure spin)
    assert quat_angle_between(q0, sc.q_body_to_icrs) > 0.5
    assert np.linalg.norm(sc.omega_body - w0) > 0.02
    # momentum accessor: world momentum = R(q) (J ω + h_w) with h_w from the reference integration
    h_ref = quat_to_matrix(y[:4] / np.linalg.norm(y[:4])) @ (
        sc.inertia_kg_m2 @ y[4:7] + sc.wheel_inertia_kg_m2 * sc.wheel_axes_body.T @ y[7:]
    )
    np.testing.assert_allclose(sc.total_angular_momentum_world, h_ref, atol=1e-7)


@pytest.mark.parametrize("n_wheels", [3, 4])
@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, -1, 1]])
def test_20_deg_per_s_slew_rate_reachable(n_wheels, axis):
    """A saturated rate loop reaches and holds 20 deg/s about any axis with the default wheels."""
    sc = Spacecraft(n_wheels=n_wheels)
    target = 20.0 * DEG * np.asarray(axis, float) / np.linalg.norm(axis)
    j = sc.inertia_kg_m2
    reached = None
    for k in range(200):  # 20 s
        w = sc.omega_body
        # rate loop with gyroscopic feed-forward: J ω̇ = u_bus - ω × H
        u_bus = j @ (2.0 * (target - w)) + np.cross(w, sc.total_angular_momentum_body)
        sc.apply_wheel_torque(sc.body_torque_to_wheel_torque(u_bus))
        sc.step(0.1)
        if reached is None and np.linalg.norm(sc.omega_body - target) < 0.05 * DEG:
            reached = sc.time_s
    assert reached is not None and reached < 12.0
    np.testing.assert_allclose(sc.omega_body, target, atol=0.01 * DEG)
    assert np.all(np.abs(sc.wheel_speeds_rad_s) < sc.wheel_max_speed_rad_s)


def test_wheel_speed_limit_holds_and_torque_is_clipped():
    sc = Spacecraft(n_wheels=3, wheel_max_speed_rad_s=100.0, wheel_max_torque_Nm=0.5)
    applied = sc.apply_wheel_torque([10.0, 0.0, 0.0])
    np.testing.assert_array_equal(applied, [0.5, 0.0, 0.0])
    sc.step(1.0)
    # unsaturated: bus x-rate from momentum exchange, wheel x-speed from I_s (a·ω̇ + Ω̇) = τ
    j, i_s = sc.inertia_kg_m2[0, 0], sc.wheel_inertia_kg_m2
    np.testing.assert_allclose(sc.omega_body[0], -0.5 * 1.0 / (j - i_s), rtol=1e-9)
    for _ in range(30):  # 0.5 N m / 0.01 kg m² = 50 rad/s²: the 100 rad/s limit is hit after ~2 s
        sc.step(0.1)
        assert sc.wheel_speeds_rad_s[0] <= 100.0 * (1 + 1e-3)
    assert sc.wheel_speeds_rad_s[0] > 99.0
    w_sat = sc.omega_body.copy()
    sc.step(1.0)
    # saturated wheel: no more torque, the bus stops accelerating
    np.testing.assert_allclose(sc.omega_body, w_sat, atol=1e-6)
    # torque of the opposite sign is still applied at the limit
    sc.apply_wheel_torque([-0.5, 0.0, 0.0])
    sc.step(0.5)
    assert sc.wheel_speeds_rad_s[0] < 90.0


def test_external_torque_changes_world_momentum_by_torque_times_time():
    sc = Spacecraft()
    sc.set_state(quat_normalize([1, 0.2, 0, -0.1]), [0.05, 0.0, -0.1], [50.0, 0.0, -80.0, 10.0])
    h0 = sc.total_angular_momentum_world
    tau = np.array([1e-3, -2e-3, 5e-4])
    sc.set_external_torque_world(tau)
    sc.apply_wheel_torque([0.1, -0.1, 0.05, 0.0])
    sc.step(10.0)
    np.testing.assert_allclose(sc.total_angular_momentum_world - h0, tau * 10.0, atol=1e-10)


def test_body_torque_to_wheel_torque_produces_the_body_torque():
    sc = Spacecraft()
    u = np.array([0.1, -0.2, 0.05])
    tau = sc.body_torque_to_wheel_torque(u)
    np.testing.assert_allclose(-sc.wheel_axes_body.T @ tau, u, atol=1e-12)
    big = sc.body_torque_to_wheel_torque(100 * u)  # saturates: direction kept, largest motor at its limit
    b = -sc.wheel_axes_body.T @ big
    np.testing.assert_allclose(b / np.linalg.norm(b), u / np.linalg.norm(u), atol=1e-12)
    assert np.isclose(np.max(np.abs(big) / sc.wheel_max_torque_Nm), 1.0)


def test_pyramid_axes_balanced_envelope():
    a = pyramid_wheel_axes()
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0)
    # momentum envelope: sum of |a_i . e| is the capacity about body axis e for equal wheels
    cap = np.abs(a).sum(axis=0)
    np.testing.assert_allclose(cap, cap[0], rtol=1e-12)


def test_snapshot_restore_and_pickle_are_exact():
    sc = Spacecraft(inertia_kg_m2=FULL_INERTIA, wheel_friction_Nm=1e-3)
    sc.set_state(quat_normalize([1, 0.3, -0.2, 0.1]), [0.1, 0.2, -0.1], [10.0, 200.0, -30.0, 5.0], time_s=3.0)
    sc.apply_wheel_torque([0.2, -0.1, 0.3, -0.4])
    sc.set_external_torque_world([1e-4, 0, 0])
    sc.step(0.5)
    snap = sc.get_state()
    clone = pickle.loads(pickle.dumps(sc))
    sc.step(2.0)
    after = sc.get_state()
    clone.step(2.0)
    np.testing.assert_array_equal(clone.get_state(), after)
    sc.restore_state(snap)
    sc.step(2.0)
    np.testing.assert_array_equal(sc.get_state(), after)
    assert snap.shape == (sc.state_size,)


def test_bad_input_raises_with_argument_name():
    with pytest.raises(ValueError, match="inertia_kg_m2"):
        Spacecraft(inertia_kg_m2=[1.0, 1.0, 5.0])  # violates A + B >= C
    with pytest.raises(ValueError, match="inertia_kg_m2"):
        Spacecraft(inertia_kg_m2=[[1, 2, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(ValueError, match="inertia_kg_m2"):
        Spacecraft(inertia_kg_m2=[0.01, 0.01, 0.01])  # cannot hold the wheels
    with pytest.raises(ValueError, match="n_wheels"):
        Spacecraft(n_wheels=5)
    with pytest.raises(ValueError, match="wheel_max_torque_Nm"):
        Spacecraft(wheel_max_torque_Nm=-1.0)
    with pytest.raises(ValueError, match="wheel_axes_body"):
        Spacecraft(n_wheels=3, wheel_axes_body=[[1, 0, 0], [0, 1, 0], [1, 1, 0]])
    with pytest.raises(ValueError, match="timestep_s"):
        Spacecraft(timestep_s=0.0)
    sc = Spacecraft()
    with pytest.raises(ValueError, match="torque_Nm"):
        sc.apply_wheel_torque([0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="torque_Nm"):
        sc.apply_wheel_torque([np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="duration_s"):
        sc.step(0.015)
    with pytest.raises(ValueError, match="duration_s"):
        sc.step(-0.1)
    with pytest.raises(ValueError, match="q_body_to_icrs"):
        sc.set_state([0, 0, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="wheel_speeds_rad_s"):
        sc.set_state([1, 0, 0, 0], [0, 0, 0], [1e4, 0, 0, 0])
    with pytest.raises(ValueError, match="time_s"):
        sc.set_state([0, 1, 0, 0], [1, 0, 0], [10.0, 0, 0, 0], time_s=np.nan)
    with pytest.raises(ValueError, match="state"):
        sc.restore_state(np.zeros(3))
    # the rejected calls left the state untouched
    np.testing.assert_array_equal(sc.q_body_to_icrs, [1, 0, 0, 0])
    np.testing.assert_array_equal(sc.wheel_speeds_rad_s, 0.0)
    np.testing.assert_array_equal(sc.commanded_wheel_torque_Nm, 0.0)
    assert sc.time_s == 0.0


def test_bearing_friction_decelerates_wheel_as_coulomb_plus_viscous():
    """Wheel on the body x axis: relative deceleration = τ_f (1/I_s + 1/(J_xx - I_s)), τ_f = c + b Ω."""
    c, b = 2e-3, 1e-4
    sc = Spacecraft(n_wheels=3, wheel_friction_Nm=c, wheel_viscous_Nm_s=b)
    sc.set_state([1, 0, 0, 0], [0, 0, 0], [300.0, 0.0, 0.0])
    i_s, j = sc.wheel_inertia_kg_m2, sc.inertia_kg_m2[0, 0]
    k = 1.0 / i_s + 1.0 / (j - i_s)
    # closed form of dΩ/dt = -k (c + b Ω)
    t = 5.0
    expected = (300.0 + c / b) * np.exp(-k * b * t) - c / b
    sc.step(t)
    assert abs(sc.wheel_speeds_rad_s[0] - expected) < 0.02
    # Coulomb friction stops the wheel and holds it (no creep, no reversal)
    sc.set_state([1, 0, 0, 0], [0, 0, 0], [0.05, 0.0, 0.0])
    sc.step(1.0)
    assert abs(sc.wheel_speeds_rad_s[0]) < 1e-6


def test_step_recording_equals_stepping_and_reading():
    """The truth history the env hands to the avionics: the same states as step() then reading, bit for bit,
    on the fast path and when a wheel hits its speed limit."""
    for torque, speed0 in ((0.05, 0.0), (0.5, 595.0)):
        a, b = Spacecraft(), Spacecraft()
        for sc in (a, b):
            sc.set_state([0.9, 0.1, -0.2, 0.3], [0.01, -0.02, 0.03], np.full(4, speed0), time_s=1.0)
            sc.apply_wheel_torque(np.full(4, torque))
        t_rec, q_rec = a.step_recording(0.01, 10)
        t_ref, q_ref = [], []
        for _ in range(10):
            b.step(0.01)
            t_ref.append(b.time_s)
            q_ref.append(b.q_body_to_icrs)
        assert np.array_equal(t_rec, t_ref) and np.array_equal(q_rec, q_ref)
        assert np.array_equal(a.get_state(), b.get_state())
        assert t_rec.shape == (10,) and q_rec.shape == (10, 4) and np.isclose(t_rec[-1], 1.1)
        # include_start: the state before the span as row 0, then the same rows
        c = Spacecraft()
        c.set_state([0.9, 0.1, -0.2, 0.3], [0.01, -0.02, 0.03], np.full(4, speed0), time_s=1.0)
        c.apply_wheel_torque(np.full(4, torque))
        t0, q0 = c.time_s, c.q_body_to_icrs
        t_all, q_all = c.step_recording(0.01, 10, include_start=True)
        assert t_all.shape == (11,) and q_all.shape == (11, 4)
        assert t_all[0] == t0 == 1.0 and np.array_equal(q_all[0], q0)
        assert np.array_equal(t_all[1:], t_ref) and np.array_equal(q_all[1:], q_ref)
    with pytest.raises(ValueError, match="n_steps"):
        a.step_recording(0.01, 0)
    with pytest.raises(ValueError, match="substep_s"):
        a.step_recording(-0.01, 3)
