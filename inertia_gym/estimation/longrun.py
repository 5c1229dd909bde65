"""Serial correlation of residual and score sequences: how long it lasts, and the Bartlett
(Newey-West) long-run covariance it implies. Shared by the output-error and filter-error fits.
"""

from __future__ import annotations

import math

import numpy as np


def correlation_lags(residuals, max_lag: int | None = None) -> int:
    """Number of lags over which the residuals (M, c) stay correlated (0: white).

    The mean autocorrelation over channels is significant at lag l when it exceeds 3/sqrt(M);
    the count is the last significant lag before the first run of five insignificant ones.
    """
    x = residuals - residuals.mean(axis=0)
    m = x.shape[0]
    max_lag = min(m // 4, 2000 if max_lag is None else max_lag)
    if max_lag < 1:
        return 0
    spec = np.fft.rfft(x, n=2 * m, axis=0)
    acf = np.fft.irfft(spec * np.conj(spec), axis=0)[: max_lag + 1]
    acf = (acf / np.clip(acf[0], 1e-300, None)).mean(axis=1)
    bound = 3.0 / math.sqrt(m)
    last, quiet = 0, 0
    for lag in range(1, max_lag + 1):
        if abs(acf[lag]) > bound:
            last, quiet = lag, 0
        else:
            quiet += 1
            if quiet >= 5:
                break
    return last


def long_run_covariance(scores, lags: int) -> np.ndarray:
    """(n, n) Bartlett long-run covariance sum_k g_k g_k^T + sum_l (1 - l/(lags+1)) (C_l + C_l^T),
    C_l = sum_k g_{k+l} g_k^T, of a score sequence scores (M, n).
    """
    g = np.asarray(scores, dtype=float)
    b = g.T @ g
    for lag in range(1, lags + 1):
        c = g[lag:].T @ g[:-lag]
        b += (1.0 - lag / (lags + 1.0)) * (c + c.T)
    return b
