import json

import numpy as np
import pytest

from inertia_gym.errors import ConfigError
from inertia_gym.excitation import (
    burst_direction,
    burst_directions,
    burst_torque,
    check_xi,
    episode_schedule,
    validation_schedule,
)
from inertia_gym.information import theta_from_inertia
from inertia_gym.scenario import Scenario, ScenarioWarning, shipped_scenarios


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
    with pytest.warns(ScenarioWarning, match="inertia_guess"):  # the paper's guess for this body
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


def test_burst_directions_of_a_stack_are_each_alone(rng):
    a = rng.standard_normal((30, 6, 6))
    p = a @ a.transpose(0, 2, 1)
    skip = np.arange(30) % 7 == 3
    p[3] = np.nan  # skipped rows are not looked at
    expected = [burst_direction(m) if not s else [1.0, 0.0, 0.0] for m, s in zip(p, skip)]
    np.testing.assert_array_equal(burst_directions(p, skip), np.array(expected))
    assert burst_directions(p[skip], np.ones(4, bool)).tolist() == [[1.0, 0.0, 0.0]] * 4
    with pytest.raises(ConfigError, match="finite"):
        burst_directions(p, np.zeros(30, bool))


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


# --- scale-free defaults ------------------------------------------------------------------------

PAPER_NUMBERS = dict(P0_theta=15000.0, Q_theta=5e-2, Q_omega=1e-3, Q_quat=1e-4, P0_attitude_rate=1e-2,
                     epsilon=1e-8, epsilon_lambda=1e-8, softmin_beta=1.0, t_on=(0.05, 1.0),
                     dwell=(5.0, 20.0), validation_coast=(90.0, 100.0))


def test_paper_scenario_derives_exactly_the_papers_numbers(paper):
    for name, value in PAPER_NUMBERS.items():
        got = np.array(paper.P0_theta) if name == "P0_theta" else getattr(paper, name)
        expected = value * np.eye(6) if name == "P0_theta" else value
        assert np.array_equal(got, expected), name  # bit-identical, not approximately
    assert set(paper.derived) == set(PAPER_NUMBERS)
    assert paper == Scenario(**PAPER_NUMBERS) and paper.burst_time == 1.0


def test_derived_defaults_follow_their_rules():
    """Each rule written out from its definition (README, "Scenarios") on a non-paper body."""
    guess = np.diag([0.085, 0.2, 0.15])
    sc = Scenario(inertia_true=np.diag([0.1, 0.12, 0.05]), inertia_guess=guess, omega0=(0.03, 0.1, 0.02),
                  tau_max=1e-3, gyro_sigma=1e-3, quat_sigma=2e-3, meas_interval=(0.05, 0.1))
    size = np.trace(guess)  # 0.435 kg·m²
    accel = 1e-3 / size  # the torque's angular acceleration scale, rad/s²
    burst = max(5 * 0.1, size / 3 * 1e-3 / 1e-3)  # 0.5 s: five longest sampling intervals
    assert np.allclose(np.array(sc.P0_theta), (0.2848 * size) ** 2 * np.eye(6), rtol=1e-3)
    assert sc.Q_theta == pytest.approx(5e-2 / 430**2 * size**2)
    assert sc.Q_omega == pytest.approx(1e-3 / 0.03**2 * 1e-3**2)
    assert sc.Q_quat == pytest.approx(2e-3**2)
    assert sc.P0_attitude_rate == pytest.approx(1e-2 * (2e-3 / 1e-2) ** 2)
    assert sc.epsilon == pytest.approx(1e-8 * (accel / (5.0 / 430)) ** 2)
    assert sc.epsilon_lambda == sc.epsilon and sc.softmin_beta == pytest.approx(1e-8 / sc.epsilon)
    assert sc.burst_time == pytest.approx(burst)
    assert sc.t_on == pytest.approx((0.05, burst))
    assert sc.dwell == pytest.approx((5 * burst, 20 * burst))
    assert sc.validation_coast == pytest.approx((90 * burst, 100 * burst))
    # A weak actuator lengthens the bursts until a full one moves the mean moment's rate by
    # one gyro sigma, and the schedule with them.
    weak = sc.replace(tau_max=1e-5)
    assert weak.burst_time == pytest.approx(size / 3 * 1e-3 / 1e-5)
    assert weak.tau_max * weak.t_on[1] / (size / 3) == pytest.approx(weak.gyro_sigma)
    assert weak.dwell[0] == pytest.approx(5 * weak.burst_time)


def test_given_fields_are_kept_and_replace_derives_the_others_again(paper):
    sc = Scenario(Q_theta=1e-3)
    assert sc.Q_theta == 1e-3 and "Q_theta" not in sc.derived
    with pytest.warns(ScenarioWarning, match="factor up to 80"):  # the truth kept its size
        small = sc.replace(inertia_guess=np.array(paper.inertia_guess) * 1e-2)
    assert small.Q_theta == 1e-3  # given: kept
    assert small.P0_theta[0][0] == pytest.approx(15000.0 * 1e-4)  # derived: derived again
    back = small.replace(inertia_guess=paper.inertia_guess)
    assert back == sc
    assert Scenario.from_mapping(sc.to_dict()) == sc and "derived" not in sc.to_dict()


