"""A cubesat whose nominal inertia puts the middle moment 10 % low: `inertia_offset` leads the
explanation with the moment's change. Its single fit starts from the equation-error inertia as
well as from the nominal: from the nominal alone it stalls on seed 3 at a delta BIC of 1087 (the
same offset fitted after a drag: 65624; from the equation-error inertia too: 93540), and an
internal momentum leads the ranking, a drag the explanation, with the percent changes (-12.0,
-7.3, +11.5) for the truth's (0, +11.1, 0). The recording rebuilds a case of an independent
simulator (3 of 54 of its runs read so), its integrator aside, to those figures."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.synthetic import simulate_recording, simulate_truth
from inertia_gym.recordings import Recording
from inertia_gym.scenario import Scenario

#: kg·m², rad/s, N·m, s, Hz: the independent simulator's cubesat (principal moments turned by xyz
#: Euler angles in degrees), its gyro noise, burst torque, record length and rate
MOMENTS, TURN_DEG = np.array([0.035, 0.05, 0.065]), (5.0, -7.0, 4.0)
SIGMA, BURST, DURATION, RATE = 5e-4, 5e-4, 300.0, 10.0


def _inertia(moments) -> np.ndarray:
    axes = Rotation.from_euler("xyz", TURN_DEG, degrees=True).as_matrix()
    return axes @ np.diag(moments) @ axes.T


def bursts(rng, t) -> np.ndarray:
    """(n, 3) N·m: 5-s bursts about x, y, z in turn, every 21-39 s, signs alternating by triple."""
    tau = np.zeros((t.size, 3))
    k, start = 0, 15.0
    while start + 5.0 < DURATION:
        sign = 1.0 if (k // 3) % 2 == 0 else -1.0
        tau[(t >= start) & (t < start + 5.0), k % 3] = BURST * sign * rng.uniform(0.6, 1.0)
        start += 30.0 * rng.uniform(0.7, 1.3)
        k += 1
    return tau


def cubesat(seed: int) -> Recording:
    """The tumbling cubesat under bursts, its nominal's middle moment 10 % low (seeded as that case)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(DURATION * RATE) + 1) / RATE
    u = rng.normal(size=3)
    w0 = u / np.linalg.norm(u) * rng.uniform(0.1, 0.4)
    tau = bursts(rng, t)
    _, w = simulate_truth(np.array([1.0, 0, 0, 0]), w0, _inertia(MOMENTS), tau[:-1], 1.0 / RATE)
    noisy = w + rng.normal(0, SIGMA, w.shape)
    nominal = _inertia(MOMENTS * [1.0, 0.9, 1.0])
    return Recording(t, noisy, None, tau, {"gyro_sigma": SIGMA, "inertia_nominal": nominal.tolist()},
                     f"cubesat-{seed}")


def test_a_wrong_middle_moment_is_the_inertia_offset():
    report = diagnose(cubesat(3)).report
    assert report["effects"][0]["name"] == "inertia_offset"
    assert [e["name"] for e in report["explanation"]] == ["inertia_offset"]
    change = report["inertia_vs_nominal"]["percent_change"]
    assert report["scale_identified"]
    assert np.allclose(change, [0.0, 100 / 0.9 - 100, 0.0], atol=1.0)
    assert max(report["fit_after"]["rms_over_noise"]) < 1.2


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.science)])
def test_a_torque_free_offset_s_intervals_hold_its_estimate_and_the_truth(seed):
    """Torque-free, the scale unseen: the offset's inertia is reported at the nominal's trace, and
    its intervals are too. Taken at the fit's own gauge (its first log-Cholesky entry held),
    Ixx's would have zero width and every interval could miss the estimate (0 of 9 entries inside
    on a nominal whose axes are turned 10 deg, 7 of 7 wrong nominals with Ixx outside).
    Measured: the truth at the nominal's trace within 1.15 and 0.81 half-widths."""
    rec, side = simulate_recording(Scenario(), 60.0, "inertia_offset", seed=seed, torque=False, sample_dt=0.1)
    meta = {k: v for k, v in rec.meta.items() if k not in ("effect", "effects")}
    report = diagnose(dataclasses.replace(rec, meta=meta)).report
    assert report["scale_identified"] is False
    entry = report["explanation"][0]
    assert entry["name"] == "inertia_offset"
    fitted = np.array(entry["params"]["inertia"])
    lo, hi = (np.array(entry["ci95"]["inertia"][k]) for k in ("lo", "hi"))
    assert np.all(lo < fitted) and np.all(fitted < hi)
    truth = np.array(side["effect"]["params"]["inertia"])
    truth *= np.trace(rec.meta["inertia_nominal"]) / np.trace(truth)
    assert np.max(np.abs(fitted - truth) / ((hi - lo) / 2)) < 1.5
