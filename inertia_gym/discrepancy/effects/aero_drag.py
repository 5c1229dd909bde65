"""aero_drag: air on the body, quadratic drag of its rotation or a flat body's flight."""

from __future__ import annotations

import numpy as np
from scipy import signal
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import register
from inertia_gym.discrepancy.effects.drag import _Drag, _drag_matrix
from inertia_gym.errors import ConfigError

#: s: the longest record read as a free flight through air (AeroDrag's flight form): a body
#: thrown by hand falls back within a few seconds (2.9 s from a throw to 10 m).
FLIGHT_MAX_S = 5.0
#: m/s^2, standard gravity
GRAVITY = 9.80665


def plane_basis(polar: float, azimuth: float) -> np.ndarray:
    """(3, 2): two unit vectors normal to the direction (polar, azimuth) rad and to each other,
    along increasing polar and azimuth angle (smooth in both).
    """
    return np.array([[np.cos(polar) * np.cos(azimuth), -np.sin(azimuth)],
                     [np.cos(polar) * np.sin(azimuth), np.cos(azimuth)],
                     [-np.sin(polar), 0.0]])


def direction(polar: float, azimuth: float) -> np.ndarray:
    """The unit vector (3,) of the angles polar and azimuth (rad)."""
    return np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])


def direction_angles(v) -> tuple[float, float]:
    """Polar and azimuth angles (rad) of the direction of v (3,)."""
    v = np.asarray(v, float) / np.linalg.norm(v)
    return float(np.arccos(np.clip(v[2], -1.0, 1.0))), float(np.arctan2(v[1], v[0]))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross(a, b) of one vector a (3,) with rows b (n, 3), the same products in the same
    order, without np.cross's axis handling: the flight's torque takes it at every evaluation.
    """
    out = np.empty(b.shape)
    np.subtract(a[1] * b[:, 2], a[2] * b[:, 1], out=out[:, 0])
    np.subtract(a[2] * b[:, 0], a[0] * b[:, 2], out=out[:, 1])
    np.subtract(a[0] * b[:, 1], a[1] * b[:, 0], out=out[:, 2])
    return out


def _in_plane(e: np.ndarray, a: float, b: float, c: float) -> np.ndarray:
    """The symmetric (3, 3) matrix E [[a, c], [c, b]] E^T of a plane's basis e (3, 2)."""
    return e @ np.array([[a, c], [c, b]]) @ e.T


