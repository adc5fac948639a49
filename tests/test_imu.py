"""IMU error models: the simulated noise has the statistics its parameters promise."""

import math

import numpy as np
import pytest

from startracker.imu import (
    DEG_PER_H,
    DEG_PER_SQRT_H,
    MICRO_G,
    Accelerometer,
    AccelerometerSpec,
    Gyro,
    GyroSpec,
    accelerometer_preset,
    gyro_preset,
)


def allan_variance(y, dt, m_list):
    """Overlapping Allan variance of rate samples y (n, ...) at cluster sizes m (IEEE Std 952 form)."""
    theta = np.concatenate([np.zeros((1,) + y.shape[1:]), np.cumsum(y, axis=0) * dt])
    out = []
    for m in m_list:
        tau = m * dt
        d = theta[2 * m :] - 2 * theta[m:-m] + theta[: -2 * m]
        out.append(np.mean(d**2) / (2 * tau**2))
    return np.array(out)


def run(sensor, n, rng, value=None):
    u = np.zeros((n, 3)) if value is None else np.broadcast_to(value, (n, 3))
    return sensor.measure(u, rng)


def test_angle_random_walk_allan_slope_and_level():
    n_arw = 1e-4  # rad/√s
    g = Gyro(GyroSpec(rate_hz=100.0, arw_rad_sqrt_s=n_arw), np.random.default_rng(0))
    y = run(g, 200_000, np.random.default_rng(1))  # 2000 s, 3 axes
    m = np.array([10, 30, 100, 300, 1000])
    tau = m * 0.01
    adev = np.sqrt(allan_variance(y, 0.01, m))
    np.testing.assert_allclose(adev, n_arw / np.sqrt(tau), rtol=0.06)
    slope = np.polyfit(np.log(tau), np.log(adev), 1)[0]
    assert abs(slope + 0.5) < 0.03


def test_arw_plus_rate_random_walk_allan_curve():
    """σ_A(τ)² = N²/τ + K² τ/3: the white-noise and random-walk branches and their crossover."""
    n_arw, k_rrw = 1e-4, 1e-6
    rng = np.random.default_rng(2)
    spec = GyroSpec(rate_hz=10.0, arw_rad_sqrt_s=n_arw, rrw_rad_s_sqrt_s=k_rrw)
    ys = [run(Gyro(spec, rng), 200_000, rng) for _ in range(4)]  # 4 x 3 series of 20000 s
    y = np.stack(ys, axis=1)
    m = np.array([10, 100, 1000, 3000, 10000, 20000])
    tau = m * 0.1
    avar = allan_variance(y, 0.1, m)
    expected = n_arw**2 / tau + k_rrw**2 * tau / 3.0
    np.testing.assert_allclose(np.sqrt(avar), np.sqrt(expected), rtol=0.15)
    np.testing.assert_allclose(np.sqrt(avar[:3]), np.sqrt(expected[:3]), rtol=0.05)
    # the curve turns upward past the crossover τ = √3 N / K ≈ 173 s
    assert avar[-1] > avar[2]


def test_rate_random_walk_increments():
    k_rrw = 2e-6
    g = Gyro(GyroSpec(rate_hz=10.0, rrw_rad_s_sqrt_s=k_rrw), np.random.default_rng(3))
    y = run(g, 300_000, np.random.default_rng(4))
    inc = np.diff(y, axis=0)
    np.testing.assert_allclose(inc.var(), k_rrw**2 * 0.1, rtol=0.02)
    assert abs(np.corrcoef(inc[1:, 0], inc[:-1, 0])[0, 1]) < 0.01  # independent increments
    np.testing.assert_allclose(g.bias_rad_s, y[-1], rtol=0, atol=1e-18)


