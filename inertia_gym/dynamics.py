"""Rigid-body rotational dynamics: Euler's equation with quaternion kinematics.

Convention: q = (q_w, q_x, q_y, q_z), scalar first, rotates body-frame vectors into the
inertial frame (v_I = R(q) v_B); omega is the body rate in the body frame, rad/s.

    J w_dot = tau - w x (J w + h) + tau_dist,     q_dot = 1/2 q (x) (0, w)

The closed-loop truth and the estimators integrate with classical RK4 at dt (quaternion
renormalised each step): at the paper's rate (|w| = 10 rad/s, dt = 0.01 s) its torque-free energy
drift is about 5e-8 over 1000 s, and it is three times cheaper than the alternative. That
alternative, ``method="gauss"``, is the 2-stage Gauss-Legendre collocation method (order 4),
which conserves every quadratic invariant (energy, |J w|^2, |q|^2) exactly: use it for long
torque-free runs or fast spins (|w| dt > 0.2), where RK4's drift grows as (|w| dt)^4.
All kernels are numba-compiled; ``propagate_batch``
advances many trajectories in one call (parallel over the batch).

Extra torques enter through a :class:`Disturbance` (the "hook"): a frozen dataclass packed into a
flat parameter vector that the compiled right-hand side reads.
"""

from __future__ import annotations

import cmath
import dataclasses
import math

import numba as nb
import numpy as np
from numba.extending import overload

from inertia_gym.errors import ConfigError

SQRT3_6 = math.sqrt(3.0) / 6.0

# Layout of the packed disturbance vector.
_D_TAU = slice(0, 3)  # constant body torque, N·m
_D_H = slice(3, 6)  # internal angular momentum (wheel bias), N·m·s
_D_C0, _D_C1 = 6, 15
_D_C = slice(_D_C0, _D_C1)  # viscous damping matrix, row-major, N·m·s
_D_AERO_ON = 15  # 1 when the drag matrix is not zero (one test in the hot loop)
_D_AERO = slice(16, 25)  # aerodynamic drag matrix C in -|w| C w, row-major, N·m·s²
_D_N = 25  # orbital rate for gravity gradient, rad/s
_D_NADIR = slice(26, 29)  # nadir direction in the inertial frame (unit)
# Terms only the augmented integrator (model_dynamics.propagate_model_batch) adds around state_rate:
_D_DISS = 29  # internal dissipation d: torque -d (w - u (u . w)), u along the total momentum, N·m·s
_D_OMEGA, _D_ZETA, _D_DELTA = 30, 31, 32  # flexible mode: omega_n rad/s, zeta, coupling (3,) sqrt(kg)·m
_D_FLEX = slice(_D_OMEGA, _D_DELTA + 3)
_D_ETA0, _D_ETAD0 = 35, 36  # the mode's state at the first segment's start: eta, eta_dot
# the flexible mode's inertia rate K = dJ/d eta (xx, xy, xz, yy, yz, zz), sqrt(kg)·m
_D_K0 = 37
_D_K = slice(_D_K0, _D_K0 + 6)
DISTURBANCE_SIZE = 43


@dataclasses.dataclass(frozen=True)
class Disturbance:
    """Extra torques on the body: the truth simulator's hook for physics beyond eq. (1).

    Attributes
    ----------
    constant_torque : (3,) N·m, body frame.
    internal_momentum : (3,) N·m·s, a stored momentum h (e.g. a wheel) in J w_dot + w x (J w + h).
    damping : (3, 3) N·m·s, viscous torque -C w.
    aero_drag : N·m·s², torque -|w| C w; C a number (isotropic), (3,) per body axis or a (3, 3)
        matrix (a body whose drag differs about its own axes, e.g. a flat plate or a racquet's
        head, in any orientation to the gyro's).
    orbit_rate : rad/s, gravity-gradient torque 3 n^2 (r x J r) with r the nadir in the body frame.
    nadir_inertial : (3,), nadir direction in the inertial frame (normalised internally).
    dissipation : N·m·s, internal dissipation (slosh, dampers): torque -d (w - u (u . w)) with u
        along the total momentum J w + h, so energy decays while |J w + h| is kept. The RK4
        steps apply it; the Gauss-Legendre step (``method="gauss"``) refuses it.
    flex_omega, flex_zeta, flex_coupling : one flexible mode (rad/s, damping ratio, coupling
        delta (3,) sqrt(kg)·m): J w_dot + delta eta_ddot + w x (J w + h + delta eta_dot) = tau,
        eta_ddot + 2 zeta Omega eta_dot + Omega^2 eta = -delta . w_dot. Its state (eta, eta_dot)
        is carried only by the augmented integrator (:func:`model_dynamics.propagate_model_batch`);
        the rigid-body integrators here refuse a coupling.
    flex_eta0, flex_eta_dot0 : the mode's state (sqrt(kg)·m, sqrt(kg)·m/s) where the recording
        starts: a panel or a propellant already moving (zero: at rest).
    flex_inertia_rate : (6,) sqrt(kg)·m, K = dJ/d eta as (xx, xy, xz, yy, yz, zz): the mode
        moves mass, so the body's inertia is J + K eta. From the Lagrangian
        T = w^T J(eta) w / 2 + w^T delta eta_dot + eta_dot^2 / 2, the body's equation becomes
        J(eta) w_dot + K eta_dot w + delta eta_ddot + w x (J(eta) w + h + delta eta_dot) = tau
        and the mode is driven by the centrifugal load w^T K w / 2 (a propellant mass pressed
        outwards by the rotation, a panel bent back by it).

    """

    constant_torque: tuple = (0.0, 0.0, 0.0)
    internal_momentum: tuple = (0.0, 0.0, 0.0)
    damping: tuple = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    aero_drag: float | tuple = 0.0
    orbit_rate: float = 0.0
    nadir_inertial: tuple = (0.0, 0.0, -1.0)
    dissipation: float = 0.0
    flex_omega: float = 0.0
    flex_zeta: float = 0.0
    flex_coupling: tuple = (0.0, 0.0, 0.0)
    flex_eta0: float = 0.0
    flex_eta_dot0: float = 0.0
    flex_inertia_rate: tuple = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def pack(self) -> np.ndarray:
        """Flat float64 vector of length DISTURBANCE_SIZE read by the compiled kernels."""
        return pack_fields({f.name: getattr(self, f.name) for f in dataclasses.fields(self)})


