"""sensors.estimate_white_noise: the gyro's white-noise level read from the data; and the
report's flag where the fit says that level reads high."""

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from inertia_gym.discrepancy.report import NOISE_READ_HIGH, diagnose, markdown
from inertia_gym.sensors import NOISE_ORDERS, estimate_white_noise, stated_noise_note

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from bench_diagnose import toss as bench_toss  # noqa: E402


@pytest.mark.parametrize("k", NOISE_ORDERS)
def test_each_orders_level_is_the_noises_by_its_definition(k):
    """The k-th difference of white noise of level s has variance binom(2k, k) s^2, and a
    normal's median absolute deviation is 0.6745 of its standard deviation."""
    sigma = 0.02
    w = np.random.default_rng(k).normal(0.0, sigma, (40000, 1))
    d = np.diff(w, n=k, axis=0)
    level = np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(math.comb(2 * k, k))
    assert level == pytest.approx(sigma, rel=0.03)


def test_on_white_noise_alone_it_is_the_third_differences_level():
    """Over 200 seeds of 100 rows of white noise, the estimate is the third differences' level
    on nearly every axis (the slow-motion case is left as it was), and unbiased to a few %."""
    third, ratios = [], []
    for seed in range(200):
        w = np.random.default_rng(seed).normal(0.0, 1e-3, (100, 3))
        d3 = np.diff(w, n=3, axis=0)
        level3 = np.median(np.abs(d3 - np.median(d3, axis=0)), axis=0) / 0.6745 / math.sqrt(20)
        estimate = estimate_white_noise(w)
        third.extend(estimate == level3)
        ratios.extend(estimate / 1e-3)
    assert np.mean(third) > 0.95
    assert 0.95 < np.mean(ratios) < 1.05


def test_fast_motion_does_not_pass_for_noise():
    """A body turning fast for the sampling (a 3-Hz nutation of 10 rad/s at 100 Hz, as a
    flipping racquet): the third differences read several times the noise, the estimate reads
    the noise, within 25 % on the median over seeds, on every axis."""
    t = np.arange(100) * 0.01
    motion = np.c_[10 * np.sin(2 * np.pi * 3 * t), 6 * np.cos(2 * np.pi * 3 * t + 0.4), 2 + t]
    sigma = 2e-3
    estimates, thirds = [], []
    for seed in range(40):
        w = motion + np.random.default_rng(seed).normal(0.0, sigma, motion.shape)
        d3 = np.diff(w, n=3, axis=0)
        thirds.append(np.median(np.abs(d3 - np.median(d3, axis=0)), axis=0) / 0.6745 / math.sqrt(20))
        estimates.append(estimate_white_noise(w))
    assert np.all(np.median(thirds, axis=0)[:2] > 4 * sigma)  # what the third differences alone read
    assert np.all(np.abs(np.median(estimates, axis=0) / sigma - 1) < 0.25), np.median(estimates, axis=0)


def test_a_recording_too_short_for_higher_orders_uses_the_third():
    w = np.random.default_rng(0).normal(size=(6, 3))
    d3 = np.diff(w, n=3, axis=0)
    level3 = np.median(np.abs(d3 - np.median(d3, axis=0)), axis=0) / 0.6745 / math.sqrt(20)
    assert np.array_equal(estimate_white_noise(w), level3)


@pytest.mark.parametrize("every, sidecar, expected",
                         [(40, False, True), (10, False, False), (40, True, False)])
def test_the_report_says_where_the_noise_level_read_from_the_data_reads_high(every, sidecar, expected):
    """The speed bench's 1-s toss at 15 rad/s (scripts/bench_diagnose.py): at 25 Hz it moves too
    much between samples for the differences to read its noise (they read it 2.3-3.3x high), and
    the fit leaves well under that level: the report says so. At 100 Hz the level is right, and a
    sidecar's level is never flagged."""
    report, _ = diagnose(bench_toss(every, sidecar))
    assert report["fit_after"]["valid"]
    assert report["noise"]["read_high"] is expected
    assert ("reads high" in markdown(report, [])) is expected
    if expected:
        assert max(report["fit_after"]["rms_over_noise"]) < NOISE_READ_HIGH
        assert report["noise"]["sigma"][0] > 1.2 * 5e-3


@pytest.mark.parametrize("factor, expected", [(1.0, None), (1 / 3, "leave it out"), (3.0, "coloured noise")])
def test_a_sidecar_level_the_samples_disagree_with_is_said(factor, expected):
    """The bench's 1-s toss (noise 5e-3 rad/s) with its sidecar's gyro_sigma as given, 3x too
    small or 3x too large: the samples' own level (estimate_white_noise) disagrees with the last
    two, and stated_noise_note says which way; a 2x margin keeps the true level silent."""
    rec = bench_toss()
    stated = np.full(3, 5e-3 * factor)
    residual_rms = np.full(3, 5e-3)  # a fit to the noise
    note = stated_noise_note(rec.w, stated, residual_rms)
    if expected is None:
        assert note is None
    else:
        ratios = [float(r) for r in note.split("rad/s, ")[1].split(" times")[0].split(", ")]
        assert expected in note and np.allclose(ratios, 1 / factor, rtol=0.25)
        # a fit that leaves the stated level (the differences read high from fast motion, say)
        assert stated_noise_note(rec.w, stated, stated) is None


def test_diagnose_and_identify_say_a_sidecar_level_3x_too_small():
    """The level is in the sidecar and 3x too small: diagnose's report (noise.sidecar_disagrees)
    and summary, and identify's notes, say so; at the true level both stay silent."""
    from inertia_gym import identify

    rec = bench_toss()
    low = dataclasses.replace(rec, meta={**rec.meta, "gyro_sigma": 5e-3 / 3})
    report, _ = diagnose(low)
    assert "leave it out" in report["noise"]["sidecar_disagrees"]
    assert "the sidecar's noise level disagrees with the data's" in markdown(report, [])
    assert any("high-frequency scatter" in n for n in identify(low).notes)
    assert diagnose(rec)[0]["noise"]["sidecar_disagrees"] is None
    assert not any("high-frequency scatter" in n for n in identify(rec).notes)
