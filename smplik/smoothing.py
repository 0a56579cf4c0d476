"""The temporal smoother: weighted Whittaker-Henderson smoothing along time.

``z`` minimises ``sum_t w_t (z_t - y_t)^2 + sum_t lam_t (z_t+1 - 2 z_t + z_t-1)^2``: one banded
(pentadiagonal) linear solve per channel over the whole clip. :func:`whittaker` takes a smoothness per channel
(and frame); :func:`smplik.sequence.smooth_trajectories` (joint paths, one smoothness) solves the same system
from :func:`penalty_bands`. Used by the sequence solver (:mod:`smplik.sequence`) and the animation's adaptive
cleaning (:mod:`workflows.animation.denoise`).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solveh_banded

__all__ = ["penalty_bands", "savgol_coefficients", "savgol_smooth", "whittaker"]


def _fit_matrix(window: int, order: int) -> np.ndarray:
    """(order + 1, window) least-squares map from ``window`` samples at offsets ``-(window // 2)..window // 2`` to the
    coefficients of their polynomial of ``order`` (increasing powers of the offset)."""
    offsets = np.arange(window, dtype=np.float64) - window // 2
    return np.linalg.pinv(np.vander(offsets, order + 1, increasing=True))


def savgol_coefficients(window: int, order: int) -> np.ndarray:
    """(window,) Savitzky-Golay smoothing weights: the value at the window's centre of the least-squares polynomial
    of ``order`` through ``window`` samples (odd); equal to ``scipy.signal.savgol_coeffs(window, order)`` (whose
    import costs seconds of CPU on every run)."""
    return _fit_matrix(window, order)[0]


def savgol_smooth(y: np.ndarray, window: int, order: int) -> np.ndarray:
    """Savitzky-Golay smoothing of y (T, ...) along time (axis 0), as ``scipy.signal.savgol_filter(y, window, order,
    axis=0, mode="interp")``: the centre value of the local polynomial inside, and the first and last
    ``window // 2`` samples from the polynomial fitted to the first and last ``window`` samples. T >= window."""
    y = np.asarray(y, dtype=np.float64)
    T, half = y.shape[0], window // 2
    if window % 2 == 0 or order >= window or T < window:
        raise ValueError(f"savgol_smooth needs an odd window > order and at most T samples; got window {window}, "
                         f"order {order}, T {T}.")
    flat = y.reshape(T, -1)
    fit = _fit_matrix(window, order)  # (order + 1, window)
    windows = np.lib.stride_tricks.sliding_window_view(flat, window, axis=0)  # (T - window + 1, C, window)
    out = np.empty_like(flat)
    out[half:T - half] = windows @ fit[0]
    offsets = np.arange(window, dtype=np.float64) - half
    powers = np.vander(offsets, order + 1, increasing=True)  # (window, order + 1)
    out[:half] = (powers @ (fit @ flat[:window]))[:half]  # the first window's polynomial at its first samples
    out[T - half:] = (powers @ (fit @ flat[T - window:]))[window - half:]
    return out.reshape(y.shape)


def penalty_bands(lam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bands of D2^T diag(lam) D2 for lam (T-2,): main (T,), first (T-1,), second (T-2,) diagonals."""
    T = lam.shape[0] + 2
    main, off1, off2 = np.zeros(T), np.zeros(T - 1), np.zeros(T - 2)
    coef = (1.0, -2.0, 1.0)
    for a in range(3):
        main[a:T - 2 + a] += lam * coef[a] ** 2
    for a in range(2):
        off1[a:T - 2 + a] += lam * coef[a] * coef[a + 1]
    off2 += lam * coef[0] * coef[2]
    return main, off1, off2


def whittaker(y: np.ndarray, weight: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Weighted Whittaker-Henderson smoothing along time, a smoothness per channel (and frame).

    Args:
        y: (T, C) data; weight: (T, C) > 0 data weights; lam: (C,) or (T-2, C) >= 0 smoothness.

    Returns:
        (T, C) the smoothed channels (``y`` itself when T < 3).
    """
    y = np.asarray(y, dtype=np.float64)
    T, C = y.shape
    if T < 3:
        return y.copy()
    lam = np.broadcast_to(np.asarray(lam, dtype=np.float64), (T - 2, C))
    weight = np.broadcast_to(np.asarray(weight, dtype=np.float64), (T, C))
    out = np.empty_like(y)
    banded = np.zeros((3, T))
    for c in range(C):
        main, off1, off2 = penalty_bands(lam[:, c])
        banded[0, 2:] = off2
        banded[1, 1:] = off1
        banded[2] = main + weight[:, c]
        out[:, c] = solveh_banded(banded, weight[:, c] * y[:, c], check_finite=False)
    return out
