"""A gyro bias or scale that drifts (their varying form): its reading against its definition, the
records it is fitted on, and a bias random walk (not the model's spline) read as it, blind.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import interpolate

from inertia_gym.discrepancy.effects import BIAS_KNOT_SPACING_S, GYRO_SCALE_BOUND, REGISTRY, Effect
from inertia_gym.discrepancy.fit import prepare
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.synthetic import gyro_reading, simulate_recording
from inertia_gym.recordings import Recording
from inertia_gym.scenario import Scenario

GYRO = REGISTRY["gyro_bias"]
SLOW = Scenario(omega0=(0.05, 0.3, 0.04), dt=0.05)


def _spline_drift(knots, profile, t) -> np.ndarray:
    """(n, 3): per axis scipy's not-a-knot cubic spline through profile (K, 3) at knots (K,) s,
    at times t (n,) s, held at its end values beyond the knots: the drift's definition."""
    return np.stack([interpolate.CubicSpline(knots, profile[:, i], bc_type="not-a-knot")(
        np.clip(t, knots[0], knots[-1])) for i in range(3)], axis=1)

def test_a_drifting_bias_reads_as_the_not_a_knot_spline_through_its_knots_held_beyond_them():
    knots = np.array([10.0, 40.0, 70.0, 100.0, 130.0])
    profile = np.array([[0.0, 0.0, 0.0], [1.0, -2.0, 0.5], [3.0, 1.0, -1.0], [2.0, 0.0, 0.0],
                        [-1.0, 4.0, 2.0]]) * 1e-3
    bias = np.array([0.1, -0.2, 0.3])
    t = np.linspace(0.0, 140.0, 57)
    w = np.random.default_rng(0).normal(size=(t.size, 3))
    read = gyro_reading(t, w, Effect("gyro_bias", {"bias": bias, "profile_t": knots, "profile": profile}))
    drift = _spline_drift(knots, profile, t)
    np.testing.assert_allclose(read, w + bias + drift, rtol=0, atol=1e-12)
    before = t <= knots[0]  # m = 0 at the first knot and before it
    np.testing.assert_allclose(read[before] - w[before], np.tile(bias, (before.sum(), 1)), atol=1e-12)
    # the vector packs and unpacks losslessly
    params = {"bias": bias, "profile_t": knots, "profile": profile}
    back = GYRO.unpack(GYRO.pack(params))
    for key in params:
        np.testing.assert_array_equal(back[key], params[key])


def test_the_varying_vector_holds_its_knot_times_and_first_row_and_starts_at_the_constant_bias():
    d = prepare(_record(300.0, 1.0, seed=1))
    k = GYRO.knots(d)
    assert k == 10
    assert np.flatnonzero(GYRO.held("varying", d)).tolist() == list(range(3, 3 + k + 3))
    assert GYRO.form_size("varying", d) == 3 + 4 * k
    bias = np.array([1e-3, -2e-3, 5e-4])
    w = np.random.default_rng(2).normal(size=(d.t.size, 3))
    nested = GYRO.unpack(GYRO.nested("varying", d, bias))
    np.testing.assert_array_equal(GYRO.gyro(nested, w, d.t), GYRO.gyro({"bias": bias}, w, d.t))
    np.testing.assert_array_equal(GYRO.gyro(GYRO.unpack(GYRO.neutral("varying", d, None)), w, d.t), w)


def _record(duration, sample_dt, seed, walk=0.0, bias=(0.0, 0.0, 0.0), scenario=SLOW):
    """The scenario's body (by default tumbling at 0.3 rad/s) with no torque for duration s at
    sample_dt s, its gyro reading plus a bias random walk of `walk` rad/s/sqrt(s) per axis (a
    cumulative sum of Gaussian steps, not a spline) and a constant bias (rad/s); the sidecar
    without its truth.
    """
    rec, _ = simulate_recording(scenario, duration, None, seed=seed, torque=False, sample_dt=sample_dt)
    rng = np.random.default_rng(seed + 1000)
    steps = rng.normal(0.0, walk * np.sqrt(np.diff(rec.t, prepend=rec.t[0]))[:, None], rec.w.shape)
    meta = {k: v for k, v in rec.meta.items() if k not in ("effect", "effects")}
    return Recording(rec.t, rec.w + np.cumsum(steps, axis=0) + np.asarray(bias), None, None, meta, "drift")


@pytest.mark.parametrize("duration, sample_dt, rate, knots", [
    (60.0, 1.0, 0.3, 0), (119.0, 1.0, 0.3, 0), (120.0, 1.0, 0.3, 4), (200.0, 1.0, 0.3, 6),
    (900.0, 1.0, 0.3, 16),  # 30 s apart (a turn takes 21 s), at most 16
    (200.0, 2.0, 0.3, 4),  # 25 rows apart
    (900.0, 2.0, 0.03, 4),  # a turn (209 s) apart
    (600.0, 2.0, 0.02, 0)])  # a turn takes 314 s: too few
