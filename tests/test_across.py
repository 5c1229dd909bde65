"""What several recordings say together (inertia_gym.across): the combined estimate against its
definition and its coverage over fixed seeds, the shape's covariance against finite
differences, and the summaries of diagnoses and identifications."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from inertia_gym.across import (
    combined,
    diagnoses_across,
    diagnoses_markdown,
    identifications_across,
    identifications_markdown,
    series_name,
    source_words,
)
from inertia_gym.estimation.uncertainty import InertiaEstimate


def _random_effects(y, v):
    """DerSimonian-Laird's tau^2 and the Hartung-Knapp interval of one component, written out
    from their textbook definitions: y (n,) estimates, v (n,) their variances."""
    n, w = len(y), 1 / v
    q = np.sum(w * (y - np.sum(w * y) / np.sum(w)) ** 2)
    tau2 = max(0.0, (q - (n - 1)) / (np.sum(w) - np.sum(w ** 2) / np.sum(w)))
    ws = 1 / (v + tau2)
    mu = np.sum(ws * y) / np.sum(ws)
    hk = np.sum(ws * (y - mu) ** 2) / (n - 1)
    half = stats.t.ppf(0.975, n - 1) * np.sqrt(max(hk, 1.0) / np.sum(ws))
    return mu, tau2, half


def test_agreeing_estimates_give_their_weighted_mean_and_its_interval():
    values = [np.array([1.0, 2.0]), np.array([1.02, 2.01]), np.array([0.99, 1.995])]
    sigmas = [np.array([0.1, 0.2]), np.array([0.2, 0.1]), np.array([0.1, 0.1])]
    out = combined(values, [np.diag(s ** 2) for s in sigmas])
    x, v = np.array(values), np.array(sigmas) ** 2
    w = 1 / v
    mean = (w * x).sum(0) / w.sum(0)
    chi2 = float(np.sum(w * (x - mean) ** 2))
    half = stats.t.ppf(0.975, 2) / np.sqrt(w.sum(0))  # the scatter is within the weights: HK's floor
    assert out["source"] == "intervals" and out["n"] == 3 and out["dof"] == 4 and out["between_sd"] == [0, 0]
    assert np.allclose(out["estimate"], mean)
    assert np.allclose(np.array(out["ci95"]), np.stack([mean - half, mean + half], 1))
    assert out["chi2"] == pytest.approx(chi2) and out["p"] == pytest.approx(stats.chi2.sf(chi2, 4))
    assert out["median"] == [1.0, 2.0] and out["min"] == [0.99, 1.995] and out["max"] == [1.02, 2.01]
    assert "no more than their own intervals allow" in source_words(out)


def test_disagreeing_estimates_get_a_between_recording_error():
    """Estimates far farther apart than their intervals: DerSimonian-Laird's tau^2 joins each
    recording's variance, and the interval is Hartung-Knapp's."""
    values = [np.array([1.0]), np.array([2.0]), np.array([1.5]), np.array([1.2])]
    sigmas = np.array([0.01, 0.02, 0.01, 0.04])
    out = combined(values, [np.array([[s ** 2]]) for s in sigmas])
    mu, tau2, half = _random_effects(np.array(values)[:, 0], sigmas ** 2)
    assert out["source"] == "random effects" and out["p"] < 1e-10
    assert out["between_sd"] == [pytest.approx(np.sqrt(tau2))] and np.sqrt(tau2) > 0.3
    assert out["estimate"] == [pytest.approx(mu)]
    assert np.allclose(out["ci95"], [[mu - half, mu + half]])
    assert "understates its error" in source_words(out) and "random effects" in source_words(out)


def test_singular_or_missing_intervals_fall_back_to_the_scatter():
    values = [np.array([1.0, 2.0]), np.array([1.1, 2.2])]
    out = combined(values, [np.zeros((2, 2)), np.eye(2)])
    assert out["source"] == "scatter" and out["chi2"] is None and out["ci95"] is not None
    alone = combined(values[:1], [np.full((2, 2), np.nan)])
    assert alone["source"] == "scatter" and alone["ci95"] is None and alone["estimate"] == [1.0, 2.0]
    assert combined([], []) is None
    one = combined(values[:1], [np.eye(2) * 0.01])
    assert one["source"] == "intervals" and one["p"] == 1.0


@pytest.mark.parametrize("understated, recordings", [
    ("none", 5), ("3x", 5), ("model error", 5), ("model error", 12)])
def test_the_combined_interval_covers_the_truth_about_95_percent(understated, recordings):
    """Over 400 fixed seeds of 5 or 12 recordings of one ratio, their stated sigmas spread over
    two decades (0.001-0.1): intervals honest, all 3x too narrow, or missing an error of 0.02
    of each recording's own (a model misfit: the real tosses' case). The combined interval
    covers the truth on 88.5-99.8 % of seeds (measured); weighting by the stated intervals, even
    widened by one common factor, covers 62 % of the model-error seeds (a separate simulation)."""
    covered = 0
    for seed in range(400):
        rng = np.random.default_rng(seed)
        sigma = 0.01 * 10 ** rng.uniform(-1, 1, recordings)
        true_sd = {"none": sigma, "3x": 3 * sigma, "model error": np.hypot(sigma, 0.02)}[understated]
        values = [np.array([0.9 + s * rng.standard_normal()]) for s in true_sd]
        out = combined(values, [np.array([[s ** 2]]) for s in sigma])
        (lo, hi), = out["ci95"]
        covered += lo <= 0.9 <= hi
    assert 0.85 <= covered / 400 <= 1.0


def test_the_shapes_covariance_is_the_delta_method_of_the_inertias():
    """InertiaEstimate.principal_ratios: ratios of the principal moments, descending over the
    largest, and their covariance from theta's by the gradient, here checked against central
    finite differences of the ratios themselves."""
    theta = np.array([0.45, 0.02, -0.01, 0.40, 0.005, 0.05])  # xx, xy, xz, yy, yz, zz
    a = np.random.default_rng(0).normal(size=(6, 6)) * 1e-3
    est = InertiaEstimate(theta, a @ a.T, False)
    ratios, cov = est.principal_ratios()

    def shape(t):
        j = np.array([[t[0], t[1], t[2]], [t[1], t[3], t[4]], [t[2], t[4], t[5]]])
        m = np.sort(np.linalg.eigvalsh(j))[::-1]
        return m / m[0]

    jac = np.stack([(shape(theta + 1e-7 * e) - shape(theta - 1e-7 * e)) / 2e-7 for e in np.eye(6)], 1)
    assert np.allclose(ratios, shape(theta))
    assert np.allclose(cov, jac @ est.theta_cov @ jac.T, rtol=1e-5, atol=1e-14)
    assert np.all(cov[0] == 0) and np.all(cov[:, 0] == 0)


def _report(lead, before, after, ratios, valid=True, half=0.01, reading=None, singles=None, params=None,
            mirrored=None):
    """A report.json dict as diagnose writes it, with what the summaries read: singles {effect:
    its single-effect delta BIC (None: no valid fit)}, params {effect: its params in the
    explanation}, mirrored its gyro_frame_mirrored."""
    fit_after = {"valid": valid, "rms_over_noise": after if valid else None,
                 "principal_ratios": ratios if valid else None,
                 "principal_ratios_ci95": None if not valid else
                 [[r - half * (k > 0), r + half * (k > 0)] for k, r in enumerate(ratios)]}
    return {"explanation": [{"name": n, "params": (params or {}).get(n, {})} for n in lead],
            "effects": [{"name": n, "delta_bic": v} for n, v in (singles or {}).items()],
            "beyond_catalogue": not valid or max(after) > 20, "gyro_frame_mirrored": mirrored,
            "fit_before": {"rms_over_noise": before}, "fit_after": fit_after,
            "invariants": ({"applicable": False} if reading is None
                           else {"applicable": True, "reading": reading})}


def test_diagnoses_across_counts_leads_and_compares_fits():
    drag = "against the angular momentum"
    done = [("a", _report(["viscous_damping", "flexible_mode"], [50, 10, 5], [2, 1, 1], [1, 0.93, 0.07],
                          reading=drag)),
            ("b", _report(["viscous_damping"], [80, 20, 9], [3, 2, 1], [1, 0.94, 0.066], reading=drag)),
            ("c", _report(["internal_momentum"], [200, 9, 9], [30, 2, 2], [1, 0.8, 0.2],
                          reading="adds to the rotation",
                          mirrored={"rms_over_noise": [1, 1, 1], "delta_bic": 50.0,
                                    "principal_ratios": [1, 0.99, 0.01]})),
            ("d", _report([], [1.1, 1.0, 0.9], [1.1, 1.0, 0.9], [1, 0.92, 0.07], valid=False))]
    out = diagnoses_across(done, [("e", "too short")])
    assert out["gyro_frame_mirrored"] == 1
    assert "The gyro's frame reads left-handed** on 1 of 4" in diagnoses_markdown(out)
    assert diagnoses_across(done[:2], [])["gyro_frame_mirrored"] == 0
    assert "left-handed" not in diagnoses_markdown(diagnoses_across(done[:2], []))
    assert out["recordings"] == 5 and out["diagnosed"] == 4
    assert out["refused"] == [{"name": "e", "reason": "too short"}]
    assert out["leading_effects"] == {"viscous_damping": 2, "internal_momentum": 1, "none": 1}
    assert out["leading_causes"] == {"drag": {"count": 2, "effects": {"viscous_damping": 2}},
                                     "internal momentum": {"count": 1, "effects": {"internal_momentum": 1}},
                                     "none": {"count": 1, "effects": {"none": 1}}}
    assert ("Its physical cause (the catalogue's family of each leading effect): drag on 2 (50%: "
            "`viscous_damping` 2); internal momentum on 1 (25%: `internal_momentum` 1); none on 1 (25%)"
            in diagnoses_markdown(out))
    assert out["most_common_lead"] == {"name": "viscous_damping", "count": 2, "share": 0.5}
    assert out["valid_fits"] == 3 and out["beyond_catalogue"] == 2
    assert out["invariants_readings"] == {drag: 2, "adds to the rotation": 1, "not applicable": 1}
    assert [row["invariants_reading"] for row in out["rows"]] == [drag, drag, "adds to the rotation",
                                                                   "not applicable"]
    # worst axes: before 50, 80, 200, 1.1 (median 65); after 2, 3, 30 (the invalid fit has none)
    assert out["worst_rms_over_noise"] == {"before_median": 65.0, "after_median": 3.0, "fall": 65.0 / 3.0}
    shape = out["principal_ratios"]  # the valid fits' shapes: c's far from a's and b's
    assert shape["n"] == 3 and shape["source"] == "random effects" and shape["estimate"][0] == 1.0
    assert shape["median"] == [1.0, 0.93, 0.07] and shape["min"] == [1.0, 0.8, 0.066]
    text = diagnoses_markdown(out)
    assert "`viscous_damping` on 2 (50%)" in text and "Refused: 1 (e: too short)" in text
    assert "65 before, 3 after (21.7x lower)" in text and "understates its error" in text
    assert f"(the invariants): {drag} on 2, adds to the rotation on 1, not applicable on 1." in text


def test_pooled_delta_bic_sums_each_effects_single_fits_over_the_recordings():
    """Independent recordings' BICs add: an effect in every recording (its parameters each one's
    own) beats none by the sum of its single-effect delta BICs. One toss's lead (the momentum on
    c) can lose to what the rest say together; an effect without a valid fit on a recording
    (None) is not pooled."""
    done = [("a", _report(["viscous_damping"], [50] * 3, [2] * 3, [1, 0.93, 0.07],
                          singles={"viscous_damping": 300.0, "internal_momentum": 100.0, "gyro_bias": 5.0})),
            ("b", _report(["viscous_damping"], [50] * 3, [2] * 3, [1, 0.93, 0.07],
                          singles={"viscous_damping": 250.0, "internal_momentum": 150.0, "gyro_bias": None})),
            ("c", _report(["internal_momentum"], [50] * 3, [2] * 3, [1, 0.93, 0.07],
                          singles={"internal_momentum": 120.0, "viscous_damping": 80.0, "gyro_bias": -7.0}))]
    out = diagnoses_across(done, [])
    assert out["pooled_delta_bic"] == {"viscous_damping": 630.0, "internal_momentum": 370.0}
    assert list(out["pooled_delta_bic"]) == ["viscous_damping", "internal_momentum"]
    assert ("`viscous_damping` 630, `internal_momentum` 370; together they are best read as "
            "`viscous_damping`.") in diagnoses_markdown(out)
    assert diagnoses_across(done[:1], [])["pooled_delta_bic"] == {}  # one recording: its own ranking
    worse = [(n, _report([], [1] * 3, [1] * 3, [1, 0.93, 0.07], singles={"gyro_bias": -3.0})) for n in "ab"]
    assert "no effect improves the BIC" in diagnoses_markdown(diagnoses_across(worse, []))


def test_pooled_delta_bic_takes_off_what_a_coarse_gyros_rounding_alone_gives_each_effect():
    """A recording whose gyro rounds its samples as a function of the rate reports what each
    effect gains from that rounding alone (noise.rounding_floor), recounted with the rows'
    independent share: pooled, that part is taken off, so that recordings whose effects only
    trace their rounding do not add up to a claim."""
    def coarse(gain, floor, share):
        report = _report([], [1] * 3, [1] * 3, [1, 0.93, 0.07],
                         singles={"gyro_scale": gain, "gyro_bias": 4.0})
        report["noise"] = {"rounding_floor": {"gyro_scale": floor}, "independent_row_share": share}
        return report

    done = [("a", coarse(40.0, 70.0, 0.5)), ("b", coarse(25.0, 30.0, 0.8))]
    out = diagnoses_across(done, [])
    assert out["pooled_delta_bic"] == {"gyro_bias": 8.0, "gyro_scale": pytest.approx(40 - 35 + 25 - 24)}
    assert "best read as `gyro_bias`" in diagnoses_markdown(out)
    plain = [(n, _report([], [1] * 3, [1] * 3, [1, 0.93, 0.07], singles={"gyro_scale": 40.0})) for n in "ab"]
    assert diagnoses_across(plain, [])["pooled_delta_bic"] == {"gyro_scale": 80.0}  # no floors: as summed


@pytest.mark.parametrize("tilts, one", [((2.0, -3.0, 5.0, 1.0), True), ((2.0, 35.0, 50.0, 70.0), False)])
def test_momentum_axes_say_whether_one_rotor_fixed_in_the_body_would_explain_them(tilts, one):
    """internal_momentum's axes over several recordings, each tilted from z by a known angle (the
    varying form's axis, or the constant form's h, of either sign): their common axis, each one's
    angle to it, and one_axis where the median is within ONE_AXIS_DEG."""
    done, vectors = [], []
    for i, tilt in enumerate(tilts):
        a = np.radians(tilt)
        vector = np.array([np.sin(a) * np.cos(i), np.sin(a) * np.sin(i), np.cos(a)]) * (-1) ** i
        vectors.append(vector)
        params = {"axis": vector.tolist()} if i % 2 else {"h": (3e-3 * vector).tolist()}
        done.append((f"t{i}", _report(["viscous_damping", "internal_momentum"], [9] * 3, [2] * 3,
                                      [1, 0.9, 0.1], params={"internal_momentum": params})))
    done.append(("plain", _report(["viscous_damping"], [9] * 3, [2] * 3, [1, 0.9, 0.1])))
    axes = diagnoses_across(done, [])["momentum_axes"]
    common = np.array(axes["axis"])
    tilted = np.degrees(np.arccos(np.minimum(np.abs(np.array(vectors) @ common), 1.0)))  # to the common axis
    assert axes["recordings"] == 4 and axes["one_axis"] is one
    assert axes["median_angle_deg"] == pytest.approx(np.median(tilted))
    assert axes["max_angle_deg"] == pytest.approx(max(tilted))
    if one:  # the common axis is then near z, each axis within a few degrees of its tilt
        assert abs(common[2]) > np.cos(np.radians(5.0))
        assert np.allclose(tilted, np.abs(tilts), atol=4.0)
    text = diagnoses_markdown(diagnoses_across(done, []))
    assert ("as one rotor fixed in the body would." in text) is one
    assert ("not one rotor fixed in the body" in text) is (not one)
    assert diagnoses_across(done[:1] + done[-1:], [])["momentum_axes"] is None  # one: nothing to compare
    # held by a minority (2 of 6, as by 3 of 30 drag-led racquet flips of an independent simulator): said
    assert "recordings hold it" not in text  # 4 of 5 hold it
    if one:
        minority = diagnoses_markdown(diagnoses_across(done[:2] + [done[-1]] * 4, []))
        assert "as one rotor fixed in the body would; but only 2 of 6 recordings hold it" in minority

def test_identifications_across_combines_the_shape_and_the_moments_where_scaled():
    rng = np.random.default_rng(1)
    truth = np.array([0.45, 0.0, 0.0, 0.42, 0.0, 0.03])
    summaries = []
    for k in range(4):
        a = rng.normal(size=(6, 6)) * 2e-4
        cov = a @ a.T
        theta = truth + np.linalg.cholesky(cov) @ rng.standard_normal(6)
        est = InertiaEstimate(theta, cov, True)
        vals = est.principal().moments
        ratios, ratio_cov = est.principal_ratios()
        summaries.append((f"throw {k}", {
            "principal_moments": vals.tolist(), "principal_moments_cov": est.moment_covariance().tolist(),
            "principal_ratios": ratios.tolist(), "principal_ratios_cov": ratio_cov.tolist(),
            "principal_ratios_ci95": np.stack([ratios - 0.01, ratios + 0.01], 1).tolist(),
            "scale_identified": True, "rms_over_noise": 1.0}))
    out = identifications_across(summaries, [])
    assert out["identified"] == 4 and out["principal_ratios"]["p"] > 0.01  # drawn from their covs
    lo, hi = np.array(out["principal_moments"]["ci95"]).T
    assert np.all((lo <= [0.45, 0.42, 0.03]) & ([0.45, 0.42, 0.03] <= hi))
    lo, hi = np.array(out["principal_ratios"]["ci95"]).T
    assert np.all((lo <= [1, 0.42 / 0.45, 0.03 / 0.45]) & ([1, 0.42 / 0.45, 0.03 / 0.45] <= hi))
    text = identifications_markdown(out)
    assert "(95 %" in text and "kg·m²" in text and "| throw 3 |" in text
    unscaled = [(name, {**s, "scale_identified": False}) for name, s in summaries]
    assert identifications_across(unscaled, [])["principal_moments"] is None


@pytest.mark.parametrize("name, series", [
    ("Empty_LOG00179", "Empty_LOG"), ("cal_proof_body_LOG00121", "cal_proof_body_LOG"),
    ("round1/Gyroscope rotation rate 2025-01-16 17-10-11 segment 3",
     "round1/Gyroscope rotation rate 2025-01-16 17-10-11"),
    ("Gyroscope rotation rate 1 flight 2", "Gyroscope rotation rate 1"), ("REC rows 1-150", "REC"),
    ("throw 3", "throw"), ("spin", "spin"), ("007", "007")])
def test_a_recordings_series_is_its_name_without_its_number(name, series):
    assert series_name(name) == series


def test_several_series_are_summarized_each():
    """Throws of two bodies in one folder: the shape of all of them means nothing, each series'
    is its body's; one series gives no groups."""
    done = [(f"{body}_LOG{k:05d}", _report(["viscous_damping"], [9, 9, 9], [1, 1, 1], ratios))
            for body, ratios in (("plate", [1, 0.5, 0.4]), ("cube", [1, 0.95, 0.9])) for k in range(3)]
    out = diagnoses_across(done, [])
    assert [g["name"] for g in out["groups"]] == ["plate_LOG", "cube_LOG"]
    assert [g["diagnosed"] for g in out["groups"]] == [3, 3]
    assert out["groups"][0]["principal_ratios"]["estimate"] == pytest.approx([1, 0.5, 0.4])
    assert out["groups"][1]["principal_ratios"]["estimate"] == pytest.approx([1, 0.95, 0.9])
    assert out["rows"][0]["series"] == "plate_LOG" and out["principal_ratios"]["n"] == 6
    text = diagnoses_markdown(out)
    assert "fall into 2 series" in text and "## Series cube_LOG (3 recordings)" in text
    assert diagnoses_across(done[:3], [])["groups"] == []


