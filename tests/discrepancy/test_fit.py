"""The output-error engine of diagnose (discrepancy/fit.py, model.py) against its definitions:
the grid and the held torque, the arrow-shaped Jacobian and its Levenberg-Marquardt step, the
rows (block means, clipped samples, trimmed impulses), and fits on cases a modulating-function
equation-error fit does not reach (a fast toss at 100 Hz, a rotor with its momentum withheld).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from records import cases, slow_tumble, thin_body, thin_body_record, true_gains

from inertia_gym.discrepancy import fit as F
from inertia_gym.discrepancy import fitting, statistics
from inertia_gym.discrepancy import report as report_module
from inertia_gym.discrepancy.effects import REGISTRY, Effect, rotvec_matrix
from inertia_gym.discrepancy.model import Grid, held_cumulative
from inertia_gym.discrepancy.objective import _bounds, _free, _steps, finish
from inertia_gym.discrepancy.report import diagnose, markdown, principal_ratios
from inertia_gym.discrepancy.starts import Probe, _inertia_starts
from inertia_gym.discrepancy.synthetic import simulate_recording, simulate_truth
from inertia_gym.errors import RecordingError
from inertia_gym.estimation import solver
from inertia_gym.recordings import Recording, read_csv_recording, retimed
from inertia_gym.scenario import Scenario

#: kg·m², a tennis racquet: the phyphox-racquet README's pendulum moments (20.7 ± 3.8, 18.8 ± 5.7,
#: 1.39 ± 0.08 g·m²) with the middle one raised within its error bar to 19.5, since as given no
#: body has them (18.8 + 1.39 < 20.7) and the fits keep to the bodies that exist
RACQUET = np.diag([20.7e-3, 19.5e-3, 1.39e-3])


def _toss(w0, sigma=0.005, n=1000, every=10, seed=0, inertia=RACQUET, effects=()):
    """A toss integrated at 1 kHz, sampled every `every` steps, gyro noise sigma; torque-free
    but for `effects` (catalogue Effects of the truth)."""
    q, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.asarray(w0, float), inertia, np.zeros((n, 3)), 1e-3,
                          effects)
    idx = np.arange(0, n + 1, every)
    rng = np.random.default_rng(seed)
    return Recording(idx * 1e-3, w[idx] + rng.normal(0, sigma, (idx.size, 3)), None, None,
                     {"gyro_sigma": sigma}, "toss")


def test_grid_places_samples_and_equal_substeps():
    t = np.array([0.0, 0.1, 0.3, 0.35])
    grid = Grid.of(t, [2, 4, 1])
    np.testing.assert_array_equal(grid.sample_pos, [0, 2, 6, 7])
    np.testing.assert_allclose(grid.t, [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35])


def test_held_torque_integral_is_its_definition():
    t = np.array([0.0, 1.0, 2.5, 3.0])
    tau = np.array([[1.0, 0, 0], [2.0, -1, 0], [0.0, 0, 3], [5.0, 5, 5]])
    cum = held_cumulative(t, tau)
    np.testing.assert_allclose(cum(np.array([-1.0, 0.5, 1.5, 2.5, 3.5])),
                               [[0, 0, 0], [0.5, 0, 0], [2.0, -0.5, 0], [4.0, -1.5, 0], [6.5, 1.0, 4.0]])


def _data(seed=3, duration=12.0):
    rec, _ = simulate_recording(Scenario(tau_max=50.0), duration, "gyro_bias", seed=seed)
    rec = dataclasses.replace(rec, meta={k: v for k, v in rec.meta.items() if k != "inertia_nominal"})
    return F.prepare(rec)


def test_jacobian_columns_equal_brute_force_differences():
    """The batched Jacobian (global columns, and the three rate columns of all segments at once)
    equals perturbing every entry of x on its own."""
    d = _data()
    assert d.segments > 2
    layout = F.Layout.of(("gyro_bias",), ("",), d)
    nominal = F.fit_nominal(d)
    x = F.Probe(layout, d, nominal).x(np.array([0.01, -0.02, 0.03]))
    free = _free(layout, d)
    r0, g, js = F.jacobian(x, free, layout, d, central=True)
    steps = _steps(x, layout, d)
    seg_of = np.repeat(d.row_seg, 3)
    for col, i in enumerate(np.flatnonzero(free[:layout.n_global])):
        up, dn = x.copy(), x.copy()
        up[i] += steps[i]
        dn[i] -= steps[i]
        brute = (F.objective(up[None], layout, d)[0] - F.objective(dn[None], layout, d)[0]) / (2 * steps[i])
        np.testing.assert_allclose(g[:, col], brute, rtol=1e-6, atol=1e-6 * np.abs(brute).max())
    for s in (0, d.segments - 1):
        for c in range(3):
            i = layout.n_global + 3 * s + c
            up, dn = x.copy(), x.copy()
            up[i] += steps[i]
            dn[i] -= steps[i]
            brute = (F.objective(up[None], layout, d)[0]
                     - F.objective(dn[None], layout, d)[0]) / (2 * steps[i])
            mine = np.where(seg_of == s, js[:seg_of.size, c], 0.0)
            np.testing.assert_allclose(mine, brute[:seg_of.size], rtol=1e-6, atol=1e-6 * np.abs(brute).max())


@pytest.mark.parametrize("w0", [(0.3, 15.0, 0.4), (0.5, 0.5, 25.0)])
def test_a_fast_toss_at_100_hz_is_fitted_to_its_noise(w0):
    """A racquet flipping at 15-25 rad/s sampled at 100 Hz (0.15-0.25 rad per sample): the
    output-error fit reaches the noise and the inertia's ratios (a modulating-function
    equation-error fit leaves 15-33x the noise on the same data)."""
    d = F.prepare(_toss(w0))
    fit = F.fit_nominal(d)
    assert np.sqrt(np.mean(fit.z ** 2)) < 1.15
    moments = np.sort(np.linalg.eigvalsh(fit.inertia))
    truth = np.sort(np.diag(RACQUET))
    np.testing.assert_allclose(moments / moments[-1], truth / truth[-1], atol=0.01)


@pytest.mark.parametrize("w0, drag", [pytest.param((12.0, 0.5, 0.3), False, marks=pytest.mark.science),
                                      ((0.3, 10.0, 0.2), False),
                                      pytest.param((12.0, 0.5, 0.3), True, marks=pytest.mark.science)])
# near the middle axis (a flip, the common real toss); near the major and with the air's drag
# fitted too on demand (the drag fit is guarded in make test by tests/discrepancy/test_flight_air.py)
def test_a_short_flight_is_fitted_to_its_valleys_floor_and_its_shape_intervals_cover(w0, drag):
    """1 s of the racquet's flight at 100 Hz, gyro noise 2e-3 rad/s (given), 8 seeds, torque-free
    or with drag: the fits crawl along a curved valley. Stopped where a step gains under 1 in
    BIC, the ratios' intervals cover the truth on 4 (major axis), 8 (middle axis) and, with
    drag near the major axis, 1 of 8 seeds; polished, on 8, 8 and 8. (With the noise estimated
    from the data, torque-free: 1 and 5 of 8, and a gyro scale or bias named on 3 of the 8 near
    the major axis; polished, 8 and 8, none named.) Near the middle axis with drag (not a case
    here) the intervals cover 5 of these 8 seeds: seeds 0-31 scatter 1.27x the stated sigma,
    32-95 1.00x and 0.72x (README, the paragraph on `identify` and `diagnose` accuracy).
    """
    truth = np.sort(np.diag(RACQUET))[::-1] / RACQUET.max()
    c_true = np.diag([0.1, 0.1, 0.02]) * np.diag(RACQUET)  # N·m·s
    effects = Effect("viscous_damping", {"c": c_true.tolist()}) if drag else ()
    covered = named = 0
    for seed in range(8):
        report = diagnose(_toss(w0, sigma=2e-3, seed=seed, effects=effects)).report
        lo, hi = np.array(report["fit_after"]["principal_ratios_ci95"]).T
        covered += bool(np.all((lo <= truth) & (truth <= hi)))
        named += [e["name"] for e in report["explanation"]] == (["viscous_damping"] if drag else [])
        assert report["gyro_frame_mirrored"] is None  # a right-handed gyro: never read as mirrored
    assert covered >= 7 and named >= 7


def test_the_ratios_intervals_are_the_delta_methods_where_the_ratios_are_linear():
    """A racquet flip with drag (1 s at 100 Hz), whose ratios are linear in the parameters over
    their interval: the percentile interval from the quasi-random draws is the delta method's,
    +-1.96 sqrt(g^T Cov g) with g the ratio's gradient (central differences) and Cov the fit's
    covariance, within 3 %. (400 pseudo-random draws give 3.45e-4 for 3.92e-4 here.)
    """
    c_true = np.diag([0.1, 0.1, 0.02]) * np.diag(RACQUET)
    d = F.prepare(_toss((0.3, 10.0, 0.2), sigma=2e-3, seed=1,
                        effects=Effect("viscous_damping", {"c": c_true.tolist()})))
    fit = F.polished([F.fit_model(["viscous_damping"], [""], d, F.fit_nominal(d))], d)[0]
    ratios, ci = principal_ratios(fit, d)
    cov, idx = F.covariance(fit, d)

    def middle_ratio(x):
        moments = np.sort(np.linalg.eigvalsh(F.model_inertia(fit.layout, x, d)))
        return moments[1] / moments[2]

    grad = np.zeros(idx.size)
    for k, i in enumerate(idx):
        step = 1e-6 * max(abs(fit.x[i]), 1e-3)
        up, down = fit.x.copy(), fit.x.copy()
        up[i] += step
        down[i] -= step
        grad[k] = (middle_ratio(up) - middle_ratio(down)) / (2 * step)
    half = 1.96 * np.sqrt(grad @ cov @ grad)
    assert ratios[1] == pytest.approx(middle_ratio(fit.x), rel=1e-12)
    assert (ci[1][1] - ci[1][0]) / 2 == pytest.approx(half, rel=0.03)
    assert np.mean(ci[1]) == pytest.approx(ratios[1], abs=0.1 * half)


@pytest.mark.science  # 20 fits, 13 s; make test checks the widening's formula (test_statistics.py)
def test_the_shapes_intervals_count_the_residuals_correlation(monkeypatch):
    """A 1-s racquet flip with quadratic drag at 100 Hz whose gyro noise is AR(1), 0.9 from row
    to row, at the stated level: rows correlated over tau of them inform as 1/tau as many. The
    fit's covariance is widened by 1/effective_share, the count the BICs are recounted with: its
    shape's 95 % intervals cover the truth on 13 of 20 seeds, against 8 without the factor (the
    same fits, effective_share patched to 1)."""
    drag = Effect("aero_drag", {"c": np.diag([4e-5, 3e-5, 2e-6])})
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.array([0.3, 15.0, 0.4]), RACQUET, np.zeros((1000, 3)),
                          1e-3, drag)
    rows = np.arange(0, 1001, 10)
    truth = np.sort(np.diag(RACQUET))[::-1] / RACQUET.max()
    share = statistics.effective_share
    covered = {True: 0, False: 0}
    for seed in range(20):
        white = np.random.default_rng(seed).normal(0.0, 0.005, (rows.size, 3))
        noise = np.zeros_like(white)
        noise[0] = white[0]
        for k in range(1, rows.size):
            noise[k] = 0.9 * noise[k - 1] + np.sqrt(1.0 - 0.9 ** 2) * white[k]
        d = F.prepare(Recording(rows * 1e-3, w[rows] + noise, None, None, {"gyro_sigma": 0.005}, "toss"))
        fit = F.fit_effect("aero_drag", d, F.fit_nominal(d))
        for counted in (True, False):
            monkeypatch.setattr(statistics, "effective_share", share if counted else lambda d, fit: 1.0)
            lo, hi = np.array(principal_ratios(fit, d)[1]).T
            covered[counted] += bool(np.all((lo <= truth) & (truth <= hi)))
    assert covered[True] >= 12 and covered[True] - covered[False] >= 4, covered

def test_block_means_remove_vibration_far_above_the_motion():
    """A 4-kHz gyro with a 250-Hz vibration of ten times the sensor noise: the rows are block
    means (22 samples: 5.5 ms, the vibration attenuated to a fifth), the fit reaches their noise
    and the inertia's ratios."""
    n, dt, sigma = 2000, 2.5e-4, 1e-3
    q, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.array([2.0, 15.0, 1.0]), RACQUET,
                          np.zeros((n, 3)), dt)
    t = np.arange(n + 1) * dt
    rng = np.random.default_rng(1)
    vib = 10 * sigma * np.sin(2 * np.pi * 250 * t)[:, None] * np.array([1.0, -0.5, 0.7])
    rec = Recording(t, w + vib + rng.normal(0, sigma, w.shape), None, None, {}, "vibrating")
    d = F.prepare(rec)
    assert d.block >= 8 and "means" in d.sigma_source
    per_sample = np.sqrt(sigma ** 2 + 0.5 * (10 * sigma) ** 2 * np.array([1.0, 0.25, 0.49]))
    assert np.all(d.sigma < 0.7 * per_sample)
    fit = F.fit_nominal(d)
    assert np.sqrt(np.mean(fit.z ** 2)) < 1.5
    moments = np.sort(np.linalg.eigvalsh(fit.inertia))
    truth = np.sort(np.diag(RACQUET))
    np.testing.assert_allclose(moments / moments[-1], truth / truth[-1], atol=0.01)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_drag_nil_about_one_axis_is_fitted_and_stays_dissipative(seed):
    """A racquet toss with air drag about the two broad axes and none about the handle (C of
    rank 2, as the real tosses fit): the drag fit finds C's two coefficients within 15 % and
    nothing about the handle, and every step is projected onto dissipative C (a penalty row
    leaves C slightly indefinite here, and freezes the drag fit of two real tosses at C = 0).
    """
    c_true = np.diag([0.1, 0.1, 0.0]) * np.diag(RACQUET)  # N·m·s: ~10 % spin decay over the toss
    w0 = np.array([0.3, 15.0, 0.4]) + np.random.default_rng(seed).normal(0, 0.3, 3)
    d = F.prepare(_toss(w0, seed=seed + 10, effects=Effect("viscous_damping", {"c": c_true.tolist()})))
    nominal = F.fit_nominal(d)
    fit = F.fit_model(("viscous_damping",), ("",), d, nominal)
    assert nominal.bic - fit.bic > 100
    assert np.sqrt(np.mean(fit.z ** 2)) < 1.2
    c = fit.params["c"] * np.trace(RACQUET) / np.trace(fit.inertia)  # the toss's scale is free
    np.testing.assert_allclose(np.diag(c)[:2], np.diag(c_true)[:2], rtol=0.15)
    assert np.linalg.eigvalsh(fit.params["c"])[0] >= -1e-12
    assert abs(c[2, 2]) < 0.05 * c_true[0, 0]