@register
class AeroDrag(_Drag):
    """Air on the body. Two forms.

    The default, quadratic drag of the rotation's own air speed: torque -|w| C w (C symmetric,
    N·m·s²); C = c I is the isotropic -c |w| w, a diagonal C the per-axis -c_i |w| w_i.

    "flight": the air a flat body meets as it flies (a thrown phone, racquet or plate; records
    of at most FLIGHT_MAX_S). The body moves through still air at u = R(t)^T (v0 + g (t - t0)),
    in its own axes (R(t) its attitude relative to the first sample, integrated from the
    measured rates; v0 the launch velocity and g gravity, 9.80665 m/s² along a fitted
    direction, both in the body's axes at the first sample), and a plate of normal n takes
        tau = (n.u) n x (K u) + (n.u)|n.u| m + (n.u)^2 m' - |n.u| C w,
    K symmetric in the plate's plane (kg: a centre of pressure that moves with the flow across
    the plate, which turns a plate broadside to it), m and m' in the plane (kg: a centre of
    pressure off the centre of mass, a racquet's head, for m; one that moves to the side the
    flow comes from, a body whose two faces differ, for m') and C symmetric in the plane (kg·m:
    the damping of the plate's rotation, growing with its normal air speed). Fitted as n's
    angles, K (3), m (2), m' (2) and C (3) in the plane's basis, v0 (3, m/s) and g's angles:
    17 numbers.
    """

    name = "aero_drag"
    # air is what the body needs for this to be its physics: in space the same terms are only a
    # torque that the record holds and the model does not
    hardware, hardware_words = ("air",), "air"
    as_fitted = {"": "an unmodelled torque against the rates that grows with their square, fitted as "
                     "a quadratic drag",
                 "flight": "an unmodelled torque that follows the attitude along a fitted flight path, "
                           "fitted as the air on a flat plate"}
    units = {"c": "N·m·s²", "normal": "", "static": "kg", "arm": "kg", "arm_sided": "kg",
             "flow_damping": "kg·m", "launch_velocity": "m/s", "gravity_direction": ""}
    ambiguities = (("viscous_damping", "-C w and -|w| C w coincide while |w| stays nearly constant"),)
    flight_ambiguities = (
        ("viscous_damping", "a flight's normal air speed changes the plate's damping over the record, "
                            "as the varying form of viscous_damping does"),
        ("internal_momentum", "a torque the flight sets about the body's axes has a time course of "
                              "its own, which a momentum changing along one body axis can follow"))
    FLIGHT_SIZE = 17

    @override
    def carried_words(self):
        return "the body moves through air"

    @override
    def lacked_words(self):
        return "there is no air about the body"

    @override
    def _scale(self, d):
        return 0.01 * d.j_ref / d.omega_ref

    @override
    def draw(self, rng, body):
        return {"c": np.diag(rng.uniform(0.004, 0.015) * rng.uniform(0.3, 1.0, 3) * body.j / body.omega_ref)}

    @override
    def forms(self, d):
        return ("", "flight") if d.duration <= FLIGHT_MAX_S else ("",)

    @override
    def form_size(self, form, d):
        return self.FLIGHT_SIZE if form == "flight" else self.size

    @override
    def confounded(self, form):
        return self.ambiguities + (self.flight_ambiguities if form == "flight" else ())

    @staticmethod
    def _speed(d) -> float:
        """m/s: the air speed of a toss as long as d, rising and falling back (g T / 2)."""
        return max(GRAVITY * d.duration / 2.0, 0.5)

    def _flight_typical(self, d) -> np.ndarray:
        k = 0.05 * d.j_ref * d.omega_ref ** 2 / self._speed(d) ** 2  # a torque of 5 % of J w^2
        c = 0.01 * d.j_ref / self._speed(d)
        return np.r_[0.3, 0.3, np.full(7, k), np.full(3, c), np.full(3, 1.0), 0.3, 0.3]

    @override
    def typical(self, form, d):
        return self._flight_typical(d) if form == "flight" else super().typical(form, d)

    @override
    def bounds(self, form, d):
        if form != "flight":
            return super().bounds(form, d)
        top = np.r_[10.0, 10.0, np.full(10, np.inf), np.full(3, 50.0), 10.0, 10.0]
        return -top, top

    @override
    def starts(self, form, d, probe):
        if form != "flight":
            return super().starts(form, d, probe)
        return self._flight_screen(d, probe.base.inertia)

    #: Gravity's directions (in the body's axes at the first sample) the flight form's screen tries.
    SCREEN_DIRECTIONS = 64
    #: Starts the screen keeps (its best directions, at least FLIGHT_APART_DEG apart).
    SCREEN_KEEP = 2
    FLIGHT_APART_DEG = 30.0

    def _flight_screen(self, d, inertia) -> list[np.ndarray]:
        """Starts of the flight form: the plate's normal along the largest moment's axis of
        inertia (3, 3) kg·m² (a flat body's), launched straight up at g T / 2 (the apex
        mid-record) against gravity along each of SCREEN_DIRECTIONS directions; for each, K, m,
        m' and C by least squares against the torque the rates ask of the body, J dw/dt + w x J w
        - tau (w smoothed and differentiated by a cubic Savitzky-Golay filter over about half a
        radian of turn), linear in them; the SCREEN_KEEP directions that explain most.
        """
        t, w = d.t, d.w
        window = int(np.clip(0.5 / max(d.omega_ref * d.dt, 1e-9), 5, 31)) | 1
        if t.size <= window:
            return []
        rotation = d.motion(d.grid).rotation[d.grid.sample_pos]
        w_dot = signal.savgol_filter(w, window, 3, deriv=1, delta=d.dt, axis=0)
        asked = w_dot @ inertia.T + np.cross(w, w @ inertia.T) - d.tau
        polar, azimuth = direction_angles(np.linalg.eigh(inertia)[1][:, 2])
        n, e = direction(polar, azimuth), plane_basis(polar, azimuth)
        shapes = [np.outer(e[:, 0], e[:, 0]), np.outer(e[:, 1], e[:, 1]),
                  np.outer(e[:, 0], e[:, 1]) + np.outer(e[:, 1], e[:, 0])]
        golden = np.pi * (3.0 - np.sqrt(5.0))
        z = 1.0 - (2 * np.arange(self.SCREEN_DIRECTIONS) + 1) / self.SCREEN_DIRECTIONS
        ring = np.sqrt(1.0 - z ** 2)
        turn = golden * np.arange(z.size)
        downs = np.stack([ring * np.cos(turn), ring * np.sin(turn), z], 1)
        fits = []
        for down in downs:
            velocity = -self._speed(d) * down + GRAVITY * down * (t - t[0])[:, None]
            u = np.einsum("kji,kj->ki", rotation, velocity)
            un = u @ n
            columns = ([un[:, None] * np.cross(n, u @ b) for b in shapes]
                       + [(un * np.abs(un))[:, None] * e[:, i] for i in range(2)]
                       + [(un ** 2)[:, None] * e[:, i] for i in range(2)]
                       + [-np.abs(un)[:, None] * (w @ b) for b in shapes])
            a = np.stack([c.ravel() for c in columns], 1)
            scale = np.linalg.norm(a, axis=0) + 1e-300
            sol, *_ = np.linalg.lstsq(a / scale, asked.ravel(), rcond=None)
            sol = sol / scale
            cost = float(np.sum((a @ sol - asked.ravel()) ** 2))
            fits.append((cost, down, sol))
        out, kept = [], []
        for _, down, sol in sorted(fits, key=lambda f: f[0]):
            if all(down @ v < np.cos(np.radians(self.FLIGHT_APART_DEG)) for v in kept):
                kept.append(down)
                start = np.r_[polar, azimuth, sol, -self._speed(d) * down, direction_angles(down)]
                out.append(self.feasible(start, None))
            if len(out) == self.SCREEN_KEEP:
                break
        return out

    @override
    def unpack(self, p):
        if p.size != self.FLIGHT_SIZE:
            return super().unpack(p)
        e = plane_basis(p[0], p[1])
        return {"normal": direction(p[0], p[1]), "static": _in_plane(e, *p[2:5]), "arm": e @ p[5:7],
                "arm_sided": e @ p[7:9], "flow_damping": _in_plane(e, *p[9:12]),
                "launch_velocity": np.array(p[12:15]), "gravity_direction": direction(p[15], p[16])}

    @override
    def pack(self, params):
        if "normal" not in params:
            return super().pack(params)
        polar, azimuth = direction_angles(params["normal"])
        e = plane_basis(polar, azimuth)
        k = e.T @ np.asarray(params["static"], float) @ e
        c = e.T @ np.asarray(params["flow_damping"], float) @ e
        return np.r_[polar, azimuth, k[0, 0], k[1, 1], k[0, 1], e.T @ np.asarray(params["arm"], float),
                     e.T @ np.asarray(params["arm_sided"], float), c[0, 0], c[1, 1], c[0, 1],
                     np.asarray(params["launch_velocity"], float),
                     direction_angles(params["gravity_direction"])]

    @override
    def feasible(self, p, inertia):
        if p.size != self.FLIGHT_SIZE:
            return super().feasible(p, inertia)
        # the plate's damping only takes energy out: its 2 x 2 matrix positive semi-definite
        values, vectors = np.linalg.eigh(np.array([[p[9], p[11]], [p[11], p[10]]]))
        c = (vectors * np.maximum(values, 0.0)) @ vectors.T
        return np.r_[p[:9], c[0, 0], c[1, 1], c[0, 1], p[12:]]

    @override
    def face(self, p):
        return np.zeros((0, p.size)) if p.size == self.FLIGHT_SIZE else super().face(p)

    @override
    def disturbance(self, params):
        return {} if "normal" in params else {"aero_drag": _drag_matrix(params["c"])}

    @override
    def motion_torque(self, params, motion):
        if "normal" not in params:
            return None
        if motion is None:
            raise ConfigError("aero_drag's flight form reads the recording's own motion: it is "
                              "fitted to recordings, not simulated")
        n = np.asarray(params["normal"], float)
        velocity = (np.asarray(params["launch_velocity"], float)[None]
                    + GRAVITY * np.asarray(params["gravity_direction"], float)[None]
                    * (motion.t - motion.t[0])[:, None])
        u = np.einsum("kji,kj->ki", motion.rotation, velocity)  # R^T v: in the body's axes
        normal_speed = u @ n
        return (normal_speed[:, None] * _cross(n, u @ np.asarray(params["static"], float))
                + (normal_speed * np.abs(normal_speed))[:, None] * np.asarray(params["arm"], float)[None]
                + (normal_speed ** 2)[:, None] * np.asarray(params["arm_sided"], float)[None]
                - np.abs(normal_speed)[:, None] * (motion.rates @ np.asarray(params["flow_damping"], float)))
