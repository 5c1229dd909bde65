"""Excitation: the burst law of eq. (18), its direction v, saturation, bounds and schedules.

tau = a (w_hat x v) + b v, held over a burst of T_on seconds, saturated to |tau|_inf <= tau_max by
scaling the whole vector (the direction of the law is kept). v is taken from P_theta as
docs/paper-errata.md proposes: the dominant eigenvector d_theta of P_theta (6x6) is mapped to the symmetric
matrix J(d_theta), and v is that matrix's eigenvector of largest |eigenvalue| (the body axis
whose inertia is least known), with its sign fixed so that its largest component is positive.
"""

from __future__ import annotations

import dataclasses

import numba as nb
import numpy as np

from inertia_gym.errors import ConfigError
from inertia_gym.information import inertia_from_theta
from inertia_gym.scenario import Scenario, steps


def burst_direction(p_theta) -> np.ndarray:
    """Unit burst direction v (3,) from the inertia covariance P_theta (6, 6)."""
    p = np.asarray(p_theta, dtype=float)
    if p.shape != (6, 6) or not np.all(np.isfinite(p)):
        raise ConfigError(f"P_theta must be a finite 6x6 matrix, got shape {p.shape}")
    _, vecs = np.linalg.eigh(0.5 * (p + p.T))
    eigval, eigvec = np.linalg.eigh(inertia_from_theta(vecs[:, -1]))
    v = eigvec[:, int(np.argmax(np.abs(eigval)))]
    return v if v[np.argmax(np.abs(v))] > 0 else -v


def burst_directions(p_thetas, skip) -> np.ndarray:
    """:func:`burst_direction` of each P_theta of the stack p_thetas (B, 6, 6), with the
    eigenproblems of all runs solved as stacks (each matrix exactly as alone); (B, 3). Rows
    where skip (B,) bool is set (diverged runs) get (1, 0, 0) and are not checked.
    """
    p = np.asarray(p_thetas, dtype=float)
    skip = np.asarray(skip, dtype=bool)
    out = np.tile(np.array([1.0, 0.0, 0.0]), (len(p), 1))
    rows = np.flatnonzero(~skip)
    if rows.size == 0:
        return out
    p = p[rows]
    if p.shape[1:] != (6, 6) or not np.all(np.isfinite(p)):
        raise ConfigError(f"P_theta must be finite 6x6 matrices, got shape {p.shape[1:]}")
    _, vecs = np.linalg.eigh(0.5 * (p + p.transpose(0, 2, 1)))
    eigval, eigvec = np.linalg.eigh(inertia_from_theta(vecs[:, :, -1]))
    picked = np.argmax(np.abs(eigval), axis=1)
    v = eigvec[np.arange(len(rows)), :, picked]
    flip = v[np.arange(len(rows)), np.argmax(np.abs(v), axis=1)] > 0
    out[rows] = np.where(flip[:, None], v, -v)
    return out


@nb.njit(cache=True)
def burst_torque_into(a, b, w_hat, v, tau_max, out):
    """Eq. (18) into out (3,): a (w_hat x v) + b v, scaled down to |tau|_inf <= tau_max keeping
    its direction. a N·m·s, b N·m, w_hat rad/s (3,), v unit (3,); allocation-free (the compiled
    closed loop calls it at every burst start).
    """
    for i in range(3):
        out[i] = b * v[i]
    out[0] += a * (w_hat[1] * v[2] - w_hat[2] * v[1])
    out[1] += a * (w_hat[2] * v[0] - w_hat[0] * v[2])
    out[2] += a * (w_hat[0] * v[1] - w_hat[1] * v[0])
    peak = max(abs(out[0]), abs(out[1]), abs(out[2]))
    if peak > tau_max:
        for i in range(3):
            out[i] *= tau_max / peak


def burst_torque(a: float, b: float, w_hat, v, tau_max: float) -> np.ndarray:
    """Eq. (18): a (w_hat x v) + b v, scaled down to |tau|_inf <= tau_max. Shape (3,), N·m."""
    if not tau_max > 0:
        raise ConfigError(f"tau_max must be > 0, got {tau_max}")
    out = np.empty(3)
    burst_torque_into(float(a), float(b), np.asarray(w_hat, dtype=float), np.asarray(v, dtype=float),
                      float(tau_max), out)
    return out


def check_xi(xi, bounds) -> np.ndarray:
    """Validate xi = (a, b, T_on) against bounds (2, 3); returns it as a float array."""
    arr = np.asarray(xi, dtype=float)
    if arr.shape != (3,):
        raise ConfigError(f"xi must be (a, b, T_on), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"xi must be finite, got {arr.tolist()}")
    if arr[2] <= 0:
        raise ConfigError(f"T_on must be > 0 s, got {arr[2]}")
    lo, hi = np.asarray(bounds)[0], np.asarray(bounds)[1]
    tol = 1e-9 * np.maximum(1.0, np.abs(hi))
    names = ("a", "b", "T_on")
    bad = [n for n, x, low, up, t in zip(names, arr, lo, hi, tol) if x < low - t or x > up + t]
    if bad:
        raise ConfigError(
            f"xi = {arr.tolist()} is outside the bounds {np.asarray(bounds).tolist()} in {bad}"
        )
    return arr


@dataclasses.dataclass(frozen=True)
class Schedule:
    """A segment of time steps with bursts: n_steps, and bursts (m, 2) [start, stop) step indices."""

    n_steps: int
    bursts: np.ndarray

    def burst_mask(self) -> np.ndarray:
        """(n_steps,) bool, True where a burst is on."""
        mask = np.zeros(self.n_steps, dtype=bool)
        for b0, b1 in self.bursts:
            mask[b0:b1] = True
        return mask


def episode_schedule(sc: Scenario, t_on: float, rng: np.random.Generator) -> Schedule:
    """One excitation episode: N bursts of T_on, each followed by a dwell drawn from sc.dwell."""
    n_on = steps(t_on, sc.dt)
    bursts, k = [], 0
    for _ in range(sc.bursts_per_episode):
        bursts.append((k, k + n_on))
        k += n_on + steps(rng.uniform(*sc.dwell), sc.dt)
    return Schedule(k, np.array(bursts, dtype=np.int64))


def validation_schedule(sc: Scenario, t_on: float | None, duration: float,
                        rng: np.random.Generator) -> list[Schedule]:
    """Long-horizon validation: coasts drawn from sc.validation_coast, each followed by a burst.

    Returned as one segment per burst (the burst at the segment's start, as in an episode), after
    a leading coast, so the caller can refresh v from P_theta before each burst. With t_on None
    the whole duration is a coast.
    """
    total = steps(duration, sc.dt)
    if t_on is None:
        return [Schedule(total, np.zeros((0, 2), dtype=np.int64))]
    n_on = steps(t_on, sc.dt)
    segments, k = [], 0
    first = min(total, steps(rng.uniform(*sc.validation_coast), sc.dt))
    segments.append(Schedule(first, np.zeros((0, 2), dtype=np.int64)))
    k = first
    while k < total:
        coast = steps(rng.uniform(*sc.validation_coast), sc.dt)
        length = min(total - k, n_on + coast)
        segments.append(Schedule(length, np.array([(0, min(n_on, length))], dtype=np.int64)))
        k += length
    return segments