def test_clipped_samples_are_left_out_and_reported():
    rec = _toss((0.3, 15.0, 0.4), sigma=0.002)
    # a gyro whose range ends just below the fastest rate: ten samples beyond it
    top = np.sort(np.abs(rec.w).ravel())[-11]
    w = np.clip(rec.w, -top, top)
    assert 3 <= (np.abs(w) >= top).sum() <= 20
    d = F.prepare(dataclasses.replace(rec, w=w))
    clipped = np.any(np.abs(w) >= top, axis=1)
    assert d.notes["saturated_samples"] == clipped.sum()
    assert np.all(d.row[clipped] == -1)
    assert np.sqrt(np.mean(F.fit_nominal(d).z ** 2)) < 1.3
    # a full scale in the sidecar is trusted: the samples at it (off a lattice) are clipped
    beyond = dataclasses.replace(rec, w=np.clip(rec.w, -14.0, 14.0),
                                 meta={**rec.meta, "gyro_full_scale_rad_s": 14.0})
    at_rail = int(np.any(np.abs(rec.w) >= 14.0, axis=1).sum())
    assert F.prepare(beyond).notes["saturated_samples"] == at_rail > 0


def test_impulses_at_the_ends_are_trimmed_and_a_drift_is_not():
    rec = _toss((0.3, 15.0, 0.4), sigma=0.002)
    hit = rec.w.copy()
    hit[-3:] += np.array([0.5, -0.4, 0.3])  # a catch
    hit[:4] += np.outer([0.6, -0.5, 0.4, -0.3], [1.0, 1.0, -1.0])  # the hand letting go
    report = diagnose(dataclasses.replace(rec, w=hit)).report
    trimmed = {e["where"]: e["samples"] for e in report["trimmed"]}
    assert 3 <= trimmed.get("start", 0) <= 8 and 2 <= trimmed.get("end", 0) <= 6
    assert max(report["fit_after"]["rms_over_noise"]) < 1.5
    # a constant torque makes a drift growing to the end: it is explained, not trimmed
    drift, _ = simulate_recording(Scenario(tau_max=50.0), 20.0, "constant_body_torque", seed=2)
    drift = dataclasses.replace(drift, meta={k: v for k, v in drift.meta.items() if k != "effect"})
    report = diagnose(drift).report
    assert report["trimmed"] == [] and report["best_effect"] == "constant_body_torque"


