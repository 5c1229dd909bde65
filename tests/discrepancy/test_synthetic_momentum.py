"""A known internal momentum (rotor): the truth conserves total momentum, simulate writes h."""

from __future__ import annotations

import json

import numpy as np
import pytest

from inertia_gym.cli import main
from inertia_gym.discrepancy.synthetic import (
    rotor_momentum,
    rotor_profile,
    simulate_recording,
    simulate_truth,
)
from inertia_gym.dynamics import quat_to_rotation
from inertia_gym.errors import ConfigError
from inertia_gym.recordings import MOMENTUM, read_recordings
from inertia_gym.scenario import Scenario


def _inertial_momentum(q, w, inertia, h):
    """(n+1, 3) kg·m²/s: R(q) (J w + h), the total angular momentum in the inertial frame."""
    return np.array([quat_to_rotation(q[i]) @ (inertia @ w[i] + h[i]) for i in range(q.shape[0])])


def test_rotor_profile_derivative_and_ends():
    t = np.linspace(0.0, 20.0, 2001)
    prof, prof_dot = rotor_profile(t, 20.0)
    assert prof[0] == 0.0 and abs(prof[-1]) < 1e-15 and prof.max() == pytest.approx(1.0)
    np.testing.assert_allclose(np.gradient(prof, t)[1:-1], prof_dot[1:-1], atol=1e-4)


def test_torque_free_truth_with_rotor_conserves_inertial_momentum():
    sc = Scenario()
    inertia, duration, dt = sc.inertia_true_array, 20.0, 0.005
    n = int(round(duration / dt))
    # A rotor of a quarter of the body's momentum (|J w| ~ 800 kg·m²/s): it moves the rates a lot.
    h = rotor_momentum(200.0, np.array([1.0, 2.0, -2.0]) / 3.0, duration, np.arange(n + 1) * dt)
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    q, w = simulate_truth(q0, np.asarray(sc.omega0), inertia, np.zeros((n, 3)), dt, momentum=h)
    big_l = _inertial_momentum(q, w, inertia, h)
    drift = np.abs(big_l - big_l[0]).max() / np.linalg.norm(big_l[0])
    assert drift < 2e-8
    _, w_free = simulate_truth(q0, np.asarray(sc.omega0), inertia, np.zeros((n, 3)), dt)
    assert np.abs(w - w_free).max() > 1.0  # not vacuous: the rotor changed the motion
    # the rotor's momentum counted without its rate (as a wheel held at each value) breaks the
    # balance: the test would catch a truth that left h_dot out
    big_l_wrong = _inertial_momentum(q, w, inertia, np.zeros_like(h))
    assert np.abs(big_l_wrong - big_l_wrong[0]).max() / np.linalg.norm(big_l_wrong[0]) > 1e-2
    with pytest.raises(ConfigError, match="momentum"):
        simulate_truth(q0, np.asarray(sc.omega0), inertia, np.zeros((n, 3)), dt, momentum=h[:-1])


def test_simulate_cli_rotor_writes_h_columns(tmp_path, capsys):
    out = tmp_path / "rotor.csv"
    assert main(["simulate", "--rotor-momentum", "0.5", "--duration", "20", "--out", str(out)]) == 0
    assert "rotor: h_max 0.5" in capsys.readouterr().out
    assert out.read_text().splitlines()[0].endswith(",".join(MOMENTUM))
    (rec,) = read_recordings(out)
    side = json.loads(out.with_suffix(".json").read_text())
    assert rec.h is not None and rec.has_momentum
    assert side["rotor"]["h_max"] == 0.5
    axis = np.asarray(side["rotor"]["axis"])
    assert np.linalg.norm(axis) == pytest.approx(1.0)
    expected = 0.5 * rotor_profile(rec.t, 20.0)[0][:, None] * axis
    np.testing.assert_allclose(rec.h, expected, atol=1e-10)
    assert np.abs(rec.h).max() == pytest.approx(0.5 * np.abs(axis).max(), rel=1e-6)


def test_simulate_without_rotor_unchanged(tmp_path):
    """Same seed, no --rotor-momentum: the seed's file as without any rotor option (pinned)."""
    out = tmp_path / "plain.csv"
    assert main(["simulate", "--duration", "20", "--out", str(out)]) == 0
    header = out.read_text().splitlines()[0]
    assert header == "t,wx,wy,wz,qw,qx,qy,qz,tau_x,tau_y,tau_z"
    assert "rotor" not in json.loads(out.with_suffix(".json").read_text())
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    # Rows 0, 1000 and 1999 and column sums of the seed's output with no rotor option at all.
    golden = {
        0: [0, 0.5012397794, 9.930249077, 0.4434362501, 0.9998923326, 0.006675689766, 0.006441812145,
            0.01136931687, 0, 0, 0],
        1000: [10, 6.786726268, -0.4390641073, 7.669464644, 0.7729648976, -0.3272805371, 0.08882156462,
               0.5362121286, 0, 0, 0],
        1999: [19.99, 4.606950373, -4.439939921, -7.974588022, 0.4641822078, 0.2271746392,
               -0.3787647141, 0.7677654933, 0, 0, 0],
    }
    for row, values in golden.items():
        np.testing.assert_allclose(data[row], values, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(data[:, 1:4].sum(0), [7790.44468411, 1577.3354878, -75.98334289],
                               rtol=1e-9)
    np.testing.assert_allclose(data[:, 8:11].sum(0), [2384.51572936, -708.95643584, -2600.35120121],
                               rtol=1e-9)


def test_rotor_axis_is_the_last_draw():
    """With the rotor, the seed's torque schedule and effect are those of the run without it."""
    sc = Scenario(tau_max=50.0)
    plain, side_plain = simulate_recording(sc, 10.0, "constant_body_torque", seed=4)
    rotor, side_rotor = simulate_recording(sc, 10.0, "constant_body_torque", seed=4, rotor_h_max=30.0)
    np.testing.assert_array_equal(plain.tau, rotor.tau)
    assert side_plain["effect"] == side_rotor["effect"] and plain.h is None
    assert rotor.has_momentum and not np.allclose(plain.w, rotor.w, atol=0.2)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf])
def test_bad_rotor_momentum_refused(bad):
    with pytest.raises(ConfigError, match="rotor-momentum"):
        simulate_recording(Scenario(), 5.0, rotor_h_max=bad)


def test_cli_refuses_non_positive_rotor_momentum(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--rotor-momentum", "0", "--out", str(tmp_path / "x.csv")])
    assert "rotor-momentum" in capsys.readouterr().err
