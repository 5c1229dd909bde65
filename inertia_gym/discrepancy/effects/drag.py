"""The drag effects' shared form (viscous_damping, aero_drag): a symmetric coefficient matrix that
only takes energy out.
"""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, inertia6, matrix6


def _drag_matrix(value) -> np.ndarray:
    """A drag coefficient as a symmetric (3, 3) matrix: a number (isotropic), three (per body
    axis), six (xx, xy, xz, yy, yz, zz) or a 3x3.
    """
    v = np.asarray(value, float)
    if v.size == 1:
        return float(v) * np.eye(3)
    if v.size == 3:
        return np.diag(np.ravel(v))
    return matrix6(np.ravel(v)) if v.size == 6 else v.reshape(3, 3)


class _Drag(EffectModel):
    """A drag torque with a symmetric coefficient matrix C (3, 3): its eigenvectors are the
    body's drag axes (a plate's normal, a racquet's handle), which need not be the gyro's, and
    its eigenvalues the coefficient about each; fitted as C's six entries. Drag only takes
    energy out (the power w . tau = -w^T C w (times |w|) <= 0): every solver step is projected
    onto positive semi-definite C (negative eigenvalues set to zero), so a fit that needs C
    feeding energy in is not drag. A projection, not a penalty row: drag about one axis is
    often nil (a racquet's handle), and a penalty's one-sided derivative there freezes the fit.
    """

    params, size, family = ("c",), 6, "drag"
    keeps_invariants = True

    def _scale(self, d) -> float:
        raise NotImplementedError

    @override
    def unpack(self, p):
        return {"c": matrix6(p)}

    @override
    def pack(self, params):
        return inertia6(_drag_matrix(params["c"]))

    @override
    def typical(self, form, d):
        return np.full(6, self._scale(d))

    @override
    def starts(self, form, d, probe):
        # none, and on a record of few long segments (where from none alone the fit can stall
        # in a shallow minimum) the two best of isotropic and single-axis drag over two decades
        if not probe.few_segments:
            return [np.zeros(6)]
        return [np.zeros(6)] + probe.best_of(self._trials(d), keep=2)

    def _trials(self, d) -> list[np.ndarray]:
        """Isotropic and single-axis drag matrices (6 entries each) over two decades."""
        size = self._scale(d)
        shapes = [np.eye(3)] + [np.diag(e) for e in np.eye(3)]
        return [inertia6(c * size * m) for c in (0.5, 2.0, 8.0, 32.0) for m in shapes]

    @override
    def feasible(self, p, inertia):
        values, vectors = np.linalg.eigh(matrix6(p))
        return inertia6((vectors * np.maximum(values, 0.0)) @ vectors.T)

    @override
    def face(self, p):
        # the tangent of the positive semi-definite matrices of C's rank: n_i^T dC n_j = 0 over
        # C's null directions (dC may turn C's range, a second-order loss the projection takes);
        # at C = 0 no face (a projected step leaves the apex, a step on it would not move)
        values, vectors = np.linalg.eigh(matrix6(p))
        null = vectors[:, values <= 1e-9 * max(float(np.abs(values).max()), 1e-300)]
        k = null.shape[1]
        if k in (0, 3):
            return np.zeros((0, 6))
        units = [matrix6(e) for e in np.eye(6)]
        return np.array([[null[:, i] @ u @ null[:, j] for u in units] for i in range(k) for j in range(i, k)])