def test_an_impulse_the_first_searchs_explanation_uncovers_is_trimmed_before_the_other_searches_run(
        monkeypatch):
    """A small catch that a strong drag's misfit hides from the nominal fit stands out once the
    first search has explained the drag: the record is trimmed then, and select's searches run
    only on the trimmed record (run on both, they would take 1.3 s more of racquet round 1
    segment 2's 5.6)."""
    drag = Effect("aero_drag", {"c": np.diag([3e-4, 2.25e-4, 1.5e-5])})
    rec = _toss((0.3, 15.0, 0.4), effects=drag)
    hit = rec.w.copy()
    hit[-2:] += np.array([0.08, -0.08, 0.08])  # a catch
    found, selected = [], []
    impulses, select = report_module.impulses, report_module.select
    monkeypatch.setattr(report_module, "impulses",
                        lambda d, fit: found.append((fit.names, impulses(d, fit))) or found[-1][1])
    monkeypatch.setattr(report_module, "select",
                        lambda d, *args, **kw: selected.append(d.n_rows) or select(d, *args, **kw))
    report = diagnose(dataclasses.replace(rec, w=hit)).report
    assert found[0] == ((), (0, 0))  # the nominal fit does not show it
    assert found[1][0] and found[1][1][1] == 2  # the first search's explanation does
    assert [(e["where"], e["samples"]) for e in report["trimmed"]] == [("end", 2)]
    assert selected and set(selected) == {rec.t.size - 2}
    assert report["explanation"][0]["name"] in ("aero_drag", "viscous_damping")


