"""Prototype effects, not in the catalogue, measured on the racquet tosses (issue 11, must-show 3).

The racquet's leading explanation split between `internal_momentum` (time-varying) and
`viscous_damping`. This script asks whether a physical effect the catalogue lacks explains the
tosses better. It fits prototypes on each toss next to the catalogue's own (`viscous_damping`
in its best form: since 2026-11-26 also the varying form, a drag whose coefficient changes over
the flight, which this script first measured as a prototype):

- ``flight_aero``: the racquet's head is a flat plate moving through still air. The force on it
  is along its normal n, -k |u_n| u_n, at an arm from the centre of mass; its torque is
  -k a |u_n| u_n with a = r x n (m), which lies in the plate's plane. The head's normal air
  speed is u_n = n . u + w . a, where u is the centre of mass's velocity v0 + g t carried into
  the body frame. The attitude comes from integrating the measured gyro. The measured rates
  also stand in for w, so the torque is an input computed from the data. Its 10 parameters are
  a's two components in the plane (along the polar and azimuth directions of n, m), k, n
  (2 angles), v0 (3, m/s, in the body frame at the first row) and the direction of g (2 angles,
  |g| = 9.81 m/s^2). Its starts: a along the fitted intermediate principal axis (0.3 m), n along
  the major axis, g along each body axis, and v0 putting the apex mid-toss.
- ``gyro_matrix``: the gyro reads (I + E) w with E symmetric (scale and cross-axis errors,
  6 parameters, each within 0.1).
- ``space_torque`` (added 2026-11-26): a torque fixed in space, tau0 + tau1 t in the frame of the
  body at the first row, carried into the body by the attitude integrated from the gyro
  (6 parameters): what a torque about a fixed body axis with a free time course (the
  time-varying internal momentum) can mimic on a steady spin.

Since 2026-12-03 the catalogue has the air of a flight itself, `aero_drag`'s form `flight`
(effects.AeroDrag: a centre of pressure that moves with the flow, one off the centre of mass and
the plate's damping, from the same flight), which leads the explanation of all 7 round-1 tosses;
``flight_aero`` here is the earlier prototype as it was measured.

Each prototype is registered in this process only, so `diagnose` is unchanged. It is fitted by
the same solver as the catalogue (fit.fit_effect) on the record as diagnose prepares it
(re-timed, its ends trimmed where the rigid fit locates impulses; diagnose may trim again after
its explanation, this script does not). Its BICs count every row as independent (diagnose
recounts them where what a fit leaves is correlated, so its delta BICs are smaller). Output per
toss: the delta BIC each candidate gains over the rigid fit, the worst-axis rms/noise, the fitted
plate geometry, the pairs viscous_damping + each of (flight_aero, internal_momentum), and the
best single effect, counted over all tosses and over the intermediate-axis flips alone (the
segments whose comment in meta/segments.csv says "Intermediate").

Usage: PYTHONPATH=. python scripts/racquet_candidates.py [--data ../shared/data/phyphox-racquet]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy import effects as E
from inertia_gym.discrepancy import fit as F
from inertia_gym.discrepancy.effects import GRAVITY, direction, direction_angles, plane_basis
from inertia_gym.discrepancy.model import integrated_attitude
from inertia_gym.discrepancy.report import impulses
from inertia_gym.recordings import read_recordings, retimed


def arm(p) -> np.ndarray:
    """The flight_aero arm a (3,) m: its two in-plane components p[0:2] on the plate's plane."""
    return plane_basis(p[3], p[4]) @ p[0:2]


class Flight:
    """The measured toss the flight_aero prototype reads: times t (n,) s, rates w (n, 3) rad/s and
    the body-to-start rotations (n, 3, 3) integrated from them (midpoint rate over each row)."""

    t = np.zeros(1)
    w = np.zeros((1, 3))
    rotation = np.eye(3)[None]

    @classmethod
    def set(cls, t, w) -> None:
        cls.t, cls.w, cls.rotation = t, w, integrated_attitude(t, w)


