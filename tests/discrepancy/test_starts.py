"""The starts diagnose's nonlinear fits begin from (starts.py): linear estimates that follow the
physics the record holds."""

import numpy as np
import pytest

from inertia_gym.discrepancy import fit as F
from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.starts import MOMENTUM_AXES, hemisphere
from inertia_gym.discrepancy.synthetic import simulate_truth
from inertia_gym.recordings import Recording

#: kg·m², a thrown device close to axisymmetric (two moments within 0.2 %); its rotor's axis (body
#: frame) and momenta kg·m²/s: spinning at the throw, spun up and braked back within the flight;
#: gyro noise rad/s
DEVICE = np.array([[5.2e-4, -1.7e-6, 1.5e-6], [-1.7e-6, 2.2e-4, 6.4e-6], [1.5e-6, 6.4e-6, 5.2e-4]])
ROTOR_AXIS = np.array([0.0, 0.0, -1.0])
H_START, H_PEAK, SIGMA = 2.8e-4, 2.1e-3, 1e-2


def spun_up_and_braked(seed: int):
    """0.5 s at 4 kHz, thrown at 17 rad/s: the rotor holds H_START at the throw and rises to
    H_PEAK and back (a raised cosine) in mid-flight; h not logged. Returns the record and the
    true h (n, 3)."""
    t = np.arange(2001) * 2.5e-4
    pulse = np.where((t > 0.1) & (t < 0.4), 0.5 * (1 - np.cos(2 * np.pi * (t - 0.1) / 0.3)), 0.0)
    h = (H_START + (H_PEAK - H_START) * pulse)[:, None] * ROTOR_AXIS
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.array([15.2, -5.6, -6.1]), DEVICE,
                          np.zeros((2000, 3)), 2.5e-4, (), momentum=h)
    noisy = w + np.random.default_rng(seed).normal(0, SIGMA, w.shape)
    return Recording(t, noisy, None, None, {"gyro_sigma": SIGMA}, f"rotor-{seed}"), h


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_linear_momentum_estimate_draws_the_change_the_record_shows(seed):
    """While the rates stay near their mean, a constant momentum and an inertia error act alike:
    estimated together they cancel and distort the change between them (profiles anticorrelated
    with the truth's). Left to the inertia, the momentum at the start is zero and its change along
    each axis kept follows the rotor's."""
    rec, h = spun_up_and_braked(seed)
    d = F.prepare(rec)
    nominal = F.fit_nominal(d)
    layout = F.Layout.of(("internal_momentum",), ("varying",), d, nominal.layout.omega_max)
    probe = F.Probe(layout, d, nominal)
    knot_t = probe.momentum_knots(REGISTRY["internal_momentum"].knots(d))
    for with_inertia in (True, False):
        estimates = probe.momentum_estimate(knot_t, hemisphere(MOMENTUM_AXES), with_inertia, keep=3,
                                             from_start=False)
        assert len(estimates) == 3
        for tk, hk, _ in estimates:
            assert np.all(hk[0] == 0.0)
            axis = np.linalg.svd(hk, full_matrices=False)[2][0]
            true_change = np.interp(tk, rec.t, (h - h[0]) @ axis)
            assert np.corrcoef(hk @ axis, true_change)[0, 1] > 0.3


def test_the_varying_momentum_is_started_with_its_start_estimated_and_left_to_the_inertia():
    """Which of the two the record separates depends on how widely its rates sweep: both kinds
    of start are among those the fit tries, and no momentum at all."""
    rec, _ = spun_up_and_braked(0)
    d = F.prepare(rec)
    nominal = F.fit_nominal(d)
    model = REGISTRY["internal_momentum"]
    layout = F.Layout.of(("internal_momentum",), ("varying",), d, nominal.layout.omega_max)
    probe = F.Probe(layout, d, nominal)
    starts = [model.unpack(x[layout.slices()[0]]) for x in model.starts("varying", d, probe)]
    estimated = [p for p in starts if np.any(p["profile"])]
    left_to_inertia = [np.all(p["h"] == 0.0) for p in estimated]
    assert any(left_to_inertia) and not all(left_to_inertia)
    assert any(not np.any(p["profile"]) and np.all(p["h"] == 0.0) for p in starts)


def test_the_modal_screen_starts_a_mode_at_each_damping_ratio_it_screens():
    """mode_starts screens every damping ratio it is given: the first's `keep` best frequencies
    and each other ratio's best are started (an overdamped response is a lag, not a ringing, and
    a start at a light ratio does not reach it), each inside the mode's bounds, an overdamped one
    with both its poles in the screened band."""
    from inertia_gym.discrepancy.effects import flex_floor_hz
    from inertia_gym.discrepancy.effects.flexible_mode import FLEX_BAND, MODE_ZETAS, zeta_max
    from inertia_gym.discrepancy.synthetic import simulate_recording
    from inertia_gym.scenario import Scenario

    rec, _ = simulate_recording(Scenario(tau_max=50.0), 20.0, "flexible_mode",
                                overrides={"zeta": 3.0, "omega_n": 2 * np.pi}, seed=2)
    d = F.prepare(rec)
    layout = F.Layout.of(("flexible_mode",), ("",), d)
    probe = F.Probe(layout, d, F.fit_nominal(d))
    zetas = tuple(min(z, zeta_max(d)) for z in MODE_ZETAS)
    starts = probe.mode_starts(keep=3, zetas=zetas)
    ratios = [float(p[1]) for p in starts]
    assert sorted(set(ratios)) == sorted(zetas)
    assert ratios.count(zetas[0]) == 3 and all(ratios.count(z) == 1 for z in zetas[1:])
    lb, ub = REGISTRY["flexible_mode"].bounds("", d)
    assert all(np.all(p[:2] >= lb[:2]) and np.all(p[:2] <= ub[:2]) for p in starts)
    assert [float(p[1]) for p in REGISTRY["flexible_mode"].starts("", d, probe)] == ratios
    # an overdamped start has both poles omega_n (zeta -+ sqrt(zeta^2 - 1)) in the screened band
    # (up to the finer screen's step around the best)
    lo, hi = 2 * np.pi * flex_floor_hz(d), 2 * np.pi * FLEX_BAND[1] / d.dt
    for omega, zeta in [(float(p[0]), float(p[1])) for p in starts if p[1] > 1.0]:
        slow, fast = omega * (zeta - np.sqrt(zeta ** 2 - 1.0)), omega * (zeta + np.sqrt(zeta ** 2 - 1.0))
        assert lo / F.MODE_GRID <= slow and fast <= hi * F.MODE_GRID
