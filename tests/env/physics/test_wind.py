"""Wind fields: the paper's gust, Dryden statistics against the MIL-F-8785C model, shear, sums,
seeding and validation."""
import math

import numpy as np
import pytest

from wt_inspect_env.physics.wind import (
    ConstantWind,
    DrydenWind,
    FunctionWind,
    GustWind,
    ShearWind,
    SumWind,
    WindBatch,
    WindField,
    dryden_low_altitude,
    make_wind,
)

FT = 0.3048
ONE = np.zeros((1, 3))


def test_constant_wind_everywhere_and_fresh_arrays():
    w = ConstantWind([1.0, -2.0, 0.5])
    pos = np.random.default_rng(0).normal(size=(5, 3)) * 100
    out = w(3.0, pos)
    np.testing.assert_array_equal(out, np.tile([1.0, -2.0, 0.5], (5, 1)))
    out[:] = 0                                    # callers may modify the result
    np.testing.assert_array_equal(w(3.0, pos)[0], [1.0, -2.0, 0.5])
    assert w(0.0, np.zeros((0, 3))).shape == (0, 3)


def test_gust_is_the_papers_sinusoid():
    w = GustWind(mean_speed=4.0)                  # defaults: along y, period 10 s, std 0.5
    ts = np.linspace(0, 10, 4000, endpoint=False)
    v = np.array([w(t, ONE)[0] for t in ts])
    np.testing.assert_allclose(v[:, [0, 2]], 0.0)
    assert v[:, 1].mean() == pytest.approx(4.0, abs=1e-12)
    assert v[:, 1].std() == pytest.approx(0.5, rel=1e-9)        # std, not amplitude
    assert v[:, 1].max() == pytest.approx(4.0 + 0.5 * math.sqrt(2), abs=1e-4)
    np.testing.assert_allclose(w(2.5, ONE), [[0, 4.0 + 0.5 * math.sqrt(2), 0]])  # quarter period
    np.testing.assert_allclose(w(12.5, ONE), w(2.5, ONE))                         # periodic
    d = GustWind(mean_speed=7.0, direction=(3, 4, 0), std=0.0)
    np.testing.assert_allclose(d(1.0, ONE), [[7 * 0.6, 7 * 0.8, 0]])


def test_shear_follows_power_law_and_is_zero_below_ground():
    w = ShearWind(ref_speed=5.0, ref_height=10.0, alpha=1 / 7, direction=(1, 0, 0), ground_height=2.0)
    pos = np.array([[0, 0, 12.0], [0, 0, 22.0], [50, -3, 162.0], [0, 0, 1.0], [0, 0, 2.0]])
    v = w(0.0, pos)
    np.testing.assert_allclose(v[:, 0], [5.0, 5.0 * 2 ** (1 / 7), 5.0 * 16 ** (1 / 7), 0.0, 0.0])
    np.testing.assert_allclose(v[:, 1:], 0.0)


def test_mil_spec_dryden_scales():
    # At 1000 ft the low-altitude model meets the medium-altitude one: all lengths 1000 ft and
    # isotropic intensities sigma = 0.1 W20.
    sigma, L = dryden_low_altitude(1000 * FT, 10.0)
    np.testing.assert_allclose(L, 1000 * FT, rtol=1e-12)
    np.testing.assert_allclose(sigma, 1.0, rtol=1e-12)
    # At 100 ft: L_w = 100 ft, L_u = 100 / 0.2593^1.2 ft = 505 ft, sigma_u = sigma_w / 0.2593^0.4.
    sigma, L = dryden_low_altitude(100 * FT, 15.0)
    np.testing.assert_allclose(L / FT, [505.2, 505.2, 100.0], rtol=1e-3)
    np.testing.assert_allclose(sigma, [1.5 / 0.2593**0.4] * 2 + [1.5], rtol=1e-3)
    with pytest.raises(ValueError, match="altitude"):
        dryden_low_altitude(1000.0, 4.0)


def dryden_samples(w, duration, dt):
    return np.array([w(t, ONE)[0] for t in np.arange(0.0, duration, dt)])


