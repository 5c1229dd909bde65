"""scripts/racquet_recut.py: a cut whose diagnosis names no effect is counted, not a crash."""

import sys
from pathlib import Path

import numpy as np

from inertia_gym.discrepancy.synthetic import simulate_truth

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from bench_diagnose import RACQUET  # noqa: E402
from racquet_recut import recut, summarize  # noqa: E402


def test_a_cut_with_nothing_to_explain_leads_with_none_and_is_summarized():
    """A torque-free 1-s toss (the bench's racquet flipping at 15 rad/s, gyro noise 5e-3 rad/s)
    has nothing for diagnose to name: its cut leads with "none", and the counts take it beside
    a cut that names an effect (the summary sorted None against names and raised a TypeError)."""
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), np.array([0.3, 15.0, 0.4]), RACQUET,
                          np.zeros((1000, 3)), 1e-3)
    t = np.arange(0, 1001, 10) * 1e-3
    noisy = w[::10] + np.random.default_rng(3).normal(0, 0.005, (t.size, 3))
    clean = recut(t, noisy, (0.0, 1.0), "round9 segment 0 +0.00 +0.00")
    assert clean["lead"] == "none" and clean["after"] == clean["before"] < 2.0
    named = dict(clean, cut="round9 segment 1 +0.00 +0.00", lead="viscous_damping", after=1.0)
    out = summarize([clean, named], [])
    assert out["leading"] == {"round9 none": 1, "round9 viscous_damping": 1}
    assert out["cuts"] == 2 and out["diagnose_valid"] == 2 and out["other_failures"] == 0
