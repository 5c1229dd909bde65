"""An independent simulator of a tennis racquet with a phone strapped to it, tossed through air.

It imports nothing of inertia_gym: its own Euler equations, quaternion attitude and the centre of
mass's flight under gravity, integrated by scipy's DOP853 (rtol 1e-10), and its own aerodynamics
by element (strip) theory, which is not of any form in diagnose's catalogue: pressure drag
-rho/2 Cd A (v.n)|v.n| n on each area element of the head (a porous string bed inside a solid
frame band) and of the phone, both plates normal to body z, and cross-flow drag on 40 segments
of the handle, each element's air speed v = v_cm + w x r (the flight's speed included, so the
drag couples the axes and follows the flight). The tests use it to check diagnose on racquet
tosses that the project's own simulator did not make, with an air drag of no form in the
catalogue.

Body frame: x along the handle (butt at x = 0, the head beyond), y across the head, z normal to
it; every moment about the combined centre of mass. The phone's gyro axes are the principal
axes (largest moment first, right-handed) turned 2-8 deg about a random axis; white noise
SIGMA rad/s per axis at 100 Hz, stamps in exact 0.01-s steps from a non-zero start.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

#: kg/m^3, air
RHO = 1.2
#: m/s^2, gravity (z up, inertial)
GRAVITY = np.array([0.0, 0.0, -9.81])
#: rad/s, the gyro's white noise per axis
SIGMA = 2e-3
#: m, the handle and throat as one rod along x from the butt, and its diameter
HANDLE_LENGTH, HANDLE_DIAMETER = 0.36, 0.03
#: m, the head's outer semi-axes (a 0.30 x 0.25 m ellipse) and its centre on x
HEAD_A, HEAD_B = 0.15, 0.125
HEAD_CENTRE = HANDLE_LENGTH + HEAD_A
#: m, the in-plane width of the frame band (solid to the air)
RING_WIDTH = 0.012
#: kg: the frame, the strings, the handle (a 0.30-kg racquet) and the phone
MASS_RING, MASS_STRINGS, MASS_HANDLE, MASS_PHONE = 0.170, 0.020, 0.110, 0.164
#: m, the phone's box (its long side along the handle), its centre on x and on z (on the handle)
PHONE_SIZE = np.array([0.146, 0.072, 0.007])
PHONE_X = 0.12
PHONE_Z = HANDLE_DIAMETER / 2 + PHONE_SIZE[2] / 2
#: drag coefficients of a plate normal to the flow and of a cylinder across it
CD_PLATE, CD_ROD = 1.2, 1.0


def _mass_points() -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) m and masses (N,) kg: the frame as a thin elliptical ring, the strings as
    a uniform membrane inside it, the handle as a line, the phone at its centre (the handle's
    and the phone's own inertia are added in inertia_tensor)."""
    angle = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    a, b = HEAD_A - RING_WIDTH / 2, HEAD_B - RING_WIDTH / 2
    ring = np.c_[HEAD_CENTRE + a * np.cos(angle), b * np.sin(angle), np.zeros(angle.size)]
    arc = np.linalg.norm(np.roll(ring, -1, 0) - ring, axis=1)
    grid = np.linspace(-1, 1, 121)
    gx, gy = np.meshgrid(grid, grid)
    inside = gx ** 2 + gy ** 2 <= 1
    strings = np.c_[HEAD_CENTRE + (HEAD_A - RING_WIDTH) * gx[inside], (HEAD_B - RING_WIDTH) * gy[inside],
                    np.zeros(inside.sum())]
    xs = (np.arange(400) + 0.5) / 400 * HANDLE_LENGTH
    handle = np.c_[xs, np.zeros_like(xs), np.zeros_like(xs)]
    points = np.vstack([ring, strings, handle, [[PHONE_X, 0.0, PHONE_Z]]])
    masses = np.concatenate([MASS_RING * arc / arc.sum(), np.full(len(strings), MASS_STRINGS / len(strings)),
                             np.full(400, MASS_HANDLE / 400), [MASS_PHONE]])
    return points, masses


