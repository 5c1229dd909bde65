"""What a fit's residual shows beyond the catalogue: impulses at the record's ends (to trim), and
the torque the model misses regressed on a library of terms of the rates (sparse_terms).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.objective import Fit
from inertia_gym.prepare import end_impulses


def impulses(d: Data, fit: Fit) -> tuple[int, int]:
    """Samples to cut at the start and the end of d (counted from its ends, clipped samples
    there included) for an impulse at either end of fit's whitened residual rows
    (:func:`end_impulses`).
    """
    start_row, stop_row = end_impulses(fit.z, d.row_seg[1:] == d.row_seg[:-1])
    kept = np.flatnonzero(d.row >= 0)
    first_sample = kept[np.r_[True, np.diff(d.row[kept]) != 0]]  # of each row
    start = int(first_sample[start_row]) if start_row else 0
    end = int(d.t.size - first_sample[stop_row]) if stop_row < d.n_rows else 0
    return start, end


def sparse_terms(d: Data, fit: Fit, threshold: float = 0.1) -> list[dict]:
    """Data-driven fallback: the torque the model misses, -J dr/dt of the rate residual rows
    (Savitzky-Golay derivative inside each segment), regressed per axis on a library of terms
    {1, w_i, w_i w_j, |w| w_i} of the measured rates by sequentially thresholded least squares.

    Returns the surviving terms per axis as {axis, term, coefficient (N·m per unit term)}.
    """
    t_row = d.t_row
    keep = d.row >= 0
    w = np.stack([np.bincount(d.row[keep], d.w[keep, i]) / np.bincount(d.row[keep]) for i in range(3)], 1)
    torque = np.zeros_like(fit.r)
    ok = np.zeros(d.n_rows, bool)
    for s in range(d.segments):
        idx = np.flatnonzero(d.row_seg == s)
        if idx.size < 7:
            continue
        step = float(np.median(np.diff(t_row[idx])))
        rate = signal.savgol_filter(fit.r[idx], 7, 2, deriv=1, delta=step, axis=0)
        torque[idx] = -rate @ fit.inertia.T
        ok[idx] = True
    if ok.sum() < 12:
        return []
    lib = {"1": np.ones(d.n_rows)}
    for i, a in enumerate("xyz"):
        lib[f"w{a}"] = w[:, i]
        lib[f"|w|w{a}"] = np.linalg.norm(w, axis=1) * w[:, i]
        for j in range(i, 3):
            lib[f"w{a}w{'xyz'[j]}"] = w[:, i] * w[:, j]
    names = list(lib)
    theta = np.stack(list(lib.values()), 1)[ok]
    scale = np.linalg.norm(theta, axis=0) + 1e-300
    a = theta / scale
    out = []
    for axis in range(3):
        y = torque[ok, axis]
        coef = np.linalg.lstsq(a, y, rcond=None)[0]
        for _ in range(10):
            small = np.abs(coef) < threshold * np.abs(coef).max()
            coef[small] = 0.0
            if (~small).any():
                coef[~small] = np.linalg.lstsq(a[:, ~small], y, rcond=None)[0]
        for name, c, s in zip(names, coef, scale):
            if c != 0.0:
                out.append({"axis": "xyz"[axis], "term": name, "coefficient": float(c / s)})
    return out