def test_scaled_body_gives_the_same_non_dimensional_filter_and_metric(paper):
    """J and tau times s: the motion is the same (w_dot = J^-1 (tau - w x J w)), so every derived
    constant must map to the paper's in the filter's scale-shape coordinates and the metric."""
    s = 1e-4
    small = paper.replace(inertia_true=np.array(paper.inertia_true) * s,
                          inertia_guess=np.array(paper.inertia_guess) * s, tau_max=paper.tau_max * s)
    assert small.Q_theta == pytest.approx(paper.Q_theta * s**2)
    assert np.allclose(small.P0_theta, np.array(paper.P0_theta) * s**2)
    for name in ("epsilon", "epsilon_lambda", "softmin_beta", "Q_omega", "Q_quat", "P0_attitude_rate",
                 "t_on", "dwell", "validation_coast"):
        assert getattr(small, name) == pytest.approx(getattr(paper, name), rel=1e-12), name
    assert np.allclose(small.xi_bounds[:, 1:], paper.xi_bounds[:, 1:] * [s, 1])


# --- physical validity and plausibility ---------------------------------------------------------

@pytest.mark.parametrize("inertia", [
    np.diag([0.1, 0.1, 0.5]),  # the impossible body: 0.5 > 0.1 + 0.1
    np.diag([3.0, 1.0, 1.0]),
])
def test_triangle_inequality_is_enforced(inertia):
    for field in ("inertia_true", "inertia_guess"):
        with pytest.raises(ConfigError, match=rf"^{field} .*triangle inequality") as err:
            Scenario(**{field: inertia})
        assert "\n" not in str(err.value)


def test_triangle_inequality_uses_principal_moments():
    rot = np.linalg.qr(np.random.default_rng(0).standard_normal((3, 3)))[0]
    with pytest.raises(ConfigError, match="0.5 > 0.1 \\+ 0.1"):
        Scenario(inertia_true=rot @ np.diag([0.1, 0.1, 0.5]) @ rot.T)
    plate = rot @ np.diag([1.0, 2.0, 3.0]) @ rot.T  # a thin plate: equality holds, allowed
    assert np.allclose(Scenario(inertia_true=plate, inertia_guess=plate).inertia_true, plate)


@pytest.mark.parametrize("field, value", [
    ("tau_max", "5 N*m"), ("tau_max", True), ("gyro_sigma", [0.01, "a"]), ("omega0", {"x": 1.0}),
    ("inertia_true", [[1.0, 0.0, 0.0], [0.0, 1.0]]), ("use_vector_sensors", "yes"), ("estimator", ["ekf"]),
    ("P0_theta", "big"), ("Q_theta", -1.0), ("dwell", [1.0]),
])
def test_wrong_types_are_one_line_errors_naming_the_field(field, value):
    with pytest.raises(ConfigError, match=field) as err:
        Scenario(**{field: value})
    assert "\n" not in str(err.value)


def test_implausible_scenarios_warn(paper):
    cubesat = dict(inertia_true=np.diag([0.1, 0.12, 0.05]), omega0=(0.03, 0.1, 0.02), gyro_sigma=1e-3)
    with pytest.warns(ScenarioWarning, match="inertia_guess's principal moments .* factor up to"):
        Scenario(**cubesat, tau_max=1e-3)  # the paper's 85-210 kg·m² guess for a CubeSat
    with pytest.warns(ScenarioWarning, match="will not be identified"):
        paper.replace(tau_max=1e-6, t_on=(0.05, 1.0))
    with pytest.warns(ScenarioWarning, match="tau_max is implausible"):
        Scenario(**cubesat, inertia_guess=np.diag([0.085, 0.2, 0.15]), tau_max=5.0)
    assert paper.implausibilities() == []


def test_shipped_scenarios_load_by_name_and_are_plausible(tmp_path, paper):
    assert {"paper", "cubesat-6u", "upper-stage"} <= set(shipped_scenarios())
    assert Scenario.load("paper") == paper
    for name in shipped_scenarios():
        sc = Scenario.load(name)
        assert sc.implausibilities() == [] and set(sc.derived) == set(PAPER_NUMBERS), name
    with pytest.raises(ConfigError, match="cubesat-6u"):  # the message lists the shipped names
        Scenario.load("cubesat")
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfe\x00tau")
    with pytest.raises(ConfigError, match="not valid toml"):
        Scenario.load(tmp_path / "bin.toml")


def test_cli_refuses_an_impossible_body_and_warns_about_a_far_guess(tmp_path, capsys):
    from inertia_gym.cli import main

    def simulate(path):
        out = str(tmp_path / "r.csv")
        return main(["simulate", "--scenario", str(path), "--duration", "1", "--out", out])

    bad = tmp_path / "bad.toml"
    bad.write_text("inertia_true = [[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.5]]\n")
    assert simulate(bad) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "triangle" in err
    assert err.startswith("inertia-gym simulate: error: inertia_true")
    far = tmp_path / "far.toml"  # a CubeSat with the paper's 85-210 kg·m² guess left in place
    far.write_text("inertia_true = [[0.1, 0, 0], [0, 0.12, 0], [0, 0, 0.05]]\ntau_max = 1e-3\n"
                   "omega0 = [0.03, 0.1, 0.02]\ngyro_sigma = 1e-3\n")
    assert simulate(far) == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("inertia-gym simulate: warning: inertia_guess's principal moments [85, 135, 210]")
    assert "\n" not in err