def inertia_tensor() -> tuple[np.ndarray, np.ndarray, float]:
    """The body's inertia (3, 3) kg·m² about its centre of mass, the centre (3,) m, the mass kg
    (principal moments about 19.9, 18.6, 1.43 g·m²: the pendulum-measured racquet's 20.7, 18.8,
    1.39)."""
    points, masses = _mass_points()
    mass = masses.sum()
    centre = masses @ points / mass
    r = points - centre
    inertia = (masses * (r ** 2).sum(1)).sum() * np.eye(3) - np.einsum("i,ij,ik->jk", masses, r, r)
    radius = HANDLE_DIAMETER / 2
    inertia += MASS_HANDLE * radius ** 2 * np.diag([1 / 2, 1 / 4, 1 / 4])  # a solid rod's own
    length, width, thick = PHONE_SIZE
    inertia += MASS_PHONE / 12 * np.diag([width ** 2 + thick ** 2, length ** 2 + thick ** 2,
                                          length ** 2 + width ** 2])
    return inertia, centre, mass


def _aero_elements(centre, string_share: float):
    """The plates' elements (positions (P, 3) m from the centre of mass, Cd x area (P,) m²; the
    string bed's area counted by string_share, the band and the phone whole) and the handle's
    segments (positions (R, 3) m, Cd x diameter x length (R,) m²)."""
    n = 60
    grid = (np.arange(n) + 0.5) / n * 2 - 1
    gx, gy = np.meshgrid(grid, grid)
    inside = gx ** 2 + gy ** 2 <= 1
    x, y = HEAD_CENTRE + HEAD_A * gx[inside], HEAD_B * gy[inside]
    in_strings = ((x - HEAD_CENTRE) / (HEAD_A - RING_WIDTH)) ** 2 + (y / (HEAD_B - RING_WIDTH)) ** 2 <= 1
    head_area = CD_PLATE * (2 * HEAD_A / n) * (2 * HEAD_B / n) * np.where(in_strings, string_share, 1.0)
    px = PHONE_X + ((np.arange(20) + 0.5) / 20 - 0.5) * PHONE_SIZE[0]
    py = ((np.arange(8) + 0.5) / 8 - 0.5) * PHONE_SIZE[1]
    gpx, gpy = np.meshgrid(px, py)
    phone = np.c_[gpx.ravel(), gpy.ravel(), np.full(gpx.size, PHONE_Z + PHONE_SIZE[2] / 2)]
    plates = np.vstack([np.c_[x, y, np.zeros_like(x)], phone]) - centre
    phone_area = np.full(gpx.size, CD_PLATE * PHONE_SIZE[0] * PHONE_SIZE[1] / gpx.size)
    plate_area = np.concatenate([head_area, phone_area])
    xs = (np.arange(40) + 0.5) / 40 * HANDLE_LENGTH
    rods = np.c_[xs, np.zeros_like(xs), np.zeros_like(xs)] - centre
    return plates, plate_area, rods, np.full(40, CD_ROD * HANDLE_DIAMETER * HANDLE_LENGTH / 40)


def aero(w, v_body, plates, plate_area, rods, rod_area) -> tuple[np.ndarray, np.ndarray]:
    """The air's force N and torque N·m about the centre of mass (body frame, (3,) each) on the
    body turning at w rad/s with its centre moving at v_body m/s (body frame)."""
    normal_speed = (v_body + np.cross(w, plates))[:, 2]
    plate_force = np.zeros_like(plates)
    plate_force[:, 2] = -0.5 * RHO * plate_area * normal_speed * np.abs(normal_speed)
    across = v_body + np.cross(w, rods)
    across[:, 0] = 0.0  # the rod feels only the flow across it
    rod_force = -0.5 * RHO * rod_area[:, None] * np.linalg.norm(across, axis=1)[:, None] * across
    force = plate_force.sum(0) + rod_force.sum(0)
    return force, np.cross(plates, plate_force).sum(0) + np.cross(rods, rod_force).sum(0)