def _slow_tumble_with_momentum() -> tuple[Recording, np.ndarray]:
    """The slow tumble of records.slow_tumble with a constant internal momentum of ~4 %
    of the body's own; and the momentum (3,) kg·m²/s. Where the momentum's starts keep the
    nominal fit's rates, its diagnosis names a constant torque, a varying momentum and a
    flexible mode (the test below)."""
    rec, truth = slow_tumble("internal_momentum", 2, 202)
    return rec, np.asarray(truth["internal_momentum"]["h"])


def test_the_pairs_harness_measures_what_each_true_effect_shows():
    """records.true_gains: a mode at rest in a torque-free tumble, beside a
    constant torque, is never excited: the truth gains less with it than its 7 parameters cost;
    the torque gains what the truth without it (fitted from the true parameters) lacks, about
    what the torque alone gains over the nominal fit."""
    rec, truth = slow_tumble(["constant_body_torque", "flexible_mode"], 0, 300)
    d = F.prepare(rec)
    nominal = F.fit_nominal(d)
    gains = true_gains(truth, d, nominal)
    assert gains["flexible_mode"] < 0
    assert gains["constant_body_torque"] > 100 * F.claim_margin(d, "constant_body_torque")
    torque_alone = F.fit_model(("constant_body_torque",), ("",), d, nominal)
    assert gains["constant_body_torque"] > 0.9 * (nominal.bic - torque_alone.bic)


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "duration"),
                         [(0, 150.0), (5, 300.0), pytest.param(9, 300.0, marks=pytest.mark.science)])
