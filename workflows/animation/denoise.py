"""Noise-aware smoothing of a motion's channels: measure each channel's noise, smooth it as much as that noise asks.

A channel is one number per frame: a component of a joint's local rotation (a sign-continuous unit quaternion)
or one axis of the root's position (x, y, depth). All functions are pure numpy over ``(T, C)`` arrays (time
first, ``C`` channels).

* **Noise** (:func:`estimate_noise`): the residual of a local cubic fit over :data:`NOISE_WINDOW` frames (Savitzky-
  Golay), whose rms within 3 robust spreads (median absolute deviations) of zero, rescaled by the truncation and the
  fit's residual gain, is the channel's frame-to-frame noise ``sigma`` (robust to glitches and to the motion itself,
  which a cubic follows over a quarter second); the residual's lag-1 autocorrelation tells independent noise (about
  :data:`WHITE_LAG1`, the fit's own) from noise correlated over frames (higher; only its fast part is measured and
  removed: the slow part looks like motion).
* **Smoothing** (:func:`whittaker`): the Whittaker-Henderson smoother, ``z`` minimising
  ``sum_t w_t (z_t - y_t)^2 + sum_t lam_t (z_t+1 - 2 z_t + z_t-1)^2`` (one banded solve per channel), the
  data weight ``w_t`` per frame (fast motion: the estimate is trusted more, :func:`motion_weights`).
* **Strength** (:func:`sure_smoothness`): per channel, the ``lam`` of a log grid that minimises Stein's
  unbiased risk estimate ``|y - z|^2 - T sigma^2 + 2 sigma^2 tr(H)`` (the expected squared error to the
  noise-free channel, for noise of that ``sigma``); ``tr(H)`` of the smoother from its frequency response.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplik.smoothing import savgol_coefficients, savgol_smooth, whittaker

NOISE_WINDOW = 7
"""Frames of the local cubic fit whose residual measures the noise."""
NOISE_ORDER = 3
_RESIDUAL_GAIN = float(np.sqrt(1.0 - savgol_coefficients(NOISE_WINDOW, NOISE_ORDER)[NOISE_WINDOW // 2]))
"""Standard deviation of the fit's residual for unit independent noise (sqrt(1 - h0))."""
_E = -savgol_coefficients(NOISE_WINDOW, NOISE_ORDER)
_E[NOISE_WINDOW // 2] += 1.0
WHITE_LAG1 = float((_E[1:] * _E[:-1]).sum() / (_E * _E).sum())
"""Lag-1 autocorrelation of the fit's residual for independent noise (the residual filter's own)."""
TRUNCATED_VARIANCE = 0.97334
"""Variance of a unit normal truncated at +-3 (the trimmed rms of :func:`estimate_noise` is divided by its root)."""
LAMBDA_GRID = np.logspace(-2, 5, 29)
"""Smoothness values :func:`sure_smoothness` chooses from."""


@dataclass(frozen=True)
class ChannelNoise:
    """Measured noise of ``C`` channels (:func:`estimate_noise`)."""

    sigma: np.ndarray
    """(C,) frame-to-frame noise (standard deviation, the channel's units)."""
    lag1: np.ndarray
    """(C,) lag-1 autocorrelation of the fit residual (:data:`WHITE_LAG1` for independent noise; higher:
    correlated over frames)."""

    @property
    def correlated(self) -> np.ndarray:
        """(C,) bool: the noise is correlated over frames (lag-1 residual autocorrelation well above white)."""
        return self.lag1 > WHITE_LAG1 + 0.25


def estimate_noise(y: np.ndarray) -> ChannelNoise:
    """Noise per channel of y (T, C) (module docstring). Fewer than :data:`NOISE_WINDOW` frames: zero."""
    y = np.asarray(y, dtype=np.float64)
    T, C = y.shape
    if T < NOISE_WINDOW:
        return ChannelNoise(np.zeros(C), np.full(C, WHITE_LAG1))
    r = y - savgol_smooth(y, NOISE_WINDOW, NOISE_ORDER)
    r = r[NOISE_WINDOW // 2:T - NOISE_WINDOW // 2]
    mad = np.median(np.abs(r - np.median(r, axis=0)), axis=0)
    inside = np.abs(r) <= 3.0 * 1.4826 * mad  # glitches and outliers left out ...
    trimmed = np.sqrt((np.where(inside, r, 0.0) ** 2).sum(0) / np.maximum(inside.sum(0), 1) / TRUNCATED_VARIANCE)
    sigma = np.where(mad > 0, trimmed, 0.0) / _RESIDUAL_GAIN  # ... the rest's rms: a steadier scale than the MAD
    clip = np.clip(r, -3 * 1.4826 * mad, 3 * 1.4826 * mad)  # glitches do not decide the correlation
    num = (clip[1:] * clip[:-1]).sum(0)
    den = np.maximum((clip * clip).sum(0), 1e-30)
    return ChannelNoise(sigma, num / den)


def _trace(T: int, lam: float) -> float:
    """tr(H) of the (unweighted, constant-lam) Whittaker smoother of T frames, from its frequency response."""
    omega = np.pi * np.arange(T) / T
    return float((1.0 / (1.0 + lam * (2.0 - 2.0 * np.cos(omega)) ** 2)).sum())


def sure_smoothness(y: np.ndarray, sigma: np.ndarray, grid: np.ndarray = LAMBDA_GRID) -> np.ndarray:
    """Per channel of y (T, C), the smoothness of ``grid`` minimising the unbiased risk for noise ``sigma`` (C,)
    (module docstring); 0 for noise-free channels."""
    y = np.asarray(y, dtype=np.float64)
    T, C = y.shape
    best = np.zeros(C)
    if T < 3:
        return best
    risk_best = np.full(C, np.inf)
    ones = np.ones((T, C))
    for lam in grid:
        z = whittaker(y, ones, np.full(C, lam))
        risk = ((y - z) ** 2).sum(0) + sigma ** 2 * (2.0 * _trace(T, lam) - T)
        better = (risk < risk_best) & (sigma > 0)
        best[better], risk_best[better] = lam, risk[better]
    return best


def noise_share(y: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Per channel, the noise ``sigma`` (C,) as a share of the rms frame-to-frame change of y (T, C) (C,): about
    0.7 for noise alone (sqrt(1/2) of white noise's), less the more the motion moves the channel; NaN for a
    constant channel (and for fewer than 2 frames)."""
    y = np.asarray(y, dtype=np.float64)
    if y.shape[0] < 2:
        return np.full(y.shape[1], np.nan)
    step = np.sqrt(np.mean(np.diff(y, axis=0) ** 2, axis=0))
    return np.where(step > 0, np.asarray(sigma) / np.maximum(step, 1e-300), np.nan)


def motion_weights(y: np.ndarray, z: np.ndarray, sigma: np.ndarray, strength: float = 1.0, floor: float = 2.0,
                   cap: float = np.inf) -> np.ndarray:
    """Per-frame data weights (T, C) that trust the estimate y where the motion is fast.

    Where the smoothing ``z`` (T, C) of y bends fast motion (a swing, a landing), its residual ``y - z`` is
    larger than the noise ``sigma`` (C,) over several frames: its mean square over 5 frames, in units of
    ``sigma^2``, above ``floor`` (noise alone stays below it) raises the data weight as
    ``1 + strength (ratio - floor)^2``, so a second smoothing keeps that motion and still smooths the slow parts;
    at most ``cap`` (a nearly noise-free channel's ratio is huge wherever the smoothing bends it at all: weights
    jumping by orders of magnitude from frame to frame pin the path there and kink it between, adding jitter).
    """
    from scipy.ndimage import uniform_filter1d

    T, C = y.shape
    ratio = uniform_filter1d((y - z) ** 2, 5, axis=0, mode="nearest") / np.maximum(sigma, 1e-12) ** 2
    return np.minimum(1.0 + strength * np.maximum(ratio - floor, 0.0) ** 2, cap)
