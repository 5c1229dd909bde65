"""A wheel that spins up in a few seconds of a long record, its momentum not logged: the varying
internal momentum's knots follow the spin-up (fit.Probe.momentum_knots) and it explains the
record alone. Spaced evenly, its twenty knots draw a spin-up of a few seconds as a slow ramp,
and a drifting gyro bias and a flexible mode take up the rest (an independent simulator's upper
stage, cubesat and thrown device: 7 of 10 runs)."""

import numpy as np
import pytest

from inertia_gym.discrepancy.fit import Layout, Probe, fit_nominal, prepare
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.synthetic import burst_schedule, simulate_truth
from inertia_gym.recordings import Recording

#: kg·m², a 6U cubesat; its rates rad/s; gyro noise rad/s; torque bursts N·m
CUBESAT = np.array([[0.10, 0.002, -0.001], [0.002, 0.12, 0.0015], [-0.001, 0.0015, 0.05]])
OMEGA0, SIGMA, TAU = np.array([0.09, 0.3, 0.06]), 1e-3, 1e-3
#: s: the record, its integration step and sampling interval, the spin-up's length
DURATION, DT, SAMPLE_DT, SPIN_UP = 300.0, 0.05, 0.2, 3.0


def spinning_up(seed: int, share: float = 0.05, spin_up: float = SPIN_UP,
                sample_dt: float = SAMPLE_DT) -> tuple[Recording, dict]:
    """DURATION s of the cubesat under torque bursts, read every sample_dt s, a wheel along a
    seeded axis spinning up (smoothstep over spin_up s, at a seeded time) to `share` of |J w0|;
    h not logged."""
    rng = np.random.default_rng(seed)
    n = int(DURATION / DT)
    t = np.arange(n + 1) * DT
    every = int(round(sample_dt / DT))
    tau = burst_schedule(n, DT, TAU, rng, every)  # held from one sample to the next, as logged
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    t_on = rng.uniform(0.2, 0.7) * DURATION
    s = np.clip((t - t_on) / spin_up, 0.0, 1.0)
    h = share * np.linalg.norm(CUBESAT @ OMEGA0) * (s * s * (3 - 2 * s))[:, None] * axis
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), OMEGA0, CUBESAT, tau, DT, (), momentum=h)
    idx = np.arange(0, n + 1, every)
    noisy = w[idx] + rng.normal(0, SIGMA, (idx.size, 3))
    rec = Recording(t[idx], noisy, None, np.vstack([tau, tau[-1:]])[idx],
                    {"gyro_sigma": SIGMA, "inertia_nominal": CUBESAT.tolist()}, f"spin-up-{seed}")
    return rec, {"axis": axis, "t_on": t_on}


@pytest.mark.parametrize("seed", [0, 1])
def test_the_knots_gather_at_the_spin_up(seed):
    rec, truth = spinning_up(seed)
    d = prepare(rec)
    nominal = fit_nominal(d)
    probe = Probe(Layout.of(("internal_momentum",), ("varying",), d), d, nominal)
    knots = probe.momentum_knots(20)
    assert knots[0] == d.t[0] and knots[-1] == d.t[-1] and np.all(np.diff(knots) >= 5 * d.dt * d.block - 1e-9)
    middle = truth["t_on"] + SPIN_UP / 2
    near = np.sum(np.abs(knots - middle) < 10.0)
    assert near >= 6  # evenly spaced (31.6 s apart), at most one falls in these 20 s of 300


def test_without_a_change_the_knots_stay_nearly_even():
    rec, _ = spinning_up(0, share=0.0)
    d = prepare(rec)
    probe = Probe(Layout.of(("internal_momentum",), ("varying",), d), d, fit_nominal(d))
    knots = probe.momentum_knots(20)
    even = np.linspace(d.t[0], d.t[-1], 20)
    assert np.max(np.abs(knots - even)) < 0.25 * (even[1] - even[0])


@pytest.mark.science  # 16-18 s a seed; make test keeps the knots' placement (above) and a
# spin-up's diagnosis (tests/discrepancy/test_spin_up.py)
@pytest.mark.parametrize("seed", [0, 1])
def test_a_short_spin_up_in_a_long_record_is_the_varying_momentum_alone(seed):
    rec, truth = spinning_up(seed)
    report = diagnose(rec).report
    assert [(e["name"], e["form"]) for e in report["explanation"]] == [("internal_momentum", "varying")]
    axis = np.asarray(report["explanation"][0]["params"]["axis"])
    assert np.degrees(np.arccos(min(1.0, abs(axis @ truth["axis"])))) < 5.0
    assert max(report["fit_before"]["rms_over_noise"]) > 10
    assert max(report["fit_after"]["rms_over_noise"]) < 1.2


@pytest.mark.slow
@pytest.mark.science  # 16 s; a spin-up in a long record stays in make test (the short one above)
@pytest.mark.parametrize("seed", [5, 7])
def test_a_large_wheel_s_spin_up_is_drawn_through_its_corners(seed):
    """A wheel of 15 % of |J w0| spinning up in 5 s, read at 10 Hz: the spin-up's corners need
    knots closer than half of them give. With half following the change (3.6 s apart there) a
    flexible mode takes up what the spline cannot draw (seeds 5 and 7, worst axis 1.11x and
    1.09x the noise; 4 of 8 such cases have a second effect); with three quarters (2.6 s apart)
    the momentum explains them alone at 1.04x and 1.0x (6 of 8 alone, all within 1.2x)."""
    rec, truth = spinning_up(seed, share=0.15, spin_up=5.0, sample_dt=0.1)
    report = diagnose(rec).report
    assert [(e["name"], e["form"]) for e in report["explanation"]] == [("internal_momentum", "varying")]
    axis = np.asarray(report["explanation"][0]["params"]["axis"])
    assert np.degrees(np.arccos(min(1.0, abs(axis @ truth["axis"])))) < 5.0
    assert max(report["fit_after"]["rms_over_noise"]) < 1.1