def plate_torque(p) -> np.ndarray:
    """The flight_aero torque (n, 3) at the measured rows for the vector p (10,)."""
    a, k, normal = arm(p), p[2], direction(p[3], p[4])
    v0, down = p[5:8], direction(p[8], p[9])
    velocity = v0[None] + GRAVITY * down[None] * (Flight.t - Flight.t[0])[:, None]
    u = np.einsum("kji,kj->ki", Flight.rotation, velocity)  # R^T v: in the body frame
    u_n = u @ normal + Flight.w @ a
    return -k * a[None] * (np.abs(u_n) * u_n)[:, None]


@E.register
class FlightAero(E.EffectModel):
    """Prototype: a plate's aerodynamic torque in flight (see the module docstring)."""

    name, params, size, family = "flight_aero", ("p",), 10, "drag"

    @override
    def typical(self, form, d):
        return np.array([0.1, 0.1, 0.3, 0.3, 0.3, 1.0, 1.0, 1.0, 0.3, 0.3])

    @override
    def bounds(self, form, d):
        top = np.array([1.0, 1.0, np.inf, 10, 10, 40, 40, 40, 10, 10])
        return np.r_[-top[:2], 0.0, -top[3:]], top

    @override
    def starts(self, form, d, probe):
        _, axes = np.linalg.eigh(probe.base.inertia)  # minor, intermediate, major
        normal = direction_angles(axes[:, 2])
        duration = float(d.t[-1] - d.t[0])
        out = []
        in_plane = plane_basis(*normal).T @ (0.3 * axes[:, 1])
        for sign in (1.0, -1.0):
            for down in np.vstack([np.eye(3), -np.eye(3)]):
                for k in (0.3, 3.0):
                    out.append(np.r_[sign * in_plane, k, normal,
                                     -GRAVITY * down * duration / 2, direction_angles(down)])
        return out

    @override
    def applied(self, params, cumulative):
        return with_torque(plate_torque(params["p"]), cumulative)


def with_torque(tau, cumulative):
    """The running integral of the command (cumulative) plus that of a torque tau (n, 3) N·m at
    the measured rows (trapezoidal, linear between rows): an input torque added to the model."""
    steps = 0.5 * (tau[1:] + tau[:-1]) * np.diff(Flight.t)[:, None]
    knots = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])

    def added(t):
        return cumulative(t) + np.stack([np.interp(t, Flight.t, knots[:, i]) for i in range(3)], 1)

    return added


@E.register
class SpaceTorque(E.EffectModel):
    """Prototype: a torque fixed in space, changing linearly in time (module docstring)."""

    name, params, size, family = "space_torque", ("p",), 6, "external torque"

    @override
    def typical(self, form, d):
        return np.r_[np.full(3, d.tau_ref), np.full(3, d.tau_ref / max(d.duration, d.dt))]

    @override
    def applied(self, params, cumulative):
        p = params["p"]
        in_space = p[None, :3] + p[None, 3:] * (Flight.t - Flight.t[0])[:, None]
        return with_torque(np.einsum("kji,kj->ki", Flight.rotation, in_space), cumulative)


@E.register
class GyroMatrix(E.EffectModel):
    """Prototype: the gyro reads (I + E) w, E symmetric (diagonal first, then xy, xz, yz)."""

    name, params, size, family = "gyro_matrix", ("e",), 6, "gyro error"

    @override
    def bounds(self, form, d):
        return np.full(6, -0.1), np.full(6, 0.1)

    @override
    def typical(self, form, d):
        return np.full(6, 0.01)

    @override
    def gyro(self, params, w, t):
        e = np.asarray(params["e"], float)
        return w + w @ np.array([[e[0], e[3], e[4]], [e[3], e[1], e[5]], [e[4], e[5], e[2]]])


def zero_command(t) -> np.ndarray:
    """The running integral of no commanded torque (N·m·s, (k, 3) at times t)."""
    return np.zeros((np.atleast_1d(t).size, 3))


