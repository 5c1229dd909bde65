"""diagnose on racquet tosses of an independent simulator (racquet_strip_sim.py beside the tests:
its own integrator, element-theory air drag of no form in the catalogue)."""

from pathlib import Path

import numpy as np
import pytest
from racquet_strip_sim import inertia_tensor, simulate_toss, write_toss

from inertia_gym.discrepancy.report import diagnose
from inertia_gym.recordings import read_recordings

DRAG_FAMILY = ("viscous_damping", "aero_drag")


def audited(path: Path, truth: dict) -> dict:
    """diagnose's reading of the toss at path: its explanation, whether the fit is valid, the
    worst-axis rms over the noise before and after, the error of its principal ratios against
    the simulator's truth, whether the ratios' intervals hold the fit's own ratios."""
    report = diagnose(read_recordings(path)[0]).report
    before, after = report["fit_before"], report["fit_after"]
    ratios, ci = np.array(after["principal_ratios"]), after["principal_ratios_ci95"]
    inside = ci is not None and bool(np.all((np.array(ci)[:, 0] <= ratios) & (ratios <= np.array(ci)[:, 1])))
    return {"explanation": [e["name"] for e in report["explanation"]], "valid": bool(after["valid"]),
            "before": max(before["rms_over_noise"]), "after": max(after["rms_over_noise"]),
            "ratio_error": float(np.abs(ratios[1:] - np.array(truth["ratios"])[1:]).max()),
            "holds_own": inside}


def test_the_simulated_racquet_is_the_measured_one_and_keeps_its_momentum_without_air():
    """Principal moments within the pendulum-measured racquet's error bars (20.7 +- 3.8,
    18.8 +- 5.7, 1.39 +- 0.08 g·m²); with no air |J w| stays to the integrator's tolerance, with
    it a 20-rad/s flip loses a tenth or more."""
    moments = np.sort(np.linalg.eigvalsh(inertia_tensor()[0]))[::-1] * 1e3
    assert np.all(np.abs(moments - [20.7, 18.8, 1.39]) <= [3.8, 5.7, 0.08])
    assert simulate_toss(4000, "flip", with_air=False)[1]["momentum_lost"] == pytest.approx(0.0, abs=1e-8)
    assert simulate_toss(1000, "flip")[1]["momentum_lost"] > 0.1


@pytest.mark.parametrize("seed, kind, with_air", [(1000, "flip", True),
                                                  pytest.param(1004, "flip", True, marks=pytest.mark.science),
                                                  (4000, "flip", False)])
def test_diagnose_reads_an_independent_racquets_air_as_drag_and_a_clean_toss_as_nothing(tmp_path, seed, kind,
                                                                                        with_air):
    """Two flips with the air (20.5 rad/s, flipping 4 times; 9.1 rad/s, once) are led by the drag
    family, their worst-axis rms falling 3x or more, and a flip without air names nothing and fits
    to the noise; every
    ratio interval holds the fit's own ratios."""
    recording, truth = simulate_toss(seed, kind, with_air)
    row = audited(write_toss(tmp_path, f"{kind}_{seed}", recording), truth)
    assert row["valid"] and row["holds_own"]
    if with_air:
        assert row["explanation"][0] in DRAG_FAMILY, row
        assert row["before"] / row["after"] >= 3.0
    else:
        assert row["explanation"] == [] and row["after"] < 1.2
        assert row["ratio_error"] < 0.01