def test_a_momentum_beside_a_gyro_bias_is_found_from_its_own_start(seed, duration):
    """A gyro bias and a constant momentum on a slow tumble, where the other's start does not
    lead to the truth. Seed 0: the momentum screened on top of the bias from its single fit (made
    with the bias missing) gains too little, and a constant torque would stand in for it; its own
    start on top of the bias is tried too (restarts_on_base) and found. Seed 9 (on demand): led by
    the momentum, the bias's screen ranks below an inertia offset's; refitted jointly from its own
    start, the bias is found. Without restarts_on_base, seed 0 names a constant torque in the
    momentum's place. Seed 5: in the simplest-form search, after the constant momentum the residual
    tests white, and the bias's screen gains nothing (it trades with the fitted momentum, held
    there), but its score test (fitting.predicted_bic) clears the claim margin: that search is
    run again with the bias refitted jointly, and its explanation, the truth, costs least; without
    that search, a loaded mode and a constant torque are named."""
    rec, truth = slow_tumble(["internal_momentum", "gyro_bias"], seed, 300, duration=duration)
    report = diagnose(rec).report
    named = {e["name"]: e for e in report["explanation"]}
    assert set(named) == {"gyro_bias", "internal_momentum"}
    assert named["internal_momentum"]["form"] == "constant"
    h = np.asarray(truth["internal_momentum"]["h"])
    assert np.linalg.norm(np.asarray(named["internal_momentum"]["params"]["h"]) - h) < 0.1 * np.linalg.norm(h)
    assert max(report["fit_after"]["rms_over_noise"]) < 1.1


def test_a_start_takes_each_segments_rates_from_its_first_sample_where_they_fit_it_better():
    """The nominal fit's rates bend to stand in for what it lacks: the momentum's equation-error
    start (within 2 % of the truth) with them costs more than no momentum at all and its fit stalls
    (a gain of 821 in BIC where the truth gains 93324); with each segment's first sample's rates,
    where they fit that segment better, the fit reaches the truth."""
    rec, h = _slow_tumble_with_momentum()
    report = diagnose(rec).report
    first, = report["explanation"]
    assert (first["name"], first["form"]) == ("internal_momentum", "constant")
    assert np.linalg.norm(np.asarray(first["params"]["h"]) - h) < 0.03 * np.linalg.norm(h)
    assert max(report["fit_after"]["rms_over_noise"]) < 1.1
    # segment by segment the cheaper rates: never dearer than either set
    d = F.prepare(rec)
    nominal = F.fit_nominal(d)
    layout = F.Layout.of(("internal_momentum",), ("constant",), d, nominal.layout.omega_max)
    probe = F.Probe(layout, d, nominal)
    xs = [probe.x(h), probe.x(np.zeros(3))]
    measured = [np.concatenate([x[:probe.layout.n_global], F.initial_rates(d)]) for x in xs]
    chosen = probe.with_segment_rates(xs)
    assert np.all(probe.costs(chosen) <= np.minimum(probe.costs(xs), probe.costs(measured)) * (1 + 1e-12))
    assert probe.costs(chosen)[0] < 0.01 * probe.costs(xs)[0]


def _rotor_recording(seed=5):
    """A slowly tumbling body with a rotor spinning up and down along a random axis, logged."""
    sc = Scenario(omega0=(0.3, 2.0, -0.4), tau_max=50.0, gyro_sigma=0.005)
    rec, side = simulate_recording(sc, 20.0, None, seed=seed, torque=False, sample_dt=0.02,
                                   rotor_h_max=60.0)
    meta = {k: v for k, v in rec.meta.items() if k not in ("rotor", "inertia_nominal")}
    return dataclasses.replace(rec, meta=meta), np.asarray(side["rotor"]["axis"])


@pytest.mark.slow
def test_a_rotor_withheld_is_named_with_its_axis_and_not_claimed_when_logged():
    """A rotor spinning up and braking, 0.5 (1 - cos 2 pi t / T) over the record T, withheld: the
    momentum the explanation draws lies along the rotor's axis. That profile is a constant and
    one cycle of a cosine, which a constant momentum beside an undamped mode of period T
    coupled along the axis draws exactly, with 10 parameters to the varying momentum's 24: where
    the explanation reads it so, the mode is that slow and says it is confounded with the
    momentum (a spin-up that is no cosine: tests/discrepancy/test_spin_up*.py)."""
    rec, axis = _rotor_recording()
    report = diagnose(dataclasses.replace(rec, h=None)).report
    named = {e["name"]: e for e in report["explanation"]}
    assert "internal_momentum" in named and set(named) <= {"internal_momentum", "flexible_mode"}
    momentum = named["internal_momentum"]
    along = [momentum["params"]["axis" if momentum["form"] == "varying" else "h"]]
    if "flexible_mode" in named:
        mode = named["flexible_mode"]
        assert momentum["form"] == "constant" and 2 * np.pi / mode["params"]["omega_n"] > 0.5 * rec.t[-1]
        assert "internal_momentum" in {c["with"] for c in mode["confounded_with"]}
        assert "a momentum that rises and falls along that axis" in markdown(report, [])
        along.append(mode["params"]["coupling"])
    for fitted in map(np.asarray, along):
        assert np.degrees(np.arccos(min(1.0, abs(fitted @ axis) / np.linalg.norm(fitted)))) < 10.0
    assert max(report["fit_after"]["rms_over_noise"]) < 1.5 < min(report["fit_before"]["rms_over_noise"])
    logged = diagnose(rec).report
    assert "internal_momentum" in logged["skipped_effects"] and logged["explanation"] == []
    assert max(logged["fit_after"]["rms_over_noise"]) < 1.2


