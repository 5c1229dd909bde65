"""report.invariants: the drifts of |H| and of the rotational energy of a torque-free body, and
what their ratio says of the missing torque (the references written from their definitions)."""

import numpy as np
import pytest

from inertia_gym.discrepancy.effects import Effect
from inertia_gym.discrepancy.report import DRAG_RATIO_TOLERANCE, _invariants_words, _read_with_both, diagnose
from inertia_gym.discrepancy.synthetic import simulate_truth
from inertia_gym.recordings import Recording

#: kg·m², a racquet that can exist (the speed bench's); flipping about its middle axis
BODY = np.diag([20.7e-3, 19.5e-3, 1.39e-3])
FLIP = np.array([0.3, 15.0, 0.4])


def _read(effects=(), omega0=FLIP) -> dict:
    """The invariants diagnose reports of a 1-s toss simulated at 1 kHz and read at 100 Hz with
    5e-3 rad/s noise (read with the inertia of its explanation's fit, or the rigid fit's)."""
    steps = 1000
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.asarray(omega0, float), BODY,
                          np.zeros((steps, 3)), 1e-3, effects)
    idx = np.arange(0, steps + 1, 10)
    noisy = w[idx] + np.random.default_rng(7).normal(0, 0.005, (idx.size, 3))
    report = diagnose(Recording(idx * 1e-3, noisy, None, None, {"gyro_sigma": 0.005}, "toss")).report
    return report["invariants"]


def test_the_references_are_the_ratios_their_torques_give_by_definition():
    """dE/dt = w.tau and d|H|/dt = H.tau / |H|: over the record, tau = -k H changes E and |H| in
    the ratio mean(w.H) / mean(E) (2 without internal momentum) and tau = -c w in the ratio
    (mean |w|^2 / mean E) / (mean (H.w / |H|) / mean |H|), written here from the simulated
    truth's rates and inertia (the report reads with the fitted inertia)."""
    steps = 1000
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), FLIP, BODY, np.zeros((steps, 3)), 1e-3)
    w = w[::10]
    big_h = w @ BODY.T
    energy = 0.5 * np.sum(w * big_h, 1)
    norm_h = np.linalg.norm(big_h, axis=1)
    along_w = (np.mean(np.sum(w * w, 1)) / np.mean(energy)) / (
        np.mean(np.sum(big_h * w, 1) / norm_h) / np.mean(norm_h))
    inv = _read()
    assert inv["against_momentum_ratio"] == pytest.approx(2.0, rel=1e-3)
    assert inv["against_rates_ratio"] == pytest.approx(along_w, rel=0.02)
    assert along_w > 2.1  # a flip is no principal-axis spin: the two references part


def test_a_torque_free_toss_reads_no_drift():
    inv = _read()
    assert inv["reading"] == "none" and inv["energy_per_momentum"] is None
    assert "no torque acts" in _invariants_words(inv)


def test_a_drag_proportional_to_the_inertia_reads_against_the_angular_momentum():
    """tau = -k J w = -k H: every motion slowed alike, |H| as exp(-k t) and E as exp(-2 k t)."""
    inv = _read(Effect("viscous_damping", {"c": 0.15 * BODY}))
    assert inv["reading"] == "against the angular momentum"
    assert inv["energy_per_momentum"] == pytest.approx(2.0, rel=0.05)
    assert inv["momentum"]["relative_drift"] == pytest.approx(np.expm1(-0.15), rel=0.1)
    words = _invariants_words(inv)
    assert "reads as the one against the angular momentum" in words


def test_an_isotropic_drag_on_a_flip_reads_against_the_rates():
    """tau = -c w drains the energy faster, relative to |H|, than -k H does wherever w is not
    along a principal axis: the ratio lies nearer the rates' reference than 2."""
    inv = _read(Effect("viscous_damping", {"c": 1e-3 * np.eye(3)}))
    assert inv["reading"] == "against the rates"
    ratio, along_w = inv["energy_per_momentum"], inv["against_rates_ratio"]
    assert abs(np.log(ratio / along_w)) < abs(np.log(ratio / 2.0))
    assert ratio < DRAG_RATIO_TOLERANCE * along_w


def test_internal_dissipation_keeps_the_momentum_and_reads_internal():
    inv = _read(Effect("internal_dissipation", {"d": 0.02 * 20.7e-3}))
    assert inv["reading"] == "internal" and "inside the body" in _invariants_words(inv)


def test_a_torque_along_the_spin_adds_to_the_rotation():
    """A body torque along a steady spin about the largest moment speeds it up: E and |H| grow."""
    spin = np.array([15.0, 0.2, 0.3])
    inv = _read(Effect("constant_body_torque", {"torque": np.array([0.02, 0.0, 0.0])}), omega0=spin)
    assert inv["momentum"]["relative_drift"] > 0 and inv["energy"]["relative_drift"] > 0
    assert inv["reading"] == "adds to the rotation" and "no drag does that" in _invariants_words(inv)


def test_a_drag_with_dissipation_inside_drains_the_energy_beyond_a_drag():
    """Internal dissipation takes energy and keeps |H|: beside a drag it lifts the ratio past
    both references (on the real racquet, the spin about its largest moment reads so)."""
    inv = _read((Effect("viscous_damping", {"c": 0.05 * BODY}),
                 Effect("internal_dissipation", {"d": 0.15 * 20.7e-3})))
    assert inv["reading"] == "drains the energy beyond a drag"
    assert inv["energy_per_momentum"] > DRAG_RATIO_TOLERANCE * max(inv["against_momentum_ratio"],
                                                                    inv["against_rates_ratio"])


def test_where_the_two_inertias_read_differently_the_reading_is_uncertain_and_says_both():
    """An explanation that leaves more than noise may have moved the inertia: its reading stands
    only where the rigid fit's inertia gives the same one."""
    explained = _read(Effect("viscous_damping", {"c": 0.15 * BODY}))
    rigid = {**explained, "reading": "adds to the rotation"}
    assert _read_with_both(explained, dict(explained)) is explained
    both = _read_with_both(explained, rigid)
    assert both["reading"] == "uncertain"
    assert both["readings"] == {"rigid fit": "adds to the rotation",
                                "explanation": "against the angular momentum"}
    words = _invariants_words(both)
    assert "'adds to the rotation'" in words and "'against the angular momentum'" in words


def test_an_unlogged_rotor_is_never_read_as_a_drag():
    """A rotor's momentum the recording does not log, at constant speed: the total momentum and
    the body's energy hold, but |J w| of the body alone does not; the explanation holds a fitted
    momentum, whose fit's inertia alone is not trusted, and nothing reads as a drag."""
    h = np.array([0.0, 0.0, 0.3]) * BODY[2, 2] * 15.0
    inv = _read(Effect("internal_momentum", {"h": h}))
    assert inv["reading"] not in ("against the angular momentum", "against the rates",
                                  "drains the energy beyond a drag", "drains |H| beyond a drag")