def test_the_drift_is_fitted_only_where_the_record_holds_4_knots_30_s_25_rows_and_a_turn_apart(
        duration, sample_dt, rate, knots):
    slow = Scenario(omega0=tuple(np.asarray(SLOW.omega0) * rate / np.linalg.norm(SLOW.omega0)), dt=0.05,
                    gyro_sigma=1e-3)  # the rate read over the noise
    rec = _record(duration, sample_dt, seed=1, scenario=slow)
    d = prepare(rec)
    assert BIAS_KNOT_SPACING_S == 30.0
    assert GYRO.knots(d) == knots
    assert GYRO.forms(d) == (("", "varying") if knots else ("",))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, pytest.param(4, marks=pytest.mark.science)])
def test_a_bias_random_walk_is_read_as_a_drifting_gyro_bias_and_a_constant_one_as_constant(seed):
    duration, sample_dt = 300.0, 0.5
    sigma = SLOW.gyro_sigma
    walk = 4.0 * sigma / np.sqrt(duration)  # about 4 sigma of drift over the record per axis
    drifting = _record(duration, sample_dt, seed, walk=walk, bias=(3 * sigma, -2 * sigma, 0.0))
    report = diagnose(drifting).report
    lead = report["explanation"][0]
    assert (lead["name"], lead["form"]) == ("gyro_bias", "varying")
    assert max(report["fit_after"]["rms_over_noise"]) < 1.15
    assert not report["beyond_catalogue"]
    # the same body with a bias that does not drift: the constant form, nothing else
    steady = _record(duration, sample_dt, seed, bias=(5 * sigma, -4 * sigma, 3 * sigma))
    report = diagnose(steady).report
    assert [(e["name"], e["form"]) for e in report["explanation"]] == [("gyro_bias", None)]


def test_a_drifting_scale_reads_as_one_plus_the_scale_and_its_spline_times_the_rates():
    """gyro_scale has the drifting bias's forms (one base class): (1 + s + m(t)) w, m the same
    spline; its scale and drift bounded to GYRO_SCALE_BOUND, its knot times not."""
    scale = REGISTRY["gyro_scale"]
    knots = np.array([10.0, 40.0, 70.0, 100.0])
    profile = np.array([[0.0, 0.0, 0.0], [1.0, -2.0, 0.5], [3.0, 1.0, -1.0], [2.0, 0.0, 4.0]]) * 1e-3
    s = np.array([0.01, -0.02, 0.005])
    t = np.linspace(0.0, 110.0, 45)
    w = np.random.default_rng(0).normal(size=(t.size, 3))
    read = gyro_reading(t, w, Effect("gyro_scale", {"scale": s, "profile_t": knots, "profile": profile}))
    drift = _spline_drift(knots, profile, t)
    np.testing.assert_allclose(read, w * (1.0 + s + drift), rtol=0, atol=1e-12)
    params = {"scale": s, "profile_t": knots, "profile": profile}
    back = scale.unpack(scale.pack(params))
    for key in params:
        np.testing.assert_array_equal(back[key], params[key])
    d = prepare(_record(300.0, 1.0, seed=1))
    k = scale.knots(d)
    lo, hi = scale.bounds("varying", d)
    bounded = np.r_[np.ones(3, bool), np.zeros(k, bool), np.ones(3 * k, bool)]
    assert np.all(hi[bounded] == GYRO_SCALE_BOUND) and np.all(lo[bounded] == -GYRO_SCALE_BOUND)
    assert np.all(np.isinf(hi[~bounded])) and scale.forms(d) == ("", "varying")


@pytest.mark.slow
def test_a_scale_drifting_linearly_is_read_as_a_drifting_gyro_scale():
    """5 min of a tumbling body with torque bursts, no nominal inertia, its gyro scale drifting
    linearly (not the model's spline) by (+1.5, -1, +2) % over the record, noise 1e-3 rad/s: led by
    gyro_scale's varying form, fitted to the noise, the shape within its intervals, the drift's
    end within 0.3 % of the truth. (With a constant scale only, a 20-min record of this kind
    reads as a drifting bias, a rotor and a constant scale, its inertia 2-4 % off.)"""
    sc = Scenario(omega0=(0.05, 0.3, 0.04), dt=0.05, gyro_sigma=1e-3)
    rec, _ = simulate_recording(sc, 300.0, None, seed=3, sample_dt=0.5)
    end = np.array([0.015, -0.01, 0.02])
    drift = (rec.t - rec.t[0])[:, None] / (rec.t[-1] - rec.t[0]) * end
    meta = {k: v for k, v in rec.meta.items() if k not in ("effect", "effects", "inertia_nominal")}
    report = diagnose(Recording(rec.t, rec.w * (1.0 + drift), None, rec.tau, meta, "scale drift")).report
    lead = report["explanation"][0]
    assert (lead["name"], lead["form"]) == ("gyro_scale", "varying")
    assert max(report["fit_after"]["rms_over_noise"]) < 1.1
    moments = np.sort(np.linalg.eigvalsh(sc.inertia_true_array))[::-1]
    lo, hi = np.array(report["fit_after"]["principal_ratios_ci95"]).T
    assert np.all((lo <= moments / moments[0]) & (moments / moments[0] <= hi))
    fitted_end = np.asarray(lead["params"]["scale"]) + np.asarray(lead["params"]["profile"])[-1]
    np.testing.assert_allclose(fitted_end, end, atol=3e-3)