@pytest.mark.slow
@pytest.mark.unit
def test_dryden_statistics_match_the_model():
    """Standard deviations and autocorrelations of a long run against the Dryden model.

    Correlation times T = L / V are 2, 2, 1 s; 4000 s gives ~1000 independent stretches for u, so
    the sample std is within ~2 % (1 sigma) of the model: we allow 6 %.
    """
    sigma = np.array([1.0, 0.8, 0.5])
    w = DrydenWind(mean_speed=10.0, direction=(1, 1, 0), sigma=sigma, length_scales=(20, 20, 10),
                   sample_dt=0.05, seed=3)
    dt = 0.05
    v = dryden_samples(w, 4000.0, dt)
    d = np.array([1, 1, 0]) / math.sqrt(2)
    u_axes = np.stack([d, np.cross([0, 0, 1], d), [0, 0, 1]], axis=1)
    turb = (v - 10.0 * d) @ u_axes                                  # back to (u, v, w) axes
    np.testing.assert_allclose(turb.mean(0), 0.0, atol=0.1)
    np.testing.assert_allclose(turb.std(0), sigma, rtol=0.06)

    def corr(x, lag_s):
        k = int(round(lag_s / dt))
        return np.corrcoef(x[:-k], x[k:])[0, 1]

    # Dryden autocorrelations: u: exp(-tau/T); v, w: (1 - tau / (2T)) exp(-tau/T).
    assert corr(turb[:, 0], 2.0) == pytest.approx(math.exp(-1), abs=0.05)
    assert corr(turb[:, 1], 1.0) == pytest.approx(0.75 * math.exp(-0.5), abs=0.05)
    assert corr(turb[:, 2], 1.0) == pytest.approx(0.5 * math.exp(-1), abs=0.05)
    # Components are independent.
    assert abs(np.corrcoef(turb[:, 0], turb[:, 1])[0, 1]) < 0.1


def test_dryden_default_is_mil_spec_and_stationary_from_the_start():
    w = DrydenWind(mean_speed=4.0, altitude=100.0)
    sig, L = dryden_low_altitude(100.0, 4.0)
    np.testing.assert_allclose(w.sigma, sig)
    np.testing.assert_allclose(w.length_scales, L)
    # Many seeds at t = 0 (no warm-up): the ensemble std is already the stationary one.
    w = DrydenWind(mean_speed=6.0, length_scales=(200, 200, 100), sigma=(1, 1, 1))
    v0 = []
    for s in range(600):
        w.reset(s)
        v0.append(w(0.0, ONE)[0])
    v0 = np.array(v0)
    np.testing.assert_allclose((v0 - [0, 6.0, 0]).std(0), 1.0, rtol=0.1)


def test_seeding_is_exact_and_reset_replays():
    a = DrydenWind(seed=11)
    b = DrydenWind(seed=11)
    c = DrydenWind(seed=12)
    ts = np.linspace(0, 30, 301)
    va = [a(t, ONE) for t in ts]
    np.testing.assert_array_equal(va, [b(t, ONE) for t in ts])
    assert np.abs(np.array(va) - [c(t, ONE) for t in ts]).max() > 1e-3
    a.reset(11)
    np.testing.assert_array_equal(va, [a(t, ONE) for t in ts])
    # Out-of-order queries far in the past (beyond the stored window) give the same values.
    a._KEEP_CHUNKS = 1
    late = a(200.0, ONE)
    np.testing.assert_array_equal(a(ts[5], ONE), va[5])
    np.testing.assert_array_equal(a(200.0, ONE), late)


def test_a_wind_batch_gives_each_field_its_own_values_through_reseeds_and_replays():
    """The batch evaluates gusts in compiled code and Dryden fields as one array operation over
    copies of their sample chunks; every value must stay the field's own - across chunk
    boundaries, after a reseed of one field (its copied chunk is then old) and after a query far
    in the past (a replay from t = 0) - to rounding (the Dryden axis rotation may round its last
    bit differently), bit for bit for the others."""
    def fields():
        out = [DrydenWind(mean_speed=4.0 + j, direction=(1.0, j - 2.0, 0.0), include_mean=j % 2 == 0,
                          altitude=30.0 + 10 * j, seed=j) for j in range(5)]
        return out + [GustWind(mean_speed=7.0, seed=9), ShearWind(ref_speed=5.0), ConstantWind((1.0, 2.0, 0.0))]

    batched, alone = fields(), fields()
    batch = WindBatch(batched)
    rng = np.random.default_rng(3)
    t = np.zeros(len(batched))
    dryden = slice(0, 5)
    for k in range(1200):                       # 12-24 s: several 2.56 s chunks per field
        t = t + 0.01 * rng.integers(1, 3, len(t))
        if k == 600:
            batched[2].reset(77)
            alone[2].reset(77)
        if k == 900:
            batched[1]._KEEP_CHUNKS = alone[1]._KEEP_CHUNKS = 1
            t[1] = 0.5                          # before the stored window: replayed from t = 0
        pos = rng.normal(0.0, 20.0, (len(t), 3)) + [0.0, 0.0, 40.0]
        got = batch(t, pos)
        want = np.array([f(t[j], pos[j:j + 1])[0] for j, f in enumerate(alone)])
        np.testing.assert_allclose(got[dryden], want[dryden], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got[5:], want[5:])
    assert np.abs(got[dryden] - want[dryden]).max() < 1e-12 and np.ptp(want[dryden], axis=0).min() > 0.1