class WithPlateInput(F.Data):
    """The prepared record, with a zero command where it has none, so that the torque-input hook
    (EffectModel.applied) that flight_aero uses is called on a gyro-only toss."""

    def inputs(self, grid):
        cumulative, commanded, h = super().inputs(grid)
        return (zero_command if cumulative is None else cumulative), commanded, h


def worst(fit) -> float:
    """Worst-axis rms/noise of a fit."""
    return round(float(np.sqrt(np.mean(fit.z ** 2, axis=0)).max()), 1)


def main() -> None:
    ap = argparse.ArgumentParser()
    data = Path(__file__).resolve().parents[2] / "shared/data/phyphox-racquet"
    ap.add_argument("--data", default=str(data))
    args = ap.parse_args()
    singles = ("flight_aero", "gyro_matrix", "space_torque", "viscous_damping", "internal_momentum")
    rows = []
    for raw in sorted(Path(args.data).glob("round*/*/Raw Data.csv")):
        comments = segment_comments(raw.parent)
        for rec in map(retimed, read_recordings(raw.parent)):
            d = F.prepare(rec)
            nominal = F.fit_nominal(d)
            trim = impulses(d, nominal)
            d = F.prepare(rec, trim)
            d = WithPlateInput(**{f.name: getattr(d, f.name) for f in dataclasses.fields(d)
                                  if f.name != "cache"})
            nominal = F.fit_nominal(d)
            keep = slice(trim[0], rec.t.size - trim[1])
            Flight.set(np.asarray(rec.t, float)[keep], np.asarray(rec.w, float)[keep])
            row = {"toss": f"{raw.parent.parent.name} {rec.name[-9:]}", "rigid": worst(nominal),
                   "flip": "intermediate" in comments.get(rec.meta.get("segment"), "").lower()}
            fits = {name: F.fit_effect(name, d, nominal) for name in singles}
            for name, f in fits.items():
                row[name] = [round(float(nominal.bic - f.bic)), worst(f)]
            drag = fits["viscous_damping"]  # in its best form
            for second in ("flight_aero", "internal_momentum"):
                pair = min((F.fit_model(("viscous_damping", second), (drag.forms[0], form), d, drag)
                            for form in E.REGISTRY[second].forms(d)), key=lambda f: f.bic)
                row["viscous_damping+" + second] = [round(float(nominal.bic - pair.bic)), worst(pair)]
            p = fits["flight_aero"].params["p"]
            row["plate"] = {"arm_m": round(float(np.linalg.norm(arm(p))), 3),
                            "normal": np.round(direction(p[3], p[4]), 2).tolist(),
                            "launch_m_s": round(float(np.linalg.norm(p[5:8])), 2),
                            "gravity_at_start": np.round(direction(p[8], p[9]), 2).tolist()}
            row["best_single"] = max(singles, key=lambda n: row[n][0])
            rows.append(row)
            print(json.dumps(row), flush=True)
    best = [r["best_single"] for r in rows]
    flips = [r["best_single"] for r in rows if r["flip"]]
    pairs = sum(r["viscous_damping+flight_aero"][0] > r["viscous_damping+internal_momentum"][0] for r in rows)
    print(f"best single effect: {({n: best.count(n) for n in singles})}; on the {len(flips)} "
          f"intermediate-axis flips: {({n: flips.count(n) for n in singles})}; viscous_damping+flight_aero "
          f"above viscous_damping+internal_momentum on {pairs}/{len(rows)} tosses")


def segment_comments(export: Path) -> dict[int, str]:
    """Segment number -> the comment meta/segments.csv gives it (what the tosser did)."""
    path = export / "meta" / "segments.csv"
    if not path.exists():
        return {}
    with path.open() as fh:
        return {int(row["segment"]): row.get("comment") or "" for row in csv.DictReader(fh)}


if __name__ == "__main__":
    main()
