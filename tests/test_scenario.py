import json

import numpy as np
import pytest

from inertia_gym.errors import ConfigError
from inertia_gym.excitation import (
    burst_direction,
    burst_torque,
    check_xi,
    episode_schedule,
    validation_schedule,
)
from inertia_gym.information import theta_from_inertia
from inertia_gym.scenario import Scenario


def test_paper_defaults_and_bounds_formula(paper):
    assert paper.omega_ref == pytest.approx(np.linalg.norm([0.5, 10, 0.45]))
    lo, hi = paper.xi_bounds
    assert lo.tolist() == [0.0, 0.0, 0.05]
    assert hi[0] == pytest.approx(5.0 / paper.omega_ref)
    assert hi[1:].tolist() == [5.0, 1.0]


@pytest.mark.parametrize(
    "field, value",
    [
        ("inertia_true", [[100, 6, -4], [5, 80, 3], [-4, 3, 70]]),  # not symmetric
        ("inertia_true", [[1, 0, 0], [0, -1, 0], [0, 0, 1]]),  # indefinite
        ("inertia_guess", [[np.nan, 0, 0], [0, 1, 0], [0, 0, 1]]),
        ("inertia_true", [[1, 0], [0, 1]]),  # wrong shape
        ("omega0", [0.5, np.inf, 0.0]),
        ("omega0", [1.0, 2.0]),
        ("dt", 0.0),
        ("dt", -0.01),
        ("tau_max", 0.0),
        ("tau_max", -5.0),
        ("gyro_sigma", float("nan")),
        ("dwell", [5.0, 0.0]),
        ("dwell", [-1.0, 3.0]),
        ("t_on", [0.0, 1.0]),
        ("meas_interval", [0.0, 0.2]),
        ("P0_theta", -1.0),
        ("bursts_per_episode", 0),
        ("bursts_per_episode", 2.5),
        ("estimator", "pf"),
    ],
)
def test_bad_scenario_fields_name_the_field(field, value):
    with pytest.raises(ConfigError, match=field):
        Scenario(**{field: value})


def test_load_toml_and_json(tmp_path):
    (tmp_path / "s.toml").write_text('tau_max = 0.02\ninertia_true = [[1.0,0,0],[0,2.0,0],[0,0,2.5]]\n')
    sc = Scenario.load(tmp_path / "s.toml")
    assert sc.tau_max == 0.02 and sc.inertia_true[2][2] == 2.5
    (tmp_path / "s.json").write_text(json.dumps({"omega0": [0.1, 0.2, 0.3]}))
    assert Scenario.load(tmp_path / "s.json").omega0 == (0.1, 0.2, 0.3)
    (tmp_path / "bad.json").write_text(json.dumps({"omega_0": [0.1, 0.2, 0.3]}))
    with pytest.raises(ConfigError, match="omega_0"):
        Scenario.load(tmp_path / "bad.json")
    (tmp_path / "broken.toml").write_text("tau_max = = 3")
    with pytest.raises(ConfigError, match="broken.toml"):
        Scenario.load(tmp_path / "broken.toml")
    with pytest.raises(ConfigError, match="does not exist"):
        Scenario.load(tmp_path / "missing.toml")


def test_burst_torque_law_and_saturation():
    v = np.array([0.0, 0.0, 1.0])
    w = np.array([0.0, 10.0, 0.0])
    tau = burst_torque(0.2, 1.0, w, v, tau_max=5.0)
    assert np.allclose(tau, 0.2 * np.cross(w, v) + 1.0 * v)
    big = burst_torque(3.0, 4.0, w, v, tau_max=5.0)
    assert np.abs(big).max() == pytest.approx(5.0)
    unsat = 3.0 * np.cross(w, v) + 4.0 * v
    assert np.allclose(big / np.linalg.norm(big), unsat / np.linalg.norm(unsat))
    with pytest.raises(ConfigError, match="tau_max"):
        burst_torque(1.0, 1.0, w, v, tau_max=0.0)


def test_burst_direction_is_least_known_axis():
    # Uncertainty concentrated on Jzz: v is the z axis.
    p = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 100.0])
    assert np.allclose(burst_direction(p), [0.0, 0.0, 1.0])
    # Uncertainty along the scale direction of J: the axis of J's largest moment.
    j = np.diag([3.0, 1.0, 2.0])
    d = theta_from_inertia(j)
    p = np.eye(6) + 50 * np.outer(d, d)
    assert np.allclose(np.abs(burst_direction(p)), [1.0, 0.0, 0.0])


def test_check_xi_rejects_bad_actions(paper):
    bounds = paper.xi_bounds
    check_xi([0.1, 1.0, 0.5], bounds)
    for bad, what in (([np.nan, 1, 0.5], "finite"), ([0.1, 9.0, 0.5], "b"),
                      ([0.1, 1.0, 0.0], "T_on"), ([0.1, 1.0], "shape")):
        with pytest.raises(ConfigError, match=what):
            check_xi(bad, bounds)


def test_schedules_respect_bounds(paper, rng):
    ep = episode_schedule(paper, 0.5, rng)
    assert len(ep.bursts) == paper.bursts_per_episode
    assert np.all(ep.bursts[:, 1] - ep.bursts[:, 0] == 50)
    gaps = np.diff(np.r_[ep.bursts[:, 0], ep.n_steps]) - 50
    assert np.all((gaps >= 500) & (gaps <= 2000))
    segs = validation_schedule(paper, 1.0, 1000.0, rng)
    assert sum(s.n_steps for s in segs) == 100_000
    assert 9 <= sum(len(s.bursts) for s in segs) <= 11