#: Disturbance field -> (its place in the packed vector, its shape); aero_drag and
#: nadir_inertial, which pack_fields converts, are not listed.
_SLOTS = {"constant_torque": (_D_TAU, (3,)), "internal_momentum": (_D_H, (3,)),
          "damping": (_D_C, (3, 3)), "orbit_rate": (_D_N, ()), "dissipation": (_D_DISS, ()),
          "flex_omega": (_D_OMEGA, ()), "flex_zeta": (_D_ZETA, ()),
          "flex_coupling": (slice(_D_DELTA, _D_DELTA + 3), (3,)), "flex_eta0": (_D_ETA0, ()),
          "flex_eta_dot0": (_D_ETAD0, ()), "flex_inertia_rate": (_D_K, (6,))}


def check_rigid_steps(dist: np.ndarray, method: str = "rk4") -> None:
    """Refuse packed disturbances (..., DISTURBANCE_SIZE) that the 7-state steps cannot integrate:
    a flexible mode (its state must be carried from step to step), and with ``method="gauss"``
    an internal dissipation (the Gauss-Legendre rate leaves it out).
    """
    packed = np.asarray(dist)
    if np.any(packed[..., _D_DELTA:_D_DELTA + 3] != 0.0) or np.any(packed[..., _D_K] != 0.0):
        raise ConfigError("a flexible mode (flex_coupling, flex_inertia_rate) needs its state carried "
                          "between steps: integrate it with model_dynamics.propagate_model_batch")
    if method == "gauss" and np.any(np.asarray(dist)[..., _D_DISS] != 0.0):
        raise ConfigError('method="gauss" does not apply an internal dissipation: use "rk4"')


def _no_disturbance() -> np.ndarray:
    v = np.zeros(DISTURBANCE_SIZE)
    v[_D_NADIR] = (0.0, 0.0, -1.0)  # Disturbance's default nadir
    return v


def pack_fields(fields: dict) -> np.ndarray:
    """Disturbance(**fields).pack(), the fields given as a dict (the others at their defaults),
    without building the dataclass: the diagnosis packs one per model it evaluates.
    """
    if not fields:  # most models the diagnosis evaluates: the defaults, one read-only vector
        return _DEFAULTS_PACKED
    v = _no_disturbance()
    for name, value in fields.items():
        if name == "aero_drag":
            aero = np.asarray(value, dtype=float)
            if aero.ndim == 0:
                aero = aero * np.eye(3)
            elif aero.ndim == 1:
                aero = np.diag(_shaped(aero, (3,), name))
            v[_D_AERO] = _shaped(aero, (3, 3), name).ravel()
            v[_D_AERO_ON] = float(np.any(aero != 0.0))
        elif name == "nadir_inertial":
            nadir = _shaped(value, (3,), name)
            norm = np.linalg.norm(nadir)
            if norm == 0:
                raise ConfigError("nadir_inertial must be a non-zero vector")
            with np.errstate(invalid="ignore"):  # a non-finite nadir: reported below
                v[_D_NADIR] = nadir / norm
        elif name in _SLOTS:
            slot, shape = _SLOTS[name]
            v[slot] = _shaped(value, shape, name).ravel() if shape else float(_shaped(value, shape, name))
        else:
            known = sorted([*_SLOTS, "aero_drag", "nadir_inertial"])
            raise ConfigError(f"unknown disturbance term {name!r}; known: {known}")
    if not np.isfinite(v).all():  # one test of the whole vector: it is on the fits' hot path
        bad = next((name for name, value in fields.items()
                    if not np.isfinite(np.asarray(value, float)).all()), "nadir_inertial")
        raise ConfigError(f"{bad} must be finite, got {np.asarray(fields[bad], float).tolist()}")
    return v