def test_gauss_markov_bias_variance_and_correlation_time():
    sigma, tau_c, rate = 1e-4, 5.0, 10.0
    rng = np.random.default_rng(5)
    spec = GyroSpec(rate_hz=rate, gm_sigma_rad_s=sigma, gm_tau_s=tau_c)
    y = np.concatenate([run(Gyro(spec, rng), 50_000, rng) for _ in range(4)], axis=1)  # 12 series, 5000 s
    np.testing.assert_allclose(y.var(axis=0).mean(), sigma**2, rtol=0.08)
    yc = y - y.mean(axis=0)
    for lag_s in (2.5, 5.0, 10.0):
        lag = int(lag_s * rate)
        r = np.mean(yc[lag:] * yc[:-lag]) / np.mean(yc * yc)
        assert abs(r - math.exp(-lag_s / tau_c)) < 0.03
    # started in the stationary distribution: first samples of many fresh gyros have variance σ²
    first = np.array([Gyro(spec, rng).measure(np.zeros(3), rng) for _ in range(4000)])
    np.testing.assert_allclose(first.var(), sigma**2, rtol=0.08)


def test_paper001_accelerometer_markov_bias_tau_1800_s():
    acc_spec = accelerometer_preset("paper001-cond2", rate_hz=1.0)
    assert acc_spec.gm_tau_s == 1800.0
    rng = np.random.default_rng(6)
    y = np.concatenate([Accelerometer(acc_spec, rng).measure(np.zeros((180_000, 3)), rng) for _ in range(8)], axis=1)
    sigma = 100.0 * MICRO_G
    np.testing.assert_allclose(y.var(axis=0).mean(), sigma**2, rtol=0.12)
    yc = y - y.mean(axis=0)
    r = np.mean(yc[1800:] * yc[:-1800]) / np.mean(yc * yc)
    assert abs(r - math.exp(-1.0)) < 0.06


def test_paper001_gyro_conditions():
    """0.004 / 1 / 5 °/h conditions: constant + Markov (τ 3600 s) + white noise, equal magnitudes."""
    for cond, d in ((1, 0.004), (2, 1.0), (3, 5.0)):
        s = gyro_preset(f"paper001-cond{cond}")
        assert math.isclose(s.bias_sigma_rad_s, d * math.pi / 180 / 3600)
        assert math.isclose(s.gm_sigma_rad_s, s.bias_sigma_rad_s)
        assert s.gm_tau_s == 3600.0
        assert math.isclose(s.arw_rad_sqrt_s, d * math.pi / 180 / 60)
    # attitude drift over one hour of the three conditions, coasting on the gyro: ratios follow d
    rng = np.random.default_rng(7)
    drift = []
    for cond in (1, 2, 3):
        spec = gyro_preset(f"paper001-cond{cond}", rate_hz=1.0)
        angles = [np.abs(np.sum(Gyro(spec, rng).measure(np.zeros((3600, 3)), rng), axis=0)) for _ in range(30)]
        drift.append(np.sqrt(np.mean(np.square(angles))))
    # angle variance after T: constant d² T², Markov 2 d² τ² (T/τ - 1 + e^(-T/τ)), ARW N² T;
    # with T = τ = 1 h and N = d °/√h each term is (d deg)² times 1, 2/e and 1
    d_deg = np.array([0.004, 1.0, 5.0])
    expected = np.radians(d_deg) * math.sqrt(1.0 + 2.0 * math.exp(-1.0) + 1.0)
    np.testing.assert_allclose(drift, expected, rtol=0.2)


def test_constant_bias_and_scale_factor_statistics():
    spec = GyroSpec(rate_hz=50.0, bias_sigma_rad_s=3e-5, scale_factor_sigma_ppm=200.0)
    rng = np.random.default_rng(8)
    g = Gyro(spec, rng)
    w = np.array([0.3, -0.2, 0.1])
    y = g.measure(np.tile(w, (100, 1)), rng)
    np.testing.assert_array_equal(y, np.tile(y[0], (100, 1)))  # no time-varying term
    biases, sfs = [], []
    for _ in range(3000):
        g.reset(rng)
        y0 = g.measure(np.zeros(3), rng)
        y1 = g.measure(w, rng)
        biases.append(y0)
        sfs.append((y1 - y0) / w - 1.0)
    np.testing.assert_allclose(np.std(biases), 3e-5, rtol=0.05)
    np.testing.assert_allclose(np.std(sfs), 200e-6, rtol=0.05)
    assert abs(np.mean(biases)) < 3e-5 * 0.05