def test_sum_adds_fields_with_independent_streams():
    s = SumWind(DrydenWind(include_mean=False, sigma=(1, 1, 1), length_scales=(20, 20, 20)),
                DrydenWind(include_mean=False, sigma=(1, 1, 1), length_scales=(20, 20, 20)),
                GustWind(mean_speed=3.0, std=0.0), seed=4)
    pos = np.array([[0, 0, 10.0], [5, 5, 50.0]])
    total = s(1.3, pos)
    parts = [f(1.3, pos) for f in s.fields]
    np.testing.assert_allclose(total, sum(parts))
    assert np.abs(parts[0] - parts[1]).max() > 1e-3            # not the same stream twice
    s2 = ConstantWind([1, 0, 0]) + ShearWind()
    assert isinstance(s2, SumWind) and s2(0.0, pos).shape == (2, 3)


def test_make_wind_specs():
    assert isinstance(make_wind("none"), ConstantWind)
    np.testing.assert_array_equal(make_wind(None)(0.0, ONE), 0.0)
    g = make_wind({"type": "gust", "mean_speed": 7})
    assert isinstance(g, GustWind) and g.mean_speed == 7.0
    s = make_wind({"type": "sum", "components": ["shear", {"type": "dryden", "include_mean": False}]})
    assert isinstance(s, SumWind) and len(s.fields) == 2
    w = GustWind()
    assert make_wind(w) is w
    assert isinstance(make_wind(lambda t, pos: np.zeros_like(pos)), FunctionWind)
    with pytest.raises(ValueError, match="unknown wind type 'hurricane'.*gust.*dryden"):
        make_wind({"type": "hurricane"})
    with pytest.raises(ValueError, match="mean_sped"):
        make_wind({"type": "gust", "mean_sped": 4})
    with pytest.raises(ValueError, match="type"):
        make_wind({"mean_speed": 4})


def test_validation_names_the_field():
    w = GustWind()
    with pytest.raises(ValueError, match=r"GustWind: positions must have shape \(N, 3\)"):
        w(0.0, np.zeros(3))
    with pytest.raises(ValueError, match="GustWind: positions must be finite"):
        w(0.0, [[0, np.nan, 0]])
    with pytest.raises(ValueError, match="GustWind: t must be finite"):
        w(np.inf, ONE)
    with pytest.raises(ValueError, match=r"wind field wrong_shape returned shape \(3,\)"):
        FunctionWind(lambda t, pos: np.ones(3), name="wrong_shape")(0.0, ONE)
    with pytest.raises(ValueError, match="wind field nan_field returned non-finite"):
        FunctionWind(lambda t, pos: np.full_like(pos, np.nan), name="nan_field")(0.0, ONE)
    for bad, field in [(dict(period=0.0), "period"), (dict(std=-1.0), "std"),
                       (dict(direction=(0, 0, 0)), "direction"), (dict(mean_speed=np.nan), "mean_speed")]:
        with pytest.raises(ValueError, match=field):
            GustWind(**bad)
    with pytest.raises(ValueError, match="seed"):
        GustWind(seed=-1)
    with pytest.raises(ValueError, match="direction"):
        DrydenWind(direction=(0, 0, 1))
    with pytest.raises(ValueError, match="length_scales"):
        DrydenWind(length_scales=(10, -1, 10), sigma=(1, 1, 1))
    with pytest.raises(ValueError, match="alpha"):
        ShearWind(alpha=2.0)


def test_function_wind_gets_a_seeded_generator():
    def noisy(t, pos, rng):
        return rng.normal(size=pos.shape)

    a, b = FunctionWind(noisy, seed=1), FunctionWind(noisy, seed=1)
    np.testing.assert_array_equal(a(0.0, ONE), b(0.0, ONE))
    assert isinstance(a, WindField)