def _shaped(value, shape, name) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise ConfigError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


NO_DISTURBANCE = _no_disturbance()
#: The packed defaults again, read-only: what pack_fields gives every model without a term.
_DEFAULTS_PACKED = _no_disturbance()
_DEFAULTS_PACKED.flags.writeable = False


# ------------------------------------------------------------------------------------------
# Small compiled building blocks (quaternions, 3x3 inverses)
# ------------------------------------------------------------------------------------------


def root(x):
    """Square root of a real or complex scalar. The compiled integrator runs on complex states
    for complex-step derivatives (estimation/integrator.py), where the square root must be the
    analytic one; compiled for a real argument it is math.sqrt itself.
    """
    return cmath.sqrt(x) if isinstance(x, complex) else math.sqrt(x)


@overload(root)
def _root_compiled(x):
    if isinstance(x, nb.types.Complex):
        return lambda x: cmath.sqrt(x)
    return lambda x: math.sqrt(x)


@nb.njit(cache=True, error_model="numpy")
def inv3(m):
    """Inverse of a 3x3 matrix by its adjugate (closed form, :func:`inv3_entries`). A singular
    matrix gives non-finite entries, never ZeroDivisionError, whichever kernel compiles it first
    (numba keeps one compilation per argument type, with the error model of its first caller
    unless it has its own): diagnose's model prices a blown-up trajectory and the filters check
    their state for it, both by reading inf or nan.
    """
    e = inv3_entries(mat3_entries(m))
    out = np.empty((3, 3), dtype=m.dtype)
    for k in range(9):
        out[k // 3, k % 3] = e[k]
    return out


def quat_mul(p, q) -> np.ndarray:
    """Hamilton product p (x) q of (..., 4) scalar-first quaternions."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, float), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, float), -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw],
                    axis=-1)


def quat_exp(v) -> np.ndarray:
    """Unit quaternions exp(v/2) (..., 4) of rotation vectors v (..., 3) rad."""
    v = np.asarray(v, dtype=float)
    a = np.linalg.norm(v, axis=-1, keepdims=True)
    small = a < 1e-12
    half = np.where(small, 0.5 / np.sqrt(1 + 0.25 * a * a), np.sin(a / 2) / np.where(small, 1.0, a))
    scalar = np.where(small, 1.0 / np.sqrt(1 + 0.25 * a * a), np.cos(a / 2))
    return np.concatenate([scalar, half * v], axis=-1)


@nb.njit(cache=True)
def quat_to_rotation(q):
    """Rotation matrix R(q), body to inertial, of a unit quaternion (scalar first)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r = np.empty((3, 3))
    r[0, 0] = 1 - 2 * (y * y + z * z)
    r[0, 1] = 2 * (x * y - w * z)
    r[0, 2] = 2 * (x * z + w * y)
    r[1, 0] = 2 * (x * y + w * z)
    r[1, 1] = 1 - 2 * (x * x + z * z)
    r[1, 2] = 2 * (y * z - w * x)
    r[2, 0] = 2 * (x * z - w * y)
    r[2, 1] = 2 * (y * z + w * x)
    r[2, 2] = 1 - 2 * (x * x + y * y)
    return r


def skew(v) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices [v]x, with [v]x u = v x u."""
    v = np.asarray(v, float)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def euler_to_quat(roll_pitch_yaw_deg) -> np.ndarray:
    """Quaternion (scalar first) of ZYX Euler angles in degrees: q = qz(yaw) qy(pitch) qx(roll)."""
    r, p, y = np.radians(np.asarray(roll_pitch_yaw_deg, dtype=float)) / 2
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


# ------------------------------------------------------------------------------------------
# Right-hand side and integrators
# ------------------------------------------------------------------------------------------
# The small kernels below carry forceinline: LLVM inlines them into their callers, so a loop
# over lanes sees straight-line code and vectorises. numba's own inline="always" would do the
# same at the cost of copying the callee's IR at every call site, which multiplies the loop's
# compile time by about two and a half.


@nb.njit(cache=True, forceinline=True)
def mat3_entries(m):
    """The entries of a 3x3 matrix as a row-major 9-tuple, the form :func:`body_rate` reads."""
    return (m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1], m[2, 2])


@nb.njit(cache=True, forceinline=True)
def body_rate(qw, qx, qy, qz, wx, wy, wz, j, j_inv, tau, dist):
    """(q_dot, w_dot) of the state (q, w) given as seven scalars; returns a 7-tuple.

    j, j_inv : the inertia (kg·m²) and its inverse as row-major 9-sequences; tau (3,) N·m;
    dist (DISTURBANCE_SIZE,) the packed :class:`Disturbance` (arrays or tuples). Scalars in,
    scalars out, so that the integrators keep their stages in registers (an RK4 step costs
    about 60 ns instead of 300 ns through scratch arrays) and a loop over runs vectorizes
    (simulation.py).
    """
    return body_rate_with(qw, qx, qy, qz, wx, wy, wz, j, j_inv, tau[0], tau[1], tau[2],
                          dist[3], dist[4], dist[5], dist)


@nb.njit(cache=True, forceinline=True)
def body_rate_with(qw, qx, qy, qz, wx, wy, wz, j, j_inv, tx, ty, tz, sx, sy, sz, dist):
    """:func:`body_rate` with the torque (tx, ty, tz) N·m and the stored momentum (sx, sy, sz)
    kg·m²/s as scalars, in place of tau and of dist's momentum slots (which it does not read):
    a caller that varies them per stage passes registers, not a scratch array.
    """
    dqw = 0.5 * (-qx * wx - qy * wy - qz * wz)
    dqx = 0.5 * (qw * wx + qy * wz - qz * wy)
    dqy = 0.5 * (qw * wy - qx * wz + qz * wx)
    dqz = 0.5 * (qw * wz + qx * wy - qy * wx)
    hx = j[0] * wx + j[1] * wy + j[2] * wz + sx
    hy = j[3] * wx + j[4] * wy + j[5] * wz + sy
    hz = j[6] * wx + j[7] * wy + j[8] * wz + sz
    mx = tx + dist[0] - (wy * hz - wz * hy)
    my = ty + dist[1] - (wz * hx - wx * hz)
    mz = tz + dist[2] - (wx * hy - wy * hx)
    if dist[15] != 0.0:
        nw = root(wx * wx + wy * wy + wz * wz)
        mx -= nw * (dist[16] * wx + dist[17] * wy + dist[18] * wz)
        my -= nw * (dist[19] * wx + dist[20] * wy + dist[21] * wz)
        mz -= nw * (dist[22] * wx + dist[23] * wy + dist[24] * wz)
    mx -= dist[6] * wx + dist[7] * wy + dist[8] * wz
    my -= dist[9] * wx + dist[10] * wy + dist[11] * wz
    mz -= dist[12] * wx + dist[13] * wy + dist[14] * wz
    n = dist[25]
    if n != 0.0:
        # Nadir in the body frame: r_B = R(q)^T r_I.
        ix, iy, iz = dist[26], dist[27], dist[28]
        rx = (1 - 2 * (qy * qy + qz * qz)) * ix + 2 * (qx * qy + qw * qz) * iy \
            + 2 * (qx * qz - qw * qy) * iz
        ry = 2 * (qx * qy - qw * qz) * ix + (1 - 2 * (qx * qx + qz * qz)) * iy \
            + 2 * (qy * qz + qw * qx) * iz
        rz = 2 * (qx * qz + qw * qy) * ix + 2 * (qy * qz - qw * qx) * iy \
            + (1 - 2 * (qx * qx + qy * qy)) * iz
        jx = j[0] * rx + j[1] * ry + j[2] * rz
        jy = j[3] * rx + j[4] * ry + j[5] * rz
        jz = j[6] * rx + j[7] * ry + j[8] * rz
        g = 3.0 * n * n
        mx += g * (ry * jz - rz * jy)
        my += g * (rz * jx - rx * jz)
        mz += g * (rx * jy - ry * jx)
    dwx = j_inv[0] * mx + j_inv[1] * my + j_inv[2] * mz
    dwy = j_inv[3] * mx + j_inv[4] * my + j_inv[5] * mz
    dwz = j_inv[6] * mx + j_inv[7] * my + j_inv[8] * mz
    return dqw, dqx, dqy, dqz, dwx, dwy, dwz


@nb.njit(cache=True, forceinline=True)
def state_rate(qw, qx, qy, qz, wx, wy, wz, inertia, inertia_inv, tau, dist):
    """(q_dot, w_dot) of the state (q, w) given as seven scalars; returns a 7-tuple.

    inertia, inertia_inv : (3, 3) kg·m² and its inverse; tau (3,) N·m; dist (DISTURBANCE_SIZE,)
    packed disturbance. :func:`body_rate` with the matrices as entries.
    """
    return body_rate(qw, qx, qy, qz, wx, wy, wz, mat3_entries(inertia), mat3_entries(inertia_inv),
                     tau, dist)


@nb.njit(cache=True)
def _state_rate_into(y, inertia, inertia_inv, tau, dist, out):
    """Write (q_dot, w_dot) of y = (q, w) into out, shape (7,); allocation-free."""
    rate = state_rate(y[0], y[1], y[2], y[3], y[4], y[5], y[6], inertia, inertia_inv, tau, dist)
    for i in range(7):
        out[i] = rate[i]


@nb.njit(cache=True)
def _normalize_quat(y):
    s = 1.0 / math.sqrt(y[0] ** 2 + y[1] ** 2 + y[2] ** 2 + y[3] ** 2)
    for i in range(4):
        y[i] *= s


@nb.njit(cache=True)
def gauss_legendre_step_into(y, dt, inertia, inertia_inv, tau, dist, out, work, warm=False):
    """One order-4 Gauss-Legendre step of y = (q, w), shape (7,), into out (torque held).

    The implicit stages are solved by fixed-point iteration to round-off (|h w| < 1 makes it a
    contraction); the result keeps quadratic invariants (energy, |J w|, |q|) exactly.
    ``work`` is scratch of shape (4, 7); with ``warm`` its first two rows hold the previous
    step's stage slopes, extrapolated along the collocation polynomial as the first guess
    (saves about two iterations per step on a smooth trajectory).
    """
    a11, a12 = 0.25, 0.25 - SQRT3_6
    a21, a22 = 0.25 + SQRT3_6, 0.25
    k1, k2, ys = work[0], work[1], work[2]
    if warm:
        # Stage times c1, c2 = 1/2 -+ sqrt(3)/6; slope line through (c1, k1), (c2, k2)
        # evaluated at 1 + c1 and 1 + c2 (the next step's stages).
        e1 = 1.0 / (2.0 * SQRT3_6)
        for i in range(7):
            slope = (k2[i] - k1[i]) * e1
            k1[i] = k1[i] + slope
            k2[i] = k2[i] + slope
    else:
        # Explicit predictor: stage slopes from Euler steps to the stage times.
        _state_rate_into(y, inertia, inertia_inv, tau, dist, k1)
        for i in range(7):
            ys[i] = y[i] + (0.5 + SQRT3_6) * dt * k1[i]
        _state_rate_into(ys, inertia, inertia_inv, tau, dist, k2)
        for i in range(7):
            ys[i] = y[i] + (0.5 - SQRT3_6) * dt * k1[i]
        _state_rate_into(ys, inertia, inertia_inv, tau, dist, k1)
    scale = 1e-13 * (1.0 + abs(y[4]) + abs(y[5]) + abs(y[6]))
    for _ in range(60):
        change = 0.0
        for i in range(7):
            ys[i] = y[i] + dt * (a11 * k1[i] + a12 * k2[i])
        knew = work[3]
        _state_rate_into(ys, inertia, inertia_inv, tau, dist, knew)
        for i in range(7):
            change = max(change, abs(knew[i] - k1[i]))
            k1[i] = knew[i]
        for i in range(7):
            ys[i] = y[i] + dt * (a21 * k1[i] + a22 * k2[i])
        _state_rate_into(ys, inertia, inertia_inv, tau, dist, knew)
        for i in range(7):
            change = max(change, abs(knew[i] - k2[i]))
            k2[i] = knew[i]
        if change * dt <= scale:
            break
    for i in range(7):
        out[i] = y[i] + 0.5 * dt * (k1[i] + k2[i])
    _normalize_quat(out)


@nb.njit(cache=True)
def gauss_legendre_step(y, dt, inertia, inertia_inv, tau, dist):
    """Allocating wrapper of :func:`gauss_legendre_step_into`; returns the new (7,) state."""
    out = np.empty(7)
    gauss_legendre_step_into(y, dt, inertia, inertia_inv, tau, dist, out, np.empty((4, 7)))
    return out


@nb.njit(cache=True, forceinline=True)
def augmented_rate(y0, y1, y2, y3, w0, w1, w2, eta, etad, j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz,
                   hx, hy, hz, dist, modal):
    """Rates (9-tuple) of (q (4), w (3), eta, eta_dot): body_rate with the momentum
    (hx, hy, hz) + delta eta_dot added to its hook's and the torque (tx, ty, tz) (N·m, known h_dot
    already subtracted) plus the dissipation torque; a flexible mode then solves J w_dot + delta
    eta_ddot = J a together with eta_ddot + 2 zeta Omega eta_dot + Omega^2 eta = w^T K w / 2
    - delta . w_dot in closed form (jd = J^-1 delta, denom = 1 - delta . J^-1 delta), J being
    J + K eta and the torque less K eta_dot w where the mode's inertia rate K is not zero
    (Disturbance.flex_inertia_rate). Scalars in and out: j and
    j_inv row-major 9-tuples, dist the packed disturbance as a tuple (disturbance_entries).
    modal False: the mode's terms are left out (the rigid body; inlined with a literal False,
    the compiler drops them, so the rigid step costs what a 7-state step costs).
    """
    cx, cy, cz = dist[_D_DELTA], dist[_D_DELTA + 1], dist[_D_DELTA + 2]
    sx, sy, sz = dist[3] + hx, dist[4] + hy, dist[5] + hz
    force = 0.0  # the centrifugal load on the mode, w^T K w / 2
    loaded = False
    if modal:
        sx += cx * etad
        sy += cy * etad
        sz += cz * etad
        kxx, kxy, kxz = dist[_D_K0], dist[_D_K0 + 1], dist[_D_K0 + 2]
        kyy, kyz, kzz = dist[_D_K0 + 3], dist[_D_K0 + 4], dist[_D_K0 + 5]
        loaded = kxx != 0.0 or kxy != 0.0 or kxz != 0.0 or kyy != 0.0 or kyz != 0.0 or kzz != 0.0
        if loaded:
            # the mode moves mass: J(eta) = J + K eta, whose rate K eta_dot w joins the torque
            j = (j[0] + kxx * eta, j[1] + kxy * eta, j[2] + kxz * eta, j[3] + kxy * eta, j[4] + kyy * eta,
                 j[5] + kyz * eta, j[6] + kxz * eta, j[7] + kyz * eta, j[8] + kzz * eta)
            j_inv = inv3_entries(j)
            jd0, jd1, jd2, denom = modal_coupling(j_inv, dist)
            kw0 = kxx * w0 + kxy * w1 + kxz * w2
            kw1 = kxy * w0 + kyy * w1 + kyz * w2
            kw2 = kxz * w0 + kyz * w1 + kzz * w2
            tx -= etad * kw0
            ty -= etad * kw1
            tz -= etad * kw2
            force = 0.5 * (w0 * kw0 + w1 * kw1 + w2 * kw2)
    diss = dist[_D_DISS]
    if diss != 0.0:
        lx = j[0] * w0 + j[1] * w1 + j[2] * w2 + sx
        ly = j[3] * w0 + j[4] * w1 + j[5] * w2 + sy
        lz = j[6] * w0 + j[7] * w1 + j[8] * w2 + sz
        nl = root(lx * lx + ly * ly + lz * lz)
        if nl.real > 0.0:
            ux, uy, uz = lx / nl, ly / nl, lz / nl
            uw = ux * w0 + uy * w1 + uz * w2
            tx -= diss * (w0 - ux * uw)
            ty -= diss * (w1 - uy * uw)
            tz -= diss * (w2 - uz * uw)
    r = body_rate_with(y0, y1, y2, y3, w0, w1, w2, j, j_inv, tx, ty, tz, sx, sy, sz, dist)
    ax, ay, az = r[4], r[5], r[6]
    eta_dd = 0.0
    if modal and (cx != 0.0 or cy != 0.0 or cz != 0.0 or loaded):
        om = dist[_D_OMEGA]
        eta_dd = (force - 2.0 * dist[_D_ZETA] * om * etad - om * om * eta
                  - (cx * ax + cy * ay + cz * az)) / denom
        ax -= jd0 * eta_dd
        ay -= jd1 * eta_dd
        az -= jd2 * eta_dd
    return r[0], r[1], r[2], r[3], ax, ay, az, etad, eta_dd


@nb.njit(cache=True, forceinline=True, error_model="numpy")
def inv3_entries(j):
    """The inverse of a 3x3 matrix given and returned as row-major 9-tuples, by its adjugate
    (closed form): a loop that changes the matrix per stage keeps it in registers. A singular
    matrix gives non-finite entries (as :func:`inv3`).
    """
    c0 = j[4] * j[8] - j[5] * j[7]
    c1 = j[5] * j[6] - j[3] * j[8]
    c2 = j[3] * j[7] - j[4] * j[6]
    det = j[0] * c0 + j[1] * c1 + j[2] * c2
    return (c0 / det, (j[2] * j[7] - j[1] * j[8]) / det, (j[1] * j[5] - j[2] * j[4]) / det,
            c1 / det, (j[0] * j[8] - j[2] * j[6]) / det, (j[2] * j[3] - j[0] * j[5]) / det,
            c2 / det, (j[1] * j[6] - j[0] * j[7]) / det, (j[0] * j[4] - j[1] * j[3]) / det)


@nb.njit(cache=True, forceinline=True)
def modal_coupling(j_inv, dist):
    """(J^-1 delta (3 scalars), 1 - delta . J^-1 delta) of j_inv (9-tuple) and dist (tuple)."""
    cx, cy, cz = dist[_D_DELTA], dist[_D_DELTA + 1], dist[_D_DELTA + 2]
    jd0 = j_inv[0] * cx + j_inv[1] * cy + j_inv[2] * cz
    jd1 = j_inv[3] * cx + j_inv[4] * cy + j_inv[5] * cz
    jd2 = j_inv[6] * cx + j_inv[7] * cy + j_inv[8] * cz
    return jd0, jd1, jd2, 1.0 - (cx * jd0 + cy * jd1 + cz * jd2)


@nb.njit(cache=True, forceinline=True)
def rk4_augmented(y, dt, j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz, ha0, ha1, ha2, hb0, hb1, hb2,
                  dist, modal=True):
    """One RK4 step of y (9-tuple) over dt, the known momentum linear from (ha) to (hb) and
    the torque (tx, ty, tz) (its rate already subtracted) held; returns the new 9-tuple with
    the quaternion renormalised (modal: as for :func:`augmented_rate`). The state stays in
    registers: carried in an array, every store to it could alias the inputs and forced their
    loads again (2.2x slower).
    """
    hdt = 0.5 * dt
    hm0, hm1, hm2 = 0.5 * (ha0 + hb0), 0.5 * (ha1 + hb1), 0.5 * (ha2 + hb2)
    y0, y1, y2, y3, y4, y5, y6, y7, y8 = y
    k1 = augmented_rate(y0, y1, y2, y3, y4, y5, y6, y7, y8, j, j_inv, jd0, jd1, jd2, denom,
                         tx, ty, tz, ha0, ha1, ha2, dist, modal)
    k2 = augmented_rate(y0 + hdt * k1[0], y1 + hdt * k1[1], y2 + hdt * k1[2], y3 + hdt * k1[3],
                         y4 + hdt * k1[4], y5 + hdt * k1[5], y6 + hdt * k1[6], y7 + hdt * k1[7],
                         y8 + hdt * k1[8], j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz, hm0, hm1, hm2,
                         dist, modal)
    k3 = augmented_rate(y0 + hdt * k2[0], y1 + hdt * k2[1], y2 + hdt * k2[2], y3 + hdt * k2[3],
                         y4 + hdt * k2[4], y5 + hdt * k2[5], y6 + hdt * k2[6], y7 + hdt * k2[7],
                         y8 + hdt * k2[8], j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz, hm0, hm1, hm2,
                         dist, modal)
    k4 = augmented_rate(y0 + dt * k3[0], y1 + dt * k3[1], y2 + dt * k3[2], y3 + dt * k3[3],
                         y4 + dt * k3[4], y5 + dt * k3[5], y6 + dt * k3[6], y7 + dt * k3[7],
                         y8 + dt * k3[8], j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz, hb0, hb1, hb2,
                         dist, modal)
    c6 = dt / 6.0
    o0 = y0 + c6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
    o1 = y1 + c6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
    o2 = y2 + c6 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])
    o3 = y3 + c6 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3])
    s = 1.0 / root(o0 ** 2 + o1 ** 2 + o2 ** 2 + o3 ** 2)
    return (o0 * s, o1 * s, o2 * s, o3 * s,
            y4 + c6 * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4]),
            y5 + c6 * (k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5]),
            y6 + c6 * (k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6]),
            y7 + c6 * (k1[7] + 2.0 * k2[7] + 2.0 * k3[7] + k4[7]),
            y8 + c6 * (k1[8] + 2.0 * k2[8] + 2.0 * k3[8] + k4[8]))


@nb.njit(cache=True, forceinline=True)
def rk4_state(y, dt, j, j_inv, tau, dist):
    """One classical RK4 step of the rigid body y = (q, w), a 7-tuple, torque held; returns the
    new 7-tuple with the quaternion renormalised. j, j_inv, tau, dist as for :func:`body_rate`.

    It is :func:`rk4_augmented` without the modal state and with no known momentum beyond
    dist's. A flexible mode needs its state carried from step to step, which a 7-state step
    cannot hold: the callers refuse a coupling (:func:`check_rigid_steps`).
    """
    new = rk4_augmented((y[0], y[1], y[2], y[3], y[4], y[5], y[6], 0.0, 0.0), dt, j, j_inv,
                        0.0, 0.0, 0.0, 1.0, tau[0], tau[1], tau[2], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                        dist, False)
    return new[0], new[1], new[2], new[3], new[4], new[5], new[6]


@nb.njit(cache=True)
def rk4_step_into(y, dt, inertia, inertia_inv, tau, dist, out):
    """One classical RK4 step of (q, w) = y[0:7] into out[0:7] (torque held over the step).

    Only the first seven entries are read and written, and y is read in full before out is
    written, so ``out`` may be ``y`` (an in-place step) or a longer state vector such as the
    filter's (q, w, phi). inertia, inertia_inv (3, 3); see :func:`rk4_state`.
    """
    new = rk4_state((y[0], y[1], y[2], y[3], y[4], y[5], y[6]), dt, mat3_entries(inertia),
                    mat3_entries(inertia_inv), tau, dist)
    for i in range(7):
        out[i] = new[i]


@nb.njit(cache=True, forceinline=True)
def disturbance_entries(d):
    """The packed disturbance d (DISTURBANCE_SIZE,) as a tuple: values a loop over runs keeps in
    registers. Every slot is copied, including those only the augmented integrator reads.
    """
    return (d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7], d[8], d[9], d[10], d[11], d[12],
            d[13], d[14], d[15], d[16], d[17], d[18], d[19], d[20], d[21], d[22], d[23], d[24],
            d[25], d[26], d[27], d[28], d[29], d[30], d[31], d[32], d[33], d[34], d[35], d[36],
            d[37], d[38], d[39], d[40], d[41], d[42])


# disturbance_entries spells out every slot of the packed vector.
assert DISTURBANCE_SIZE == 43, "update disturbance_entries to the new DISTURBANCE_SIZE"


@nb.njit(cache=True, forceinline=True)
def lane_entries9(a, lane):
    """Column `lane` of a (9, L) lane array as a 9-tuple."""
    return (a[0, lane], a[1, lane], a[2, lane], a[3, lane], a[4, lane], a[5, lane], a[6, lane],
            a[7, lane], a[8, lane])


@nb.njit(cache=True, forceinline=True)
def rk4_lanes(y, j, j_inv, tau, dist, dt, on):
    """One RK4 step of (q, w) = y[0:7, l] for every lane l with on[l] (the others unchanged).

    Lanes are runs laid out along the last axis: y (>= 7, L), j and j_inv (9, L) row-major
    inertia (kg·m²) and inverse per lane, tau (3, L) N·m, on (L,) 1.0 / 0.0; dist the packed
    disturbance shared by all lanes, as a tuple. Each lane computes exactly what
    :func:`rk4_step_into` computes for it. Inlined into a kernel whose lane arrays are views of
    one array of constant shape (so the compiler sees they cannot overlap), the loop over
    lanes runs as SIMD instructions (one lane per vector slot).
    """
    for lane in range(y.shape[1]):
        new = rk4_state((y[0, lane], y[1, lane], y[2, lane], y[3, lane], y[4, lane], y[5, lane],
                         y[6, lane]), dt, lane_entries9(j, lane), lane_entries9(j_inv, lane),
                        (tau[0, lane], tau[1, lane], tau[2, lane]), dist)
        keep = on[lane] == 0.0
        y[0, lane] = y[0, lane] if keep else new[0]
        y[1, lane] = y[1, lane] if keep else new[1]
        y[2, lane] = y[2, lane] if keep else new[2]
        y[3, lane] = y[3, lane] if keep else new[3]
        y[4, lane] = y[4, lane] if keep else new[4]
        y[5, lane] = y[5, lane] if keep else new[5]
        y[6, lane] = y[6, lane] if keep else new[6]


@nb.njit(cache=True)
def _propagate_into(y0, torque, dt, inertia, dist, gauss, out):
    inertia_inv = inv3(inertia)
    work = np.empty((4, 7))
    for i in range(7):
        out[0, i] = y0[i]
    for k in range(torque.shape[0]):
        if gauss:
            gauss_legendre_step_into(out[k], dt, inertia, inertia_inv, torque[k], dist,
                                     out[k + 1], work, k > 0)
        else:
            rk4_step_into(out[k], dt, inertia, inertia_inv, torque[k], dist, out[k + 1])


@nb.njit(cache=True, parallel=True)
def _propagate_batch(y0, torque, dt, inertia, dist, gauss, out):
    for b in nb.prange(y0.shape[0]):
        _propagate_into(y0[b], torque[b], dt, inertia[b], dist[b], gauss, out[b])


INTEGRATORS = ("rk4", "gauss")


def propagate_batch(q0, omega0, inertia, torque, dt, disturbance=None, method="rk4"):
    """Integrate many trajectories at once.

    Parameters
    ----------
    q0 : (B, 4) initial unit quaternions.  omega0 : (B, 3) rad/s.
    inertia : (B, 3, 3) or (3, 3) kg·m².  torque : (B, n, 3) N·m, held over each step.
    dt : step, s.  disturbance : Disturbance, (B, DISTURBANCE_SIZE) packed vectors, or None.
    method : "rk4" (the closed-loop truth's integrator) or "gauss" (order-4 Gauss-Legendre,
    which keeps energy and momentum exactly: for long torque-free runs or fast spins).

    Returns
    -------
    q : (B, n+1, 4), omega : (B, n+1, 3) — the states at t = 0, dt, ..., n dt.

    """
    q0 = np.atleast_2d(np.asarray(q0, dtype=float))
    omega0 = np.atleast_2d(np.asarray(omega0, dtype=float))
    batch = q0.shape[0]
    torque = np.asarray(torque, dtype=float)
    if torque.ndim != 3 or torque.shape[0] != batch or torque.shape[2] != 3:
        raise ConfigError(f"torque must have shape (B={batch}, n, 3), got {torque.shape}")
    if q0.shape != (batch, 4) or omega0.shape != (batch, 3):
        raise ConfigError(f"q0 must be (B, 4) and omega0 (B, 3), got {q0.shape}, {omega0.shape}")
    if method not in INTEGRATORS:
        raise ConfigError(f"method must be one of {INTEGRATORS}, got {method!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt must be a positive finite number of seconds, got {dt}")
    inertia = np.broadcast_to(np.asarray(inertia, dtype=float), (batch, 3, 3)).copy()
    if disturbance is None:
        dist = np.tile(NO_DISTURBANCE, (batch, 1))
    elif isinstance(disturbance, Disturbance):
        dist = np.tile(disturbance.pack(), (batch, 1))
    else:
        dist = np.broadcast_to(np.asarray(disturbance, float), (batch, DISTURBANCE_SIZE)).copy()
    for arr, name in ((q0, "q0"), (omega0, "omega0"), (inertia, "inertia"), (torque, "torque")):
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"{name} must be finite")
    check_rigid_steps(dist, method)
    y0 = np.concatenate([q0 / np.linalg.norm(q0, axis=1, keepdims=True), omega0], axis=1)
    out = np.empty((batch, torque.shape[1] + 1, 7))
    _propagate_batch(y0, torque, float(dt), inertia, dist, method == "gauss", out)
    return out[..., :4], out[..., 4:]


def propagate(q0, omega0, inertia, torque, dt, disturbance=None, method="rk4"):
    """Integrate one trajectory: torque (n, 3) -> q (n+1, 4), omega (n+1, 3). See propagate_batch."""
    q, w = propagate_batch(
        np.asarray(q0, float)[None], np.asarray(omega0, float)[None], inertia,
        np.asarray(torque, float)[None], dt,
        disturbance if disturbance is None or isinstance(disturbance, Disturbance)
        else np.asarray(disturbance)[None],
        method,
    )
    return q[0], w[0]