@pytest.mark.slow
def test_a_rotated_rotor_axis_is_momentum_misalignment():
    rec, _ = _rotor_recording(seed=6)  # the same body, its rotor logged where it is
    sc = Scenario(omega0=(0.3, 2.0, -0.4), tau_max=50.0, gyro_sigma=0.005)
    bent, side = simulate_recording(sc, 20.0, "momentum_misalignment", {"rotvec": [0.08, -0.05, 0.0]},
                                    seed=6, torque=False, sample_dt=0.02, rotor_h_max=60.0)
    bent = dataclasses.replace(bent, meta={k: v for k, v in bent.meta.items()
                                           if k not in ("rotor", "inertia_nominal", "effect")})
    report = diagnose(bent).report
    assert report["explanation"][0]["name"] == "momentum_misalignment"
    # one rotor keeps its direction: the turn about it is not seen, the rotor's axis is
    axis = np.asarray(side["rotor"]["axis"])
    fitted = rotvec_matrix(report["explanation"][0]["params"]["rotvec"]) @ axis
    true = rotvec_matrix([0.08, -0.05, 0.0]) @ axis
    assert np.degrees(np.arccos(min(1.0, fitted @ true))) < 0.5
    assert REGISTRY["momentum_misalignment"].skip_reason(F.prepare(dataclasses.replace(rec, h=None)))


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_an_effect_at_its_neutral_parameters_changes_nothing(name):
    """The start a candidate may screen from: added to a fit at its neutral parameters, every
    effect (in every form) leaves that fit's residual as it was."""
    model = REGISTRY[name]
    other = "gyro_scale" if name == "gyro_bias" else "gyro_bias"
    rec, _ = simulate_recording(Scenario(tau_max=50.0), 12.0, other, seed=3,
                                rotor_h_max=30.0 if model.needs_momentum else None)
    d = F.prepare(rec)
    base = F.fit_model((other,), ("",), d, F.fit_nominal(d))
    assert model.skip_reason(d) is None
    forms = model.forms(d)
    # varying forms, and the mode that also moves the body's mass
    assert len(forms) == (2 if name in ("internal_momentum", "viscous_damping", "flexible_mode") else 1)
    for form in forms:
        layout = F.Layout.of((other, name), ("", form), d, base.layout.omega_max)
        x = F.Probe(layout, d, base).x(model.neutral(form, d, base))
        np.testing.assert_allclose(F.whitened(x[None], layout, d)[0], base.z, atol=1e-9)


def test_rows_too_far_apart_for_the_rotation_are_refused():
    """A time column in the wrong unit (rows 1000 s apart at 10 rad/s) is a one-line error."""
    rec, _ = simulate_recording(Scenario(), 1.0, seed=4)
    with pytest.raises(RecordingError, match="too far apart"):
        diagnose(dataclasses.replace(rec, t=rec.t * 1e5))


def test_the_rigid_fit_of_a_real_toss_keeps_the_best_basin_any_start_reaches(racquet_toss):
    """A real toss (round 1, segment 1) cut 0.05 s shorter at both ends is one segment: the start
    chosen on short pieces leads the whole toss to a worst-axis rms of about 11 rad/s (1604x the
    noise level the third differences read) with principal ratios (1, 0.06, 0.03), where the
    equation-error start reaches 1.2 rad/s and (1, 0.81, 0.20). The nominal fit is within
    the significance margin of the best of its starts run to convergence on the record."""
    d = F.prepare(retimed(racquet_toss("round1", 1, (0.05, -0.05))))
    assert d.segments < F.SHORT_SEGMENTS
    nominal = F.fit_nominal(d)
    layout = F.Layout.of((), (), d)
    lb, ub = _bounds(layout, d)
    free = _free(layout, d)
    runs = [F.solve(np.r_[phi, F.initial_rates(d)], free, layout, d, lb, ub, F.FULL_ITER).x
            for phi in _inertia_starts(d)]
    direct = [F.finish(layout, x, d) for x in runs]
    assert nominal.bic <= min(f.bic for f in direct) + F.SIGNIFICANT_DELTA_BIC
    worst_axis = np.sqrt(np.mean(nominal.r ** 2, 0)).max()
    assert worst_axis < 2.0  # rad/s; about 11 from the start chosen on short pieces
    ratios = np.sort(np.linalg.eigvalsh(nominal.inertia))[::-1]
    np.testing.assert_allclose(ratios / ratios[0], [1.0, 0.81, 0.20], atol=0.03)


