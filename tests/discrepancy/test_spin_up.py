"""A thrown device whose rotor spins up exponentially, its momentum not logged: the varying
internal momentum explains it alone. Its profile is a spline: straight lines between the knots
leave an error periodic at the knots' spacing, which a flexible mode at that frequency takes up
(an independent simulator's throws, 3 of 3 seeds)."""

import numpy as np
import pytest

from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.synthetic import simulate_truth
from inertia_gym.recordings import Recording

#: kg·m², a hand-sized device with products of inertia; its rotor's axis (body frame), final
#: momentum kg·m²/s and spin-up time constant s; gyro noise rad/s
DEVICE = np.array([[3.0e-4, 1.5e-5, -1.0e-5], [1.5e-5, 4.0e-4, 2.0e-5], [-1.0e-5, 2.0e-5, 5.0e-4]])
ROTOR_AXIS = np.array([0.2, -0.3, 0.93]) / np.linalg.norm([0.2, -0.3, 0.93])
ROTOR_H, SPIN_UP_S, SIGMA = 2e-3, 0.4, 5e-3


def spinning_up(seed: int) -> Recording:
    """2 s simulated at 1 kHz, read at 200 Hz with white gyro noise (seeded); h not logged."""
    t = np.arange(2001) * 1e-3
    h = ROTOR_H * (1.0 - np.exp(-t / SPIN_UP_S))[:, None] * ROTOR_AXIS
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.array([3.0, -9.0, 7.0]), DEVICE,
                          np.zeros((2000, 3)), 1e-3, (), momentum=h)
    idx = np.arange(0, 2001, 5)
    noisy = w[idx] + np.random.default_rng(seed).normal(0, SIGMA, (idx.size, 3))
    return Recording(t[idx], noisy, None, None, {"gyro_sigma": SIGMA}, f"spin-up-{seed}")


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.science)])
def test_an_exponential_spin_up_is_the_varying_momentum_alone(seed):
    report = diagnose(spinning_up(seed)).report
    assert [(e["name"], e["form"]) for e in report["explanation"]] == [("internal_momentum", "varying")]
    axis = np.asarray(report["explanation"][0]["params"]["axis"])
    assert np.degrees(np.arccos(min(1.0, abs(axis @ ROTOR_AXIS)))) < 5.0
    assert max(report["fit_before"]["rms_over_noise"]) > 20
    assert max(report["fit_after"]["rms_over_noise"]) < 1.2
