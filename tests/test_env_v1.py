"""AgileSlew-v1: body-torque allocation against the wheel axes, observation bounds, each reward term as documented,
divergence termination, the ideal sensor, and -v0 untouched by it."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs
from envs.agile_slew_v1 import BodyTorqueAllocator
from startracker.rotations import quat_angle_between, quat_conjugate, quat_from_rotvec, quat_multiply, quat_to_rotvec

V1 = "startracker/AgileSlew-v1"


def pd_action(obs, env):
    """A rate-limited PD on the v1 observation (decoded with the documented scales): a controller that settles."""
    u = env.unwrapped
    e = obs[0:3].astype(np.float64) * math.pi
    w = obs[6:9].astype(np.float64) * u.max_rate_rad_s
    w_ref = np.clip(e / 1.8, -0.3, 0.3)
    tau = u.spacecraft.inertia_kg_m2 @ (1.8 * (w_ref - w))
    return np.clip(tau / 0.5, -1.0, 1.0).astype(np.float32)


def test_registration_sets_the_step_limit_from_the_slew_range():
    env = gym.make(V1)
    assert env.spec.max_episode_steps == envs.V1_MAX_EPISODE_STEPS
    u = env.unwrapped
    # twice a bang-coast-bang 180° slew at 20°/s and the weakest axis' 0.5 N m / 6 kg m², plus 2 s hold and 5 s
    accel = math.degrees(0.5 / 6.0)
    t = 2 * (180 / 20 + 20 / accel) + 2 + 5
    assert u.max_episode_s == pytest.approx(math.ceil(t / 0.1) * 0.1)
    assert env.spec.max_episode_steps == round(u.max_episode_s / 0.1)
    env.close()


@pytest.mark.parametrize("kwargs", [{}, {"action_curve": "cubic", "ideal_attitude_noise_arcsec": (0.5, 20.0)}])
def test_check_env_with_the_ideal_sensor(kwargs):
    env = gym.make(V1, sensor="ideal", **kwargs).unwrapped
    check_env(env, skip_render_check=True)


def test_ideal_sensor_is_reproducible_and_noisy_as_stated():
    def run(seed):
        env = gym.make(V1, sensor="ideal")
        obs, info = env.reset(seed=seed)
        out, errs = [obs], []
        rng = np.random.default_rng(seed)
        for _ in range(30):
            obs, r, *_ , info = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
            out.append(obs)
            errs.append(info["attitude_error_arcsec"])
        return np.array(out), np.array(errs)

    o1, e1 = run(3)
    o2, e2 = run(3)
    assert np.array_equal(o1, o2) and np.array_equal(e1, e2)
    # 5″ per axis, white: the angle is Maxwell-distributed with RMS 5·√3″
    rms = math.sqrt(np.mean(e1**2))
    assert 5 * math.sqrt(3) * 0.6 < rms < 5 * math.sqrt(3) * 1.4


def test_ideal_sensor_repeats_an_episode_bit_for_bit_on_the_same_instance():
    """A second reset with the same seed on one instance gives the trajectory of a fresh instance, bit for bit
    (MuJoCo's warm start and the wheel angles of the previous episode must not leak into the arithmetic)."""
    kwargs = dict(sensor="ideal", action_curve="cubic", ideal_attitude_noise_arcsec=(0.5, 20.0))
    actions = np.random.default_rng(5).uniform(-0.3, 0.3, (40, 3)).astype(np.float32)

    def run(env, seed):
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for a in actions:
            obs, r, term, trunc, info = env.step(a)
            out.append(np.concatenate([obs, info["omega_true_body"], info["q_true"], [r]]))
        return out

    env = gym.make(V1, **kwargs)
    run(env, 8)
    again = run(env, 7)
    fresh = run(gym.make(V1, **kwargs), 7)
    assert all(np.array_equal(a, b) for a, b in zip(again, fresh))


def test_observation_error_is_the_shortest_rotation_to_the_target_and_within_bounds():
    env = gym.make(V1, sensor="ideal", slew_angle_deg_range=(170.0, 180.0))
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        for k in range(60):
            assert env.observation_space.contains(obs)
            e_true = quat_to_rotvec(quat_multiply(quat_conjugate(info["q_true"]), info["q_target"]))
            assert np.linalg.norm(e_true) <= math.pi + 1e-12
            # the observed error rotation is the true one up to the sensor's noise rotation (5″ per axis, 1σ)
            q_obs = quat_from_rotvec(obs[0:3].astype(np.float64) * math.pi)
            assert math.degrees(quat_angle_between(q_obs, quat_from_rotvec(e_true))) * 3600 < 5 * 5 * math.sqrt(3)
            obs, r, term, trunc, info = env.step(env.action_space.sample())
            if term or trunc:
                break


@pytest.mark.parametrize("fine_error_deg", [1.0, 0.2])
def test_fine_error_entries_are_tanh_of_the_error_over_their_scale(fine_error_deg):
    """Entries 3-5 are tanh(e / fine_error_deg) of the observed error rotation (default 1°; at 0.2° the 0.05°
    tolerance reads tanh(0.25) = 0.245): checked near the target, where the entries are not saturated."""
    kwargs = {} if fine_error_deg == 1.0 else {"fine_error_deg": fine_error_deg}
    env = gym.make(V1, sensor="ideal", ideal_attitude_noise_arcsec=0.01, **kwargs)
    _, info = env.reset(seed=4)
    # a target 0.04° away from the start, about an axis fixed in the body
    axis = np.array([0.6, -0.8, 0.0])
    q_target = quat_multiply(info["q_true"], quat_from_rotvec(axis * math.radians(0.04)))
    obs, info = env.reset(seed=4, options={"q_target": q_target})
    e = axis * math.radians(0.04)
    assert np.allclose(obs[3:6], np.tanh(e / math.radians(fine_error_deg)), atol=2e-4)  # 0.01″ noise
    assert np.allclose(obs[0:3], e / math.pi, atol=1e-7)


def test_observation_bounds_hold_over_settling_episodes_with_the_tracker():
    env = gym.make(V1, gyro_grade="navigation", max_episode_s=30.0, max_episode_steps=300)
    obs, info = env.reset(seed=1000, options={"slew_angle_deg": 30.0})
    lo_timer = []
    while True:
        assert env.observation_space.contains(obs), obs
        lo_timer.append(obs[-1])
        obs, r, term, trunc, info = env.step(pd_action(obs, env))
        if term or trunc:
            break
    assert env.observation_space.contains(obs)
    assert info["settled"] and not info["diverged"]
    # the settle timer runs from 0 to 1 over the hold
    assert max(lo_timer) > 0.9 and lo_timer[0] == 0.0


def test_body_torque_allocation_gives_the_commanded_torque_and_no_null_motion():
    env = gym.make(V1).unwrapped
    axes = env.spacecraft.wheel_axes_body  # (4, 3) rows
    alloc = env.allocator
    rng = np.random.default_rng(0)
    null = np.linalg.svd(axes.T)[2][-1]
    for _ in range(200):
        tau_cmd = rng.uniform(-0.4, 0.4, 3)
        h = rng.uniform(-0.5, 0.5, 4)
        tau_b, tau_n = alloc.wheel_torques(tau_cmd, h)
        body = -(axes.T @ tau_b)  # the bus feels minus each motor torque along its axis
        peak = np.max(np.abs(np.linalg.pinv(axes.T) @ tau_cmd))
        scale = min(1.0, 0.95 * 0.5 / peak)
        assert np.allclose(body, scale * tau_cmd, atol=1e-12)
        assert abs(null @ tau_b) < 1e-12  # the body part has no null-space component
        assert np.allclose(axes.T @ tau_n, 0.0, atol=1e-12)  # the management part makes no body torque
        # ... and it bleeds the null-space momentum with the documented time constant, within its budget
        m = null @ h
        expected = np.clip(-m / 10.0, -0.05 * 0.5 / np.max(np.abs(null)), 0.05 * 0.5 / np.max(np.abs(null)))
        assert np.allclose(tau_n, expected * null, atol=1e-12)
        assert np.max(np.abs(tau_b + tau_n)) <= 0.5 + 1e-12


def test_body_torque_action_accelerates_the_bus_as_J_inverse_tau():
    env = gym.make(V1, sensor="ideal")
    env.reset(seed=0)
    u = env.unwrapped
    a = np.array([0.3, -0.2, 0.1], np.float32)
    env.step(a)
    sc = u.spacecraft
    dw = sc.omega_body  # from rest, after one 0.1 s step; gyroscopic terms are O(ω²)
    # the wheels' spin inertia does not turn with the bus while the motors spin them: J - I_s A Aᵀ accelerates
    axes = sc.wheel_axes_body
    j_eff = sc.inertia_kg_m2 - sc.wheel_inertia_kg_m2 * axes.T @ axes
    expected = np.linalg.solve(j_eff, a.astype(np.float64) * 0.5) * 0.1
    assert np.allclose(dw, expected, rtol=1e-3, atol=1e-7)


def test_cubic_action_curve_commands_the_cube_and_keeps_full_authority():
    """``action_curve="cubic"``: the bus accelerates as J_eff⁻¹ (a³ τ_max), so a = 0.3 gives 2.7 % of the torque
    limit, and a = ±1 still the full limit; the default stays linear."""
    a = np.array([0.3, -0.2, 1.0], np.float32)
    rates = {}
    for curve in ("linear", "cubic"):
        env = gym.make(V1, sensor="ideal", action_curve=curve)
        env.reset(seed=0)
        env.step(a)
        sc = env.unwrapped.spacecraft
        axes = sc.wheel_axes_body
        j_eff = sc.inertia_kg_m2 - sc.wheel_inertia_kg_m2 * axes.T @ axes
        cmd = a.astype(np.float64) ** (3 if curve == "cubic" else 1)
        # the allocator scales a torque that saturates a wheel down with its direction kept
        peak = np.max(np.abs(np.linalg.pinv(axes.T) @ (cmd * 0.5)))
        expected = np.linalg.solve(j_eff, cmd * 0.5 * min(1.0, 0.95 * 0.5 / peak)) * 0.1
        assert np.allclose(sc.omega_body, expected, rtol=1e-3, atol=1e-8)
        rates[curve] = sc.omega_body.copy()
        env.close()
    assert not np.allclose(rates["linear"], rates["cubic"])
    assert gym.make(V1).unwrapped.action_curve == "linear"


def test_null_space_momentum_decays_and_makes_no_body_motion():
    """Management on: the internal momentum bleeds off; management off (an allocator of time constant ∞) it stays."""
    env = gym.make(V1, sensor="ideal")
    env.reset(seed=0)
    u = env.unwrapped
    alloc = u.allocator
    sc = u.spacecraft
    # give the wheels pure null-space momentum: no body momentum at all
    speeds = alloc.null * 50.0
    sc.set_state(sc.q_body_to_icrs, np.zeros(3), speeds, time_s=0.0)
    m0 = alloc.null @ (sc.wheel_speeds_rad_s * sc.wheel_inertia_kg_m2)
    for _ in range(50):
        env.step(np.zeros(3, np.float32))
    m1 = alloc.null @ (sc.wheel_speeds_rad_s * sc.wheel_inertia_kg_m2)
    assert abs(m1) < abs(m0) * math.exp(-5.0 / 10.0) * 1.05  # at least the 10 s exponential in 5 s
    assert np.linalg.norm(sc.omega_body) < 1e-9  # and the bus never moved


def test_reward_terms_as_documented_and_settle_bonus_only_on_settling():
    env = gym.make(V1, sensor="ideal", max_episode_s=30.0, max_episode_steps=300)
    u = env.unwrapped
    obs, info = env.reset(seed=5, options={"slew_angle_deg": 25.0})
    tol, rtol = u.settle_tolerance_rad, u.settle_rate_rad_s
    settles, steps = [], 0
    while True:
        a = pd_action(obs, env)
        obs, r, term, trunc, info = env.step(a)
        steps += 1
        theta = math.radians(info["pointing_error_deg"])
        omega = float(np.linalg.norm(info["omega_true_body"]))
        assert info["reward_pointing"] == pytest.approx(-math.log1p(theta / tol) / math.log1p(math.pi / tol) * 0.1)
        assert info["reward_rate"] == pytest.approx(
            -min(math.log1p(omega / rtol) / math.log1p(u.max_rate_rad_s / rtol), 1.0) * 0.5 * 0.1)
        for k in ("reward_pointing", "reward_rate", "reward_effort"):
            assert info[k] <= 0.0
        assert r == pytest.approx(sum(info[k] for k in ("reward_pointing", "reward_rate", "reward_effort",
                                                          "reward_settle", "reward_diverge")))
        settles.append(info["reward_settle"])
        if term or trunc:
            break
    assert term and info["settled"]
    assert settles[-1] == 10.0 and all(s == 0.0 for s in settles[:-1])
    # the pointing term does not vanish near the target: at the tolerance it is still 8 % of its largest value
    assert -math.log1p(1.0) / math.log1p(math.pi / tol) < -0.08


def test_divergence_ends_the_episode_with_the_rest_of_the_episode_as_penalty():
    env = gym.make(V1, sensor="ideal", max_episode_s=40.0, max_episode_steps=400)
    _, info0 = env.reset(seed=2)
    u = env.unwrapped
    for _ in range(400):
        obs, r, term, trunc, info = env.step(np.ones(3, np.float32))
        if term or trunc:
            break
    assert term and info["diverged"] and not info["settled"]
    rate = float(np.linalg.norm(info["omega_true_body"]))
    theta0 = math.radians(info0["pointing_error_deg"])
    assert rate > 2 * u.max_rate_rad_s or math.radians(info["pointing_error_deg"]) > theta0 + math.radians(45.0)
    remaining = round((40.0 - info["time_s"]) / 0.1)
    assert info["reward_diverge"] == pytest.approx(-(1.0 + 0.5 + 0.01) * 0.1 * remaining)
    # diverging never pays: the penalty is at least what the rest of the episode's per-step terms could cost
    assert info["reward_diverge"] <= -0.1 * 1.51 * remaining + 1e-9


def test_v1_starts_as_v0_does_with_the_same_seed():
    """The same draws: the same initial attitude and target for a seed, in both versions and both sensors."""
    _, i0 = gym.make("startracker/AgileSlew-v0").reset(seed=11, options={"slew_angle_deg": 33.0})
    _, i1 = gym.make(V1).reset(seed=11, options={"slew_angle_deg": 33.0})
    _, i2 = gym.make(V1, sensor="ideal").reset(seed=11, options={"slew_angle_deg": 33.0})
    for i in (i1, i2):
        assert np.array_equal(i0["q_true"], i["q_true"]) and np.array_equal(i0["q_target"], i["q_target"])
    assert quat_angle_between(i0["q_true"], i0["q_target"]) == pytest.approx(math.radians(33.0))


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="action_mode"):
        gym.make(V1, action_mode="torque")
    with pytest.raises(ValueError, match="sensor"):
        gym.make(V1, sensor="perfect")
    with pytest.raises(ValueError, match="fine_error_deg"):
        gym.make(V1, fine_error_deg=0.0)
    with pytest.raises(ValueError, match="action_curve"):
        gym.make(V1, action_curve="quadratic")
    with pytest.raises(ValueError, match="max_episode_s"):
        gym.make(V1, max_episode_s="long")
    env = gym.make(V1, sensor="ideal")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.array([np.nan, 0, 0], np.float32))