def _rotation(q) -> np.ndarray:
    """Body-to-inertial rotation (3, 3) of the quaternion q (w, x, y, z)."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _state_rate(inertia, mass, elements):
    """The rate of the state (w (3) rad/s body, q (4) body to inertial, v (3) m/s inertial)."""
    inverse = np.linalg.inv(inertia)

    def rate(_, s):
        w, q, v = s[:3], s[3:7], s[7:]
        to_inertial = _rotation(q)
        force, torque = aero(w, to_inertial.T @ v, *elements) if elements else (np.zeros(3), np.zeros(3))
        qw, qv = q[0], q[1:]
        q_rate = 0.5 * np.r_[-qv @ w, qw * w + np.cross(qv, w)]
        w_rate = inverse @ (torque - np.cross(w, inertia @ w))
        return np.r_[w_rate, q_rate, to_inertial @ force / mass + GRAVITY]
    return rate


def simulate_toss(seed: int, kind: str, with_air: bool = True, bias: bool = False) -> tuple[dict, dict]:
    """One toss: kind "flip" (about the intermediate axis, 6-30 rad/s, 1-10 % on the others),
    "handle" or "largest" (a spin about the smallest or the largest moment's axis, 10-25 rad/s,
    1-5 % wobble); 0.8-1.2 s. Returns the recording ({t (n,) s, w (n, 3) rad/s in the phone's
    axes}) and the truth (ratios, drag's size, the phone frame's inertia, ...)."""
    rng = np.random.default_rng(seed)
    inertia, centre, mass = inertia_tensor()
    moments, axes = np.linalg.eigh(inertia)  # ascending: the handle's axis first
    if np.linalg.det(axes) < 0:
        axes[:, 0] *= -1
    smallest, middle, largest = axes.T
    string_share = rng.uniform(0.5, 0.9)
    elements = _aero_elements(centre, string_share) if with_air else None
    main, other1, other2 = {"flip": (middle, smallest, largest), "handle": (smallest, middle, largest),
                            "largest": (largest, middle, smallest)}[kind]
    speed = rng.uniform(6, 30) if kind == "flip" else rng.uniform(10, 25)
    off = rng.uniform(0.01, 0.10 if kind == "flip" else 0.05, 2) * rng.choice([-1, 1], 2)
    w0 = speed * (rng.choice([-1, 1]) * main + off[0] * other1 + off[1] * other2)
    q0 = Rotation.random(random_state=rng.integers(2 ** 31)).as_quat(scalar_first=True)
    launch, elevation, azimuth = rng.uniform(2, 5), np.radians(rng.uniform(30, 80)), rng.uniform(0, 2 * np.pi)
    v0 = launch * np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                            np.sin(elevation)])
    duration = round(rng.uniform(0.8, 1.2), 2)
    t_start = round(rng.uniform(0.5, 5.0), 2)
    t = np.arange(int(round(duration / 0.01)) + 1) * 0.01
    sol = solve_ivp(_state_rate(inertia, mass, elements), (0, t[-1]), np.r_[w0, q0, v0], method="DOP853",
                    t_eval=t, rtol=1e-10, atol=1e-12)
    assert sol.success, sol.message
    w_body = sol.y[:3].T
    turn = Rotation.from_rotvec(np.radians(rng.uniform(2, 8)) * _unit(rng.normal(size=3))).as_matrix()
    principal = np.c_[largest, middle, smallest]
    if np.linalg.det(principal) < 0:  # a phone's axes are right-handed
        principal[:, 2] *= -1
    phone = principal @ turn  # the phone's axes (columns) in the body frame
    offset = rng.uniform(-5e-3, 5e-3, 3) if bias else np.zeros(3)
    w_phone = w_body @ phone + offset + SIGMA * rng.normal(size=w_body.shape)
    momentum = np.linalg.norm(w_body @ inertia, axis=1)
    torque = np.array([np.linalg.norm(aero(w, _rotation(q).T @ v, *elements)[1]) if with_air else 0.0
                       for w, q, v in zip(w_body, sol.y[3:7].T, sol.y[7:].T)])
    truth = {"seed": seed, "kind": kind, "air": with_air, "bias": offset.tolist(),
             "string_share": string_share, "rate": speed, "launch_speed": launch, "duration": float(t[-1]),
             "principal_moments_gm2": (moments[::-1] * 1e3).tolist(),
             "ratios": (moments[::-1] / moments[-1]).tolist(),
             "drag_over_momentum_median": float(np.median(torque / momentum)),
             "momentum_lost": float(1 - momentum[-1] / momentum[0]),
             "inertia_phone_axes": (phone.T @ inertia @ phone).tolist()}
    return {"t": t_start + t, "w": w_phone}, truth


def _unit(v) -> np.ndarray:
    return v / np.linalg.norm(v)


def write_toss(folder: Path, name: str, recording: dict, sidecar: bool = True) -> Path:
    """The toss as a CSV (t,wx,wy,wz) with, where sidecar, a JSON sidecar giving gyro_sigma."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.csv"
    np.savetxt(path, np.c_[recording["t"], recording["w"]], delimiter=",", header="t,wx,wy,wz",
               comments="", fmt=["%.2f", "%.6f", "%.6f", "%.6f"])
    if sidecar:
        (folder / f"{name}.json").write_text(json.dumps({"gyro_sigma": SIGMA}))
    return path
