"""Scale-separated log-Cholesky parameterisation of the inertia.

    J(phi) = exp(s) L L^T,   L = [[1, 0, 0], [l10, exp(g1), 0], [l20, l21, exp(g2)]]
    phi = (s, l10, g1, l20, l21, g2)

J is symmetric positive definite for every phi, and every SPD J has exactly one phi
(s = log Jxx, L the Cholesky factor of J / Jxx). The first coordinate is the pure scale: J -> cJ
is s -> s + log c with the shape untouched. Torque-free motion does not depend on the scale, so
the filters' Jacobian along s is exactly -J^-1 tau: with no torque the scale is never updated and
its variance stays at the prior, which is how the tool can say "scale not identified" instead
of printing a confident wrong number. Covariances map to theta = (Jxx, Jxy, Jxz, Jyy, Jyz, Jzz)
with D = d theta / d phi (delta method); D[:, 0] = theta.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy import optimize

from inertia_gym.errors import ConfigError

#: Upper bounds of |phi| a fit may reach (the log entries; the others are free): within them
#: exp() and its squares stay finite, and no body's moments differ by e^30.
PHI_BOUND = np.array([100.0, np.inf, 30.0, np.inf, np.inf, 30.0])
#: An inertia whose largest principal moment exceeds the sum of the other two by at most this
#: share counts as on the limit of the bodies that exist (a flat plate), not beyond it: one
#: tolerance for the fits' face (realizable_face), a filter's projected estimate
#: (filters.realizable_estimate) and the commands' check (check_physical_inertia).
REALIZABLE_TOLERANCE = 1e-6


@nb.njit(cache=True)
def theta_into(phi, out):
    """Theta (6,) of eq. (8) from phi (6,) into out (6,); allocation-free."""
    c, l10, e1, l20, l21, e2 = math.exp(phi[0]), phi[1], math.exp(phi[2]), phi[3], phi[4], \
        math.exp(phi[5])
    out[0] = c
    out[1] = c * l10
    out[2] = c * l20
    out[3] = c * (l10 * l10 + e1 * e1)
    out[4] = c * (l10 * l20 + e1 * l21)
    out[5] = c * (l20 * l20 + l21 * l21 + e2 * e2)


@nb.njit(cache=True)
def theta_from_phi(phi):
    """Theta (6,) of eq. (8) from phi (6,)."""
    out = np.empty(6)
    theta_into(phi, out)
    return out


@nb.njit(cache=True)
def inertia_norm_sq(theta):
    """||J||_F^2 of the symmetric inertia with entries theta (6,): off-diagonals count twice."""
    return theta[0] ** 2 + theta[3] ** 2 + theta[5] ** 2 \
        + 2.0 * (theta[1] ** 2 + theta[2] ** 2 + theta[4] ** 2)


@nb.njit(cache=True)
def dtheta_dphi(phi):
    """Jacobian D[i, j] = d theta_i / d phi_j, shape (6, 6)."""
    c, l10, e1, l20, l21, e2 = math.exp(phi[0]), phi[1], math.exp(phi[2]), phi[3], phi[4], \
        math.exp(phi[5])
    d = np.zeros((6, 6))
    theta = theta_from_phi(phi)
    for i in range(6):
        d[i, 0] = theta[i]
    d[1, 1] = c
    d[2, 3] = c
    d[3, 1] = 2 * c * l10
    d[3, 2] = 2 * c * e1 * e1
    d[4, 1] = c * l20
    d[4, 2] = c * e1 * l21
    d[4, 3] = c * l10
    d[4, 4] = c * e1
    d[5, 3] = 2 * c * l20
    d[5, 4] = 2 * c * l21
    d[5, 5] = 2 * c * e2 * e2
    return d


@nb.njit(cache=True)
def inertia_from_phi(phi):
    """J(phi), shape (3, 3), kg·m²."""
    t = theta_from_phi(phi)
    j = np.empty((3, 3))
    j[0, 0], j[0, 1], j[0, 2] = t[0], t[1], t[2]
    j[1, 0], j[1, 1], j[1, 2] = t[1], t[3], t[4]
    j[2, 0], j[2, 1], j[2, 2] = t[2], t[4], t[5]
    return j


def phi_from_inertia(inertia) -> np.ndarray:
    """Phi (6,) of a symmetric positive definite inertia (3, 3)."""
    j = np.asarray(inertia, dtype=float)
    try:
        low = np.linalg.cholesky(j / j[0, 0])
    except np.linalg.LinAlgError as exc:
        raise ConfigError(f"inertia is not positive definite: {j.tolist()}") from exc
    if not j[0, 0] > 0:
        raise ConfigError(f"inertia is not positive definite: {j.tolist()}")
    return np.array(
        [np.log(j[0, 0]), low[1, 0], np.log(low[1, 1]), low[2, 0], low[2, 1], np.log(low[2, 2])]
    )


def decouple_scale(cov_phi: np.ndarray) -> np.ndarray:
    """Zero the covariance between the scale s and the shape: a prior or process noise that
    correlates them would let torque-free data move the unobservable scale.
    """
    out = np.array(cov_phi, dtype=float, copy=True)
    out[..., 0, 1:] = 0.0
    out[..., 1:, 0] = 0.0
    return out


def nearest_realizable(inertia) -> np.ndarray:
    """The inertia (3, 3) kg·m² nearest to a symmetric one that a body can have: each principal
    moment at most the sum of the other two (J = trace(S) I - S for a mass distribution's second
    moment S >= 0; equality only for a flat plate). Where that holds it is the inertia itself;
    otherwise its moments are moved, least squares with its principal axes kept, onto the
    nearest flat plate's: (1, 0.45, 0.05) becomes (5/6, 37/60, 13/60). A fit projected on it
    cannot end where no body is, as unprojected fits of racquet tosses do (the largest moment
    0.04-3.9 % beyond the limit, pulled there by what the model leaves out).
    """
    j = np.asarray(inertia, dtype=float)
    j = 0.5 * (j + j.T)
    moments, axes = np.linalg.eigh(j)
    if moments[2] <= moments[0] + moments[1]:
        return j
    pairs = np.ones((3, 3)) - np.eye(3)  # moment i is the sum of S's other two principal values
    second = optimize.nnls(pairs, moments)[0]
    return (axes * (pairs @ second)) @ axes.T


#: Share of the isotropic inertia of the same trace mixed into a start (interior).
INTERIOR_SHARE = 0.02


def interior(inertia, share: float = INTERIOR_SHARE) -> np.ndarray:
    """A start strictly inside the inertias a body has: (1 - share) inertia + share trace/3 I.
    A convex mix of two bodies' inertias is a body's, and the mix keeps each moment below the
    sum of the other two by share trace / 3, so a fit projected onto realizable inertias
    (realizable_phi, realizable_face) does not begin held on the flat plate's face.
    """
    j = np.asarray(inertia, dtype=float)
    return (1.0 - share) * j + share * np.trace(j) / 3.0 * np.eye(3)


def realizable_phi(phi, keep_scale: bool = False) -> np.ndarray:
    """Phi (6,) of nearest_realizable(J(phi)): phi itself where J(phi) is a body's inertia (or
    not finite: the fit's own checks refuse that). keep_scale: phi[0], the pure scale coordinate,
    is kept (a fit that holds it, where the scale is not seen), so only J's shape moves; J is
    then the nearest one times a positive factor, a body's inertia still.
    """
    phi = np.asarray(phi, dtype=float)
    j = inertia_from_phi(phi)
    if not np.all(np.isfinite(j)):
        return phi
    near = nearest_realizable(j)
    if np.array_equal(near, j):
        return phi
    out = phi_from_inertia(near)
    if keep_scale:
        out[0] = phi[0]
    return out


def realizable_face(phi, tol: float = REALIZABLE_TOLERANCE) -> np.ndarray:
    """(m, 6) rows A (m = 1 where J(phi) is a flat plate's, at the limit nearest_realizable
    projects onto; else 0): steps d phi with A d phi = 0 keep the largest moment equal to the
    sum of the other two to first order, so a fit can move along the limit rather than creep
    by projections. The row is the gradient of (J_min + J_mid - J_max) / trace(J), by central
    differences.
    """
    def slack(p):
        moments = np.linalg.eigvalsh(inertia_from_phi(p))
        return (moments[0] + moments[1] - moments[2]) / moments.sum()

    phi = np.asarray(phi, dtype=float)
    if not (np.all(np.isfinite(inertia_from_phi(phi))) and slack(phi) <= tol):
        return np.zeros((0, 6))
    step = 1e-6 * np.maximum(1.0, np.abs(phi))
    rows = [(slack(phi + e * h) - slack(phi - e * h)) / (2 * h) for e, h in zip(np.eye(6), step)]
    return np.array([rows])