def test_one_recordings_moments_keep_their_own_intervals():
    """One identify.json alone: the combined moments (descending) are its own, with the 95 %
    intervals identify gave them (ascending in identify.json): the covariance is turned with them."""
    a = np.random.default_rng(3).normal(size=(6, 6)) * 1e-4
    est = InertiaEstimate(np.array([0.45, 0.01, 0.0, 0.30, 0.0, 0.05]), a @ a.T, True)
    vals, half = est.principal().moments, est.principal().half
    ratios, ratio_cov = est.principal_ratios()
    summary = {"principal_moments": vals.tolist(), "principal_moments_cov": est.moment_covariance().tolist(),
               "principal_ratios": ratios.tolist(), "principal_ratios_cov": ratio_cov.tolist(),
               "principal_ratios_ci95": [[r, r] for r in ratios], "scale_identified": True,
               "rms_over_noise": 1.0}
    moments = identifications_across([("throw 1", summary)], [])["principal_moments"]
    assert moments["estimate"] == pytest.approx(vals[::-1].tolist())
    assert np.allclose(moments["ci95"], np.stack([vals - half, vals + half], 1)[::-1])


def test_two_effects_of_one_family_lead_as_one_physical_cause():
    """A thrown body's air read as linear drag on one toss and as its flight's air (aero_drag) on
    another is one cause: leading_causes counts the family, leading_effects the names."""
    done = [("a", _report(["viscous_damping"], [50, 9, 9], [2, 2, 2], [1, 0.9, 0.1])),
            ("b", _report(["aero_drag", "gyro_bias"], [80, 9, 9], [3, 2, 2], [1, 0.9, 0.1])),
            ("c", _report(["internal_momentum"], [60, 9, 9], [3, 2, 2], [1, 0.9, 0.1]))]
    out = diagnoses_across(done, [])
    assert out["leading_effects"] == {"viscous_damping": 1, "aero_drag": 1, "internal_momentum": 1}
    assert out["leading_causes"] == {"drag": {"count": 2, "effects": {"viscous_damping": 1, "aero_drag": 1}},
                                     "internal momentum": {"count": 1, "effects": {"internal_momentum": 1}}}
    assert "drag on 2 (67%: `viscous_damping` 1, `aero_drag` 1)" in diagnoses_markdown(out)