def test_saturation():
    spec = GyroSpec(rate_hz=100.0, arw_rad_sqrt_s=1e-4, max_rate_rad_s=math.radians(300.0))
    rng = np.random.default_rng(9)
    g = Gyro(spec, rng)
    w = np.array([[math.radians(400.0), -math.radians(1000.0), math.radians(100.0)]] * 50)
    y = g.measure(w, rng)
    np.testing.assert_array_equal(y[:, 0], math.radians(300.0))
    np.testing.assert_array_equal(y[:, 1], -math.radians(300.0))
    assert np.all(np.abs(y[:, 2] - math.radians(100.0)) < 6 * 1e-4 / math.sqrt(0.01))


def test_same_seed_same_samples_and_chunking_invariance():
    spec = gyro_preset("industrial", rate_hz=100.0)
    a = Gyro(spec, np.random.default_rng(10)).measure(np.zeros((500, 3)), np.random.default_rng(11))
    b = Gyro(spec, np.random.default_rng(10)).measure(np.zeros((500, 3)), np.random.default_rng(11))
    np.testing.assert_array_equal(a, b)
    # the Gauss-Markov recursion gives the same bias path whether sampled in one call or sample by sample
    only_gm = GyroSpec(rate_hz=10.0, gm_sigma_rad_s=1e-4, gm_tau_s=2.0)
    g1, g2 = Gyro(only_gm, np.random.default_rng(12)), Gyro(only_gm, np.random.default_rng(12))
    r1, r2 = np.random.default_rng(13), np.random.default_rng(13)
    y1 = g1.measure(np.zeros((5, 3)), r1)
    drive = r2.standard_normal((5, 3))  # reproduce with an independent recursion from the same draws
    phi = math.exp(-0.1 / 2.0)
    b = g2.bias_rad_s
    ref = []
    for k in range(5):
        b = phi * b + 1e-4 * math.sqrt(1 - phi**2) * drive[k]
        ref.append(b)
    np.testing.assert_allclose(y1, ref, rtol=1e-12, atol=1e-20)


def test_presets_and_grades_ordering():
    arw = [gyro_preset(gr).arw_rad_sqrt_s for gr in ("navigation", "tactical", "industrial")]
    assert arw[0] < arw[1] < arw[2]
    assert gyro_preset("mems") == gyro_preset("industrial")
    ideal = Gyro(gyro_preset("ideal"), np.random.default_rng(0))
    w = np.array([[0.1, -0.2, 0.3]] * 3)
    np.testing.assert_array_equal(ideal.measure(w, np.random.default_rng(1)), w)
    assert math.isclose(GyroSpec.from_datasheet(arw_deg_sqrt_h=1.0).arw_rad_sqrt_s, math.radians(1) / 60)
    assert math.isclose(DEG_PER_H, 4.84813681109536e-06)
    assert math.isclose(DEG_PER_SQRT_H, 2.908882086657216e-4)
    s = GyroSpec(gm_sigma_rad_s=1e-5, gm_tau_s=100.0, rrw_rad_s_sqrt_s=1e-7)
    assert math.isclose(s.bias_rw_equivalent_rad_s_sqrt_s, math.sqrt(1e-14 + 2e-10 / 100.0))


def test_sample_times():
    g = Gyro(GyroSpec(rate_hz=100.0), np.random.default_rng(0))
    t = g.sample_times(0.1, 0.2)
    np.testing.assert_allclose(t, 0.11 + 0.01 * np.arange(10))
    assert len(g.sample_times(0.105, 0.109)) == 0


