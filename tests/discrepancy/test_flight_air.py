"""aero_drag's flight form: the air a flat body meets as it flies (a thrown phone or racquet)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from inertia_gym.discrepancy.effects import FLIGHT_MAX_S, GRAVITY, REGISTRY, Effect
from inertia_gym.discrepancy.model import Motion
from inertia_gym.discrepancy.report import diagnose, markdown
from inertia_gym.errors import ConfigError
from inertia_gym.recordings import read_recordings

AERO = REGISTRY["aero_drag"]
SIGMA = 2e-3


def _params(**changes):
    params = {"normal": np.array([0.0, 0.0, 1.0]), "static": np.zeros((3, 3)), "arm": np.zeros(3),
              "arm_sided": np.zeros(3), "flow_damping": np.zeros((3, 3)),
              "launch_velocity": np.zeros(3), "gravity_direction": np.array([0.0, 0.0, -1.0])}
    return {**params, **changes}


def _still(t, rotation=None, rates=None):
    """Motion at times t (k,) s: the body's axes and rates as given (default: not turning)."""
    k = len(t)
    return Motion(np.asarray(t, float), np.tile(np.eye(3), (k, 1, 1)) if rotation is None else rotation,
                  np.zeros((k, 3)) if rates is None else rates)


def test_flight_torque_is_its_definition_term_by_term():
    """tau = (n.u) n x (K u) + (n.u)|n.u| m + (n.u)^2 m' - |n.u| C w, u = R^T (v0 + g t), written out
    for a plate of normal z: each term alone against the numbers it must give."""
    t = np.array([0.0, 0.5])
    v0 = np.array([2.0, 0.0, 3.0])  # at t = 0.5 s: u = (2, 0, 3 - 9.80665 / 2)
    u_z = 3.0 - GRAVITY * 0.5
    # the centre of pressure moving with the flow: K = diag(k1, k2, 0) -> (n.u) (0, k1 u_x, 0) at
    # u = (u_x, 0, u_z): about +y, which turns the normal z towards +x, the flow's side: broadside
    static = AERO.motion_torque(_params(static=np.diag([0.7, 0.3, 0.0]), launch_velocity=v0), _still(t))
    np.testing.assert_allclose(static, [[0.0, 3.0 * 0.7 * 2.0, 0.0], [0.0, u_z * 0.7 * 2.0, 0.0]], atol=1e-12)
    arm = AERO.motion_torque(_params(arm=np.array([0.5, 0.0, 0.0]), launch_velocity=v0), _still(t))
    np.testing.assert_allclose(arm[:, 0], [0.5 * 9.0, 0.5 * u_z * abs(u_z)], atol=1e-12)  # sign follows n.u
    sided = AERO.motion_torque(_params(arm_sided=np.array([0.0, 0.5, 0.0]), launch_velocity=v0), _still(t))
    np.testing.assert_allclose(sided[:, 1], [0.5 * 9.0, 0.5 * u_z ** 2], atol=1e-12)  # whichever side
    rates = np.array([[2.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    damped = AERO.motion_torque(_params(flow_damping=np.diag([0.2, 0.0, 0.0]), launch_velocity=v0),
                                _still(t, rates=rates))
    np.testing.assert_allclose(damped, [[-3.0 * 0.2 * 2.0, 0, 0], [-abs(u_z) * 0.2 * 1.0, 0, 0]], atol=1e-12)


def test_flight_air_speed_is_carried_into_the_body_axes_it_has_turned_to():
    """A body turned 90 deg about z by t = 0.5 s (its x axis along the first sample's y) moving
    along the first sample's y meets that air along its own x: u = R^T v."""
    quarter = Rotation.from_rotvec([0.0, 0.0, np.pi / 2]).as_matrix()
    motion = _still([0.0, 0.5], rotation=np.stack([np.eye(3), quarter]))
    params = _params(normal=np.array([1.0, 0.0, 0.0]), arm=np.array([0.0, 0.0, 1.0]),
                     launch_velocity=np.array([0.0, 1.0, 0.0]), gravity_direction=np.array([0.0, 1.0, 0.0]))
    # at t = 0: u = (0, 1, 0), normal x sees none; at 0.5 s: u = R^T (0, 1 + g / 2, 0) along body x
    speed = 1.0 + GRAVITY * 0.5
    np.testing.assert_allclose(AERO.motion_torque(params, motion), [[0, 0, 0], [0, 0, speed ** 2]], atol=1e-9)


def test_flight_vector_and_named_parameters_round_trip():
    p = np.array([0.7, -2.1, 0.3, -0.2, 0.05, 0.4, -0.6, 0.1, 0.2, 0.5, 0.3, 0.1, 1.0, -2.0, 4.5, 2.5, 0.4])
    back = AERO.pack(AERO.unpack(p))
    np.testing.assert_allclose(back, p, atol=1e-12)
    named = AERO.unpack(p)
    for key in ("static", "flow_damping"):  # in the plate's plane: nothing along the normal
        np.testing.assert_allclose(named[key] @ named["normal"], 0.0, atol=1e-12)
    for key in ("arm", "arm_sided"):
        assert abs(named[key] @ named["normal"]) < 1e-12


def test_flight_form_is_tried_only_where_a_flight_can_last_and_is_never_simulated():
    assert AERO.forms(SimpleNamespace(duration=1.2)) == ("", "flight")
    assert AERO.forms(SimpleNamespace(duration=FLIGHT_MAX_S + 1.0)) == ("",)
    with pytest.raises(ConfigError, match="recording's own motion"):
        AERO.motion_torque(_params(), None)
    with pytest.raises(ConfigError):  # a truth effect takes the default form's parameters only
        Effect("aero_drag", {k: np.asarray(v).tolist() for k, v in _params().items()})


def thrown_plate(path: Path, seed: int, air: bool = True) -> np.ndarray:
    """A phone-like flat body (moments 1 : 0.8 : 0.2 of 3e-4 kg·m², axes turned 2-8 deg from the
    gyro's) thrown straight up at 4.9 m/s (+-0.5 sideways) tumbling near its middle axis at
    15 rad/s, 1 s at 100 Hz, gyro noise SIGMA; with air, a centre of pressure that turns it
    broadside (5 % of J w^2 at the launch speed) and a damping growing with its normal air speed.
    Its own integrator (scipy DOP853 over rates and attitude, the air from the true attitude).
    Returns the plate's normal in the gyro's axes.
    """
    rng = np.random.default_rng(seed)
    moments = np.array([1.0, 0.8, 0.2]) * 3e-4
    axes = Rotation.from_rotvec(np.radians(rng.uniform(2, 8)) * rng.standard_normal(3) / 1.7).as_matrix()
    inertia = axes @ np.diag(moments) @ axes.T
    normal = axes[:, 0]
    plane = np.eye(3) - np.outer(normal, normal)
    k = 0.05 * moments[0] * 15.0 ** 2 / 4.9 ** 2
    c = 0.01 * moments[0] / 4.9 * plane
    v0 = np.r_[rng.uniform(-0.5, 0.5, 2), 4.9]
    q0 = Rotation.random(random_state=int(rng.integers(2 ** 31)))
    w0 = 15.0 * (axes @ np.array([rng.uniform(0.02, 0.08), 1.0, rng.uniform(0.02, 0.08)]))

    def rate(t, y):
        w, q = y[:3], y[3:] / np.linalg.norm(y[3:])
        u = Rotation.from_quat(q, scalar_first=True).inv().apply(v0 + np.array([0.0, 0.0, -GRAVITY]) * t)
        un = u @ normal
        tau = un * np.cross(normal, k * plane @ u) - abs(un) * c @ w if air else np.zeros(3)
        qw, qx, qy, qz = q
        q_dot = 0.5 * np.array([-qx * w[0] - qy * w[1] - qz * w[2], qw * w[0] + qy * w[2] - qz * w[1],
                                qw * w[1] - qx * w[2] + qz * w[0], qw * w[2] + qx * w[1] - qy * w[0]])
        return np.r_[np.linalg.solve(inertia, tau - np.cross(w, inertia @ w)), q_dot]

    t = np.arange(0, 1.0, 0.01)
    sol = solve_ivp(rate, (0, t[-1]), np.r_[w0, q0.as_quat(scalar_first=True)], t_eval=t, method="DOP853",
                    rtol=1e-10, atol=1e-12)
    w = sol.y[:3].T + SIGMA * rng.standard_normal((t.size, 3))
    np.savetxt(path, np.column_stack([t + 2.0, w]), delimiter=",", header="t,wx,wy,wz", comments="",
               fmt="%.9g")
    path.with_suffix(".json").write_text(json.dumps({"gyro_sigma": SIGMA}))
    return normal


@pytest.mark.parametrize("seed", [0, pytest.param(2, marks=pytest.mark.science), 3])
def test_a_thrown_plate_is_read_as_the_air_of_its_flight(tmp_path, seed):
    """An independent simulator's thrown plate: aero_drag in its flight form leads the explanation,
    the fit reaches the noise, and the plate's normal comes out within 5 deg."""
    path = tmp_path / "toss.csv"
    normal = thrown_plate(path, seed)
    report = diagnose(list(read_recordings(path))[0]).report
    lead = report["explanation"][0]
    assert (lead["name"], lead["form"], lead["family"]) == ("aero_drag", "flight", "drag")
    assert max(report["fit_before"]["rms_over_noise"]) > 50
    assert max(report["fit_after"]["rms_over_noise"]) < 1.3
    angle = np.degrees(np.arccos(min(1.0, abs(np.dot(lead["params"]["normal"], normal)))))
    assert angle < 5.0
    assert {c["with"] for c in lead["confounded_with"]} >= {"viscous_damping", "internal_momentum"}
    # thrown up at 4.9 m/s (0.5 m/s at most sideways per axis): the throw's speed and climb
    v0, down = np.array(lead["params"]["launch_velocity"]), np.array(lead["params"]["gravity_direction"])
    assert 4.0 < np.linalg.norm(v0) < 6.0 and -(v0 @ down) / np.linalg.norm(v0) > np.sin(np.radians(70))
    assert "flat plate of normal" in markdown(report, [])


@pytest.mark.parametrize("seed", [0, 1])
def test_the_same_throw_without_air_names_nothing(tmp_path, seed):
    path = tmp_path / "toss.csv"
    thrown_plate(path, seed, air=False)
    report = diagnose(list(read_recordings(path))[0]).report
    assert report["explanation"] == []
    assert max(report["fit_after"]["rms_over_noise"]) < 1.3