def test_a_fit_asked_again_is_reused_and_rescored_on_recounted_rows(monkeypatch):
    """fit_model keeps its fits in d.cache: the same fit asked again on the same rows is not
    solved again, on the rows recounted (effective_share) it is re-scored with their BIC, and on
    the same data cut into other segments it is solved anew (its rates are other unknowns).
    """
    c_true = np.diag([0.1, 0.1, 0.0]) * np.diag(RACQUET)
    d = F.prepare(_toss([0.3, 15.0, 0.4], seed=4, effects=Effect("viscous_damping", {"c": c_true.tolist()})))
    nominal = F.fit_nominal(d)
    first = F.fit_model(("viscous_damping",), ("",), d, nominal)
    short = d.resegmented(4)
    assert short.segments != d.segments
    short_nominal = F.fit_nominal(short)

    def solve_again(*args, **kwargs):
        raise AssertionError("solved again")

    monkeypatch.setattr(fitting, "solve_many", solve_again)  # every solve runs through it
    same = F.fit_model(("viscous_damping",), ("",), d, nominal)
    np.testing.assert_array_equal(same.x, first.x)
    assert same.bic == first.bic
    again = F.fit_model(("viscous_damping",), ("",), dataclasses.replace(d, effective_share=0.25), nominal)
    np.testing.assert_array_equal(again.x, first.x)
    n = first.z.size * 0.25
    assert again.bic == pytest.approx(n * np.log(np.mean(first.z ** 2)) + first.k * np.log(n), rel=1e-12)
    with pytest.raises(AssertionError, match="solved again"):
        F.fit_model(("viscous_damping",), ("",), short, short_nominal)


def test_an_effects_own_starts_are_found_once_per_base(monkeypatch):
    """Probe.own_starts keeps an effect's starts for the same base on the same rows: a second
    search asks them without the screen running again, and gets copies (a start moved by one
    fit does not move the next one's).
    """
    d = F.prepare(_toss([0.3, 15.0, 0.4], seed=6))
    nominal = F.fit_nominal(d)
    layout = F.Layout.of(("flexible_mode",), ("",), d)
    first = F.Probe(layout, d, nominal).own_starts()
    assert first
    monkeypatch.setattr(F.Probe, "mode_starts", lambda self: pytest.fail("screened again"))
    again = F.Probe(layout, d, nominal).own_starts()
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    again[0][:] = np.nan
    assert np.all(np.isfinite(F.Probe(layout, d, nominal).own_starts()[0]))


def test_diagnose_says_an_axis_held_at_its_extreme_at_both_ends():
    """A torque-free axisymmetric spin (I = 2, 2, 1 g·m², 2.5 rad/s about the axis: the transverse
    rate turns at 1.25 rad/s with amplitude 3) recorded for one turn at 100 Hz, its x axis clipped
    at 2.7 rad/s, which it reads only in its first and last ~36 samples, steps of 0.004: as
    identify's misfit notes do, diagnose's report lists the two ends (`clipped_at_ends`) and its
    summary asks for the full scale; given, the rows are left out and nothing is said."""
    from inertia_gym.discrepancy.report import diagnose, markdown

    t = np.arange(0.0, 2 * np.pi / 1.25, 0.01)
    w = np.stack([3.0 * np.cos(1.25 * t), -3.0 * np.sin(1.25 * t), np.full(t.size, 2.5)], 1)
    read = np.round((w + np.random.default_rng(1).normal(0.0, 0.002, w.shape)) / 0.004) * 0.004
    read[:, 0] = np.minimum(read[:, 0], 2.7)
    nominal = np.diag([2e-3, 2e-3, 1e-3]).tolist()
    report = diagnose(Recording(t, read, meta={"inertia_nominal": nominal})).report
    ends = [phrase.split(" in its ")[1].split()[0] for phrase in report["clipped_at_ends"]]
    assert ends == ["first", "last"]
    assert all(p.startswith("the x axis reads 2.7 rad/s") for p in report["clipped_at_ends"])
    assert report["saturated_samples"] == 0
    assert "gyro_full_scale_rad_s" in markdown(report, [])
    given = diagnose(Recording(t, read, meta={"gyro_full_scale_rad_s": 2.7})).report
    assert given["clipped_at_ends"] == [] and given["saturated_samples"] > 0
    assert "gyro_full_scale_rad_s" not in markdown(given, [])


def _drag_and_bias_layout():
    """A 1-s toss with a drag and a gyro bias, prepared, its layout and the truth's x."""
    c_true = np.diag([0.1, 0.1, 0.0]) * np.diag(RACQUET)
    d = F.prepare(_toss([0.3, 15.0, 0.4], seed=5, effects=Effect("viscous_damping", {"c": c_true.tolist()})))
    layout = F.Layout.of(("viscous_damping", "gyro_bias"), ("", ""), d)
    nominal = F.fit_nominal(d)
    x = np.r_[nominal.x[:6], np.zeros(layout.sizes[0]), [0.01, -0.02, 0.005], nominal.x[6:]]
    x[layout.slices()[0]] = REGISTRY["viscous_damping"].neutral("", d, nominal)
    return d, layout, x


def test_a_batch_predicts_each_model_as_it_predicts_it_alone():
    """predict builds the effects' terms once per effect parameters and applies the gyro's terms
    to all trajectories of one model together: a batch mixing inertias, effect parameters and
    initial rates predicts for each x exactly what that x gives alone."""
    d, layout, x = _drag_and_bias_layout()
    xs = np.repeat(x[None], 5, axis=0)
    xs[1, 0] += 0.05  # another inertia, the same effects
    xs[2, layout.slices()[1]] += 0.003  # another bias, the same inertia
    xs[3, layout.n_global] += 0.1  # other initial rates
    xs[4, 0] += 0.05  # the inertia of the second with the bias of the third
    xs[4, layout.slices()[1]] += 0.003
    batch = F.predict(xs, layout, d)
    for i, xi in enumerate(xs):
        np.testing.assert_array_equal(batch[i], F.predict(xi[None], layout, d)[0])
    assert not np.array_equal(batch[0], batch[2])  # the bias is read: the check is not vacuous
    np.testing.assert_allclose(batch[2] - batch[0], np.broadcast_to([0.003, 0.003, 0.003], batch[0].shape))