def test_bad_input():
    with pytest.raises(ValueError, match="rate_hz"):
        GyroSpec(rate_hz=0.0)
    with pytest.raises(ValueError, match="arw_rad_sqrt_s"):
        GyroSpec(arw_rad_sqrt_s=-1.0)
    with pytest.raises(ValueError, match="gm_tau_s"):
        AccelerometerSpec(gm_tau_s=0.0)
    with pytest.raises(ValueError, match="max_rate_rad_s"):
        GyroSpec(max_rate_rad_s=0.0)
    with pytest.raises(TypeError, match="bias_sigma_rad_s"):
        GyroSpec(bias_sigma_rad_s="1")
    with pytest.raises(ValueError, match="grade"):
        gyro_preset("consumer")
    with pytest.raises(TypeError, match="rng"):
        Gyro(GyroSpec(), rng=42)
    with pytest.raises(TypeError, match="spec"):
        Gyro(AccelerometerSpec(), np.random.default_rng(0))
    g = Gyro(GyroSpec(arw_rad_sqrt_s=1e-4), np.random.default_rng(0))
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="omega_true_body"):
        g.measure([0.0, np.nan, 0.0], rng)
    with pytest.raises(ValueError, match="omega_true_body"):
        g.measure(np.zeros((4, 2)), rng)
    with pytest.raises(TypeError, match="rng"):
        g.measure(np.zeros(3), None)
    assert g.n_samples == 0  # rejected calls did not advance the noise state
    a = Accelerometer(AccelerometerSpec(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="specific_force_body"):
        a.measure(np.full(3, np.inf), rng)


class _NumpyReferenceGyro:
    """The sample model written with numpy and scipy (``lfilter`` for the Gauss-Markov recursion, ``cumsum`` for the
    random walk), drawing from the generator in the documented order: turn-on bias, Gauss-Markov state, scale factor
    at reset; per call the Gauss-Markov drive, the random-walk steps, the white noise (each only when non-zero)."""

    def __init__(self, spec, rng):
        from scipy.signal import lfilter

        self.lfilter = lfilter
        dt = 1.0 / spec.rate_hz
        self.phi = math.exp(-dt / spec.gm_tau_s)
        self.gm_drive = spec.gm_sigma_rad_s * math.sqrt(-math.expm1(-2.0 * dt / spec.gm_tau_s))
        self.white = spec.arw_rad_sqrt_s / math.sqrt(dt)
        self.rw_step = spec.rrw_rad_s_sqrt_s * math.sqrt(dt)
        self.limit = spec.max_rate_rad_s
        self.b_c = spec.bias_sigma_rad_s * rng.standard_normal(3)
        self.b_gm = spec.gm_sigma_rad_s * rng.standard_normal(3)
        self.b_rw = np.zeros(3)
        self.sf = 1.0 + spec.scale_factor_sigma_ppm * 1e-6 * rng.standard_normal(3)

    def measure(self, u, rng):
        k = len(u)
        gm = self.b_gm
        if self.gm_drive > 0.0:
            drive = self.gm_drive * rng.standard_normal((k, 3))
            gm, _ = self.lfilter([1.0], [1.0, -self.phi], drive, axis=0, zi=(self.phi * self.b_gm)[None, :])
            self.b_gm = gm[-1].copy()
        rw = self.b_rw
        if self.rw_step > 0.0:
            rw = self.b_rw + np.cumsum(self.rw_step * rng.standard_normal((k, 3)), axis=0)
            self.b_rw = rw[-1].copy()
        y = self.sf * u + (self.b_c + gm + rw)
        if self.white > 0.0:
            y += self.white * rng.standard_normal((k, 3))
        return np.clip(y, -self.limit, self.limit) if math.isfinite(self.limit) else y


@pytest.mark.parametrize("grade", ["ideal", "navigation", "tactical", "industrial", "paper001-cond2"])
def test_compiled_samples_are_the_numpy_model_bit_for_bit(grade):
    """Same generator, same draws in the same order and amount, same floats: every sample, the bias state and the
    generator's state afterwards equal the numpy/scipy formulation exactly, whatever the chunking of the calls."""
    spec = gyro_preset(grade, rate_hz=100.0)
    spec = GyroSpec(**{**spec.__dict__, "rrw_rad_s_sqrt_s": 1e-6, "max_rate_rad_s": 0.5})  # every term on, saturating
    g, ref = Gyro(spec, np.random.default_rng(21)), _NumpyReferenceGyro(spec, np.random.default_rng(21))
    r1, r2 = np.random.default_rng(22), np.random.default_rng(22)
    for n in (1, 10, 3, 1, 250):
        u = np.random.default_rng(n).normal(0.0, 0.3, (n, 3))
        np.testing.assert_array_equal(g.measure(u, r1, validate=n != 10), ref.measure(u, r2))
    np.testing.assert_array_equal(g.bias_rad_s, ref.b_c + ref.b_gm + ref.b_rw)
    assert r1.bit_generator.state == r2.bit_generator.state
    assert g.n_samples == 265