def test_solves_side_by_side_give_what_each_gives_alone(monkeypatch):
    """solve_many integrates the points its solves ask for in one batch, and each iteration
    tries SPECULATE dampings at once: neither changes a solve's path, bit for bit."""
    d, layout, x = _drag_and_bias_layout()
    lb, ub = _bounds(layout, d)
    free = _free(layout, d)
    starts = [x, x + np.r_[0.1, np.zeros(x.size - 1)], np.where(np.arange(x.size) == 6, x * 2, x)]
    together = F.solve_many(starts, free, layout, d, lb, ub, F.FULL_ITER)
    for speculate in (1, 2, 3):
        monkeypatch.setattr(solver, "SPECULATE", speculate)
        for x0, batch in zip(starts, together):
            alone = F.solve(x0, free, layout, d, lb, ub, F.FULL_ITER)
            np.testing.assert_array_equal(alone.x, batch.x)
            assert alone.cost == batch.cost
    assert together[0].cost < float(np.sum(F.objective(x[None], layout, d) ** 2))  # the solves moved


@pytest.mark.parametrize("name", ["s0.02_e0.005_d1.2_seed3",  # one segment: 12x in a basin of its own
                                  "s0.02_e0.005_d6_seed2"])  # five: one left at 4000x from its first sample
def test_a_clean_thin_body_is_fitted_to_the_noise_and_nothing_is_named(tmp_path, name):
    # A thin, nearly flat body (moments 1 : 0.985 : 0.02; a racquet is 1 : 0.91 : 0.07): its
    # fastest rate turns with (J1 - J2) / J3, a ratio of two small numbers: without the continued
    # start the linear start's fit stops in a basin of its own (12x and 2800x the noise), and 7 of
    # 32 such 1.2-s records and 8 of 12 longer ones name effects on clean data.
    rec, inertia = thin_body(tmp_path, name)
    d = F.prepare(rec)
    nominal = F.fit_nominal(d)
    assert np.sqrt(np.mean(nominal.z ** 2, axis=0)).max() < 1.2
    truth = np.linalg.eigvalsh(inertia)
    fitted = np.linalg.eigvalsh(nominal.inertia)
    np.testing.assert_allclose(fitted / fitted[-1], truth / truth[-1], atol=2e-3)
    report = diagnose(rec).report
    assert report["explanation"] == []


def test_a_mirrored_gyro_frame_is_said_where_no_right_handed_body_fits(tmp_path):
    # A flat plate (moments 1 : 0.99 : 0.01) tumbling, its gyro's x and y columns swapped: no
    # right-handed rigid body fits it (a plate's mirror is a rod's limit), and the fits name an
    # inertia change; the same rates fitted with the columns swapped back reach the noise.
    _, seed, moments, duration, rate, middle = next(c for c in cases() if c[0] == "s0.01_e0.0_d1.2_seed0")
    path = tmp_path / "mirrored.csv"
    thin_body_record(path, seed, moments, duration, rate, middle, mirrored=True)
    report = diagnose(read_csv_recording(path)).report
    frame = report["gyro_frame_mirrored"]
    assert frame is not None and max(frame["rms_over_noise"]) < 1.3 and frame["delta_bic"] > 10
    np.testing.assert_allclose(frame["principal_ratios"], [1.0, 0.99, 0.01], atol=2e-3)
    assert "the gyro's frame reads left-handed" in markdown(report, [])
    plain, _ = thin_body(tmp_path, "s0.01_e0.0_d1.2_seed0")
    report = diagnose(plain).report
    assert report["gyro_frame_mirrored"] is None and report["explanation"] == []


def test_the_score_test_predicts_what_a_bias_gains_when_fitted_jointly():
    """fitting.predicted_bic: a gyro bias moves the measured rates linearly, so one Gauss-Newton
    step of the joint model from the nominal fit with the bias at zero predicts the BIC its joint
    fit reaches (the BIC's logarithm counted: the gain is thousands); at the joint fit's floor,
    nothing is left to predict."""
    rec, _ = slow_tumble("gyro_bias", 0, 300, duration=60.0)
    d = F.prepare(rec)
    nominal = fitting.fit_nominal(d)
    joint = fitting.fit_model(("gyro_bias",), ("",), d, nominal)
    at_zero = finish(joint.layout, Probe(joint.layout, d, nominal).x(np.zeros(3)), d)
    gain = nominal.bic - joint.bic
    assert gain > 1000
    assert nominal.bic - fitting.predicted_bic(at_zero, d) == pytest.approx(gain, rel=0.01)
    assert joint.bic - fitting.predicted_bic(joint, d) == pytest.approx(0.0, abs=0.1)
