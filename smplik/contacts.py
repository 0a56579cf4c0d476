"""Foot contacts of a joint-position clip: the floor under the feet, the ground's motion, low and slow feet.

The detector of the animation pipeline (:mod:`workflows.animation.clean` cleans with it) and of the tracker's
training labels (:func:`smplik.tracking.data.clip_contacts`). Positions are (T, 24, 3) SMPL joints, metres,
y up. Its settings are the ``contact_*`` fields of :class:`ContactConfig` (also carried by
:class:`workflows.animation.clean.CleanConfig`, with the same defaults).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from smplik.conventions import JOINT_INDEX
from smplik.smoothing import whittaker

FOOT_JOINTS = (JOINT_INDEX["left_foot"], JOINT_INDEX["right_foot"])
"""The joints that touch the floor, per side (left, right)."""


class ContactSettings(Protocol):
    """What :func:`foot_contacts` reads from a config: :class:`ContactConfig`, or
    :class:`workflows.animation.clean.CleanConfig` (which also has :class:`GroundSettings`' field)."""

    contact_height_m: float
    contact_speed_mps: float
    contact_noise_ratio: float
    contact_release_ratio: float
    contact_min_frames: int


class GroundSettings(ContactSettings, Protocol):
    """What :func:`ground_of` reads: the contact settings, whether the ground may move and how smoothly its
    velocity may change (None: a constant velocity)."""

    ground_moves: bool
    ground_smoothness: float | None


@dataclass(frozen=True)
class ContactConfig:
    """Settings of :func:`foot_contacts`, with the defaults of :class:`workflows.animation.clean.CleanConfig`.

    A foot within ``contact_height_m`` of the floor and slower than ``contact_speed_mps`` (per axis at least
    ``contact_noise_ratio`` times the clip's foot noise, :func:`foot_noise`) is in contact; a run extends over
    neighbouring low frames up to ``contact_release_ratio`` times that threshold, and runs shorter than
    ``contact_min_frames`` are dropped.
    """

    contact_height_m: float = 0.08
    contact_speed_mps: float = 0.35
    contact_noise_ratio: float = 3.0
    contact_release_ratio: float = 1.5
    contact_min_frames: int = 3


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, end_exclusive) of the True runs of a (T,) bool array."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.diff(padded)
    return list(zip(np.nonzero(edges == 1)[0].tolist(), np.nonzero(edges == -1)[0].tolist(), strict=True))


FLOOR_TILT_PRIOR = 0.005
"""Ridge weight (m^2 per foot sample) pulling the floor's slope towards level (y up: the world's or the camera's
up): the fitted slope shrinks by s^2 / (s^2 + prior), s the standing feet's horizontal spread (std, m), so a
clip whose standing feet stay within a few centimetres keeps a level floor."""


def floor_plane(p_world: np.ndarray, prior: float = FLOOR_TILT_PRIOR) -> np.ndarray:
    """The floor under a clip's feet: ``(a, b, c)`` of ``y = a x + b z + c`` (metres, y up). p_world (T, 24, 3).

    The lower foot of every frame stands on the floor (walking, running; in camera space too, where the floor
    is tilted by the camera's pitch and roll): a plane is fitted to those points by least squares, its slope
    pulled towards level (``prior``, the world's or camera's up as the prior), to the points less than 5 cm
    above their median (airborne frames dropped), four times, "lower" measured from the previous fit. ``c``
    is the 5th percentile of the foot joints' heights above the sloped plane, as the level floor's height is.
    """
    feet = p_world[:, list(FOOT_JOINTS)]  # (T, 2, 3)
    slope = np.zeros(2)
    for _ in range(4):  # the lower foot above the current plane (a tilted floor changes which foot is lower)
        heights = feet[..., 1] - feet[..., [0, 2]] @ slope
        low = feet[np.arange(feet.shape[0]), np.argmin(heights, axis=1)]  # (T, 3)
        resid = low[:, 1] - low[:, [0, 2]] @ slope
        keep = resid < np.median(resid) + 0.05  # the lower foot stands in most frames: drop airborne ones
        xz = low[keep][:, [0, 2]]
        centred = xz - xz.mean(0)
        y = low[keep, 1] - low[keep, 1].mean()
        n = max(int(keep.sum()), 1)
        slope = np.linalg.solve(centred.T @ centred + prior * n * np.eye(2), centred.T @ y)
    heights = feet[..., 1] - feet[..., [0, 2]] @ slope
    return np.array([slope[0], slope[1], float(np.percentile(heights, 5.0))])


def height_above_floor(p: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Vertical height (m) above ``plane`` = (a, b, c) of ``y = a x + b z + c`` of points p (..., 3) -> (...)."""
    return p[..., 1] - plane[0] * p[..., 0] - plane[1] * p[..., 2] - plane[2]


def joint_speed(p: np.ndarray) -> np.ndarray:
    """Per-frame speed (units per frame) by central differences (one-sided at the ends). p (T, ..., 3) -> (T, ...)."""
    if p.shape[0] < 2:
        return np.zeros(p.shape[:-1])
    return np.linalg.norm(np.gradient(p, axis=0), axis=-1)


def ground_velocity(p_world: np.ndarray, tolerance: float | np.ndarray, height: float | None = None) -> np.ndarray:
    """The ground's velocity (3,) (units per frame) in the frame of joints p_world (T, 24, 3), y up.

    The lower foot stands on the ground in most frames of walking, so the median over the clip of its velocity
    is the ground's: the belt's or the pan's velocity for a treadmill or a camera following the person. With
    ``height``, only frames whose lower foot is within it of the floor (:func:`floor_plane`) count: a runner's
    or jumper's lower foot is in the air in the others. It is kept only when more of those frames' lower foot
    moves within ``tolerance`` (units per frame; (3,) per axis: the scaled speed below 1) of it than of a
    still ground (a person moving through a still camera's view biases the median); else zero."""
    feet = p_world[:, list(FOOT_JOINTS)]
    if feet.shape[0] < 3:
        return np.zeros(3)
    heights = feet[..., 1] if height is None else height_above_floor(feet, floor_plane(p_world))
    lower = np.argmin(heights, axis=1)
    v = np.gradient(feet, axis=0)[np.arange(feet.shape[0]), lower]
    if height is not None:
        v = v[heights[np.arange(feet.shape[0]), lower] < height]
        if v.shape[0] == 0:
            return np.zeros(3)
    median = np.median(v, axis=0)
    moving = (np.linalg.norm((v - median) / tolerance, axis=-1) < 1).sum()
    still = (np.linalg.norm(v / tolerance, axis=-1) < 1).sum()
    return median if moving > still else np.zeros(3)


def contact_threshold(cfg: ContactSettings, noise: np.ndarray | None = None) -> np.ndarray:
    """The per-axis contact speed threshold (3,) (m/s): ``contact_speed_mps``, raised to ``contact_noise_ratio``
    times the clip's foot noise ``noise`` (3,) m/s (:func:`foot_noise`) on noisy axes."""
    sigma = np.zeros(3) if noise is None else np.asarray(noise)
    return np.maximum(cfg.contact_speed_mps, cfg.contact_noise_ratio * sigma)


def ground_drift(ground: np.ndarray | None, T: int) -> np.ndarray:
    """How far the ground has moved since frame 0 (T, 3), from its velocity (units per frame): ``ground`` (3,)
    constant or (T, 3) per frame (trapezoids between frames: a constant velocity g gives exactly ``g * t``),
    None still."""
    if ground is None:
        return np.zeros((T, 3))
    g = np.broadcast_to(np.asarray(ground, dtype=np.float64), (T, 3))
    return np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (g[1:] + g[:-1]), axis=0)])


GROUND_ITERATIONS = 5
"""Reweighting passes of :func:`varying_ground` (each down-weights the observations far from the last fit)."""
GROUND_PRIOR = 1e-3
"""Data weight of the constant start velocity on every frame of :func:`varying_ground` (only where no foot is low
does it matter: the fit then runs on from its neighbours' velocity)."""
GROUND_VARYING_GAIN = 2.0
""":func:`ground_track` keeps a varying ground only where it explains at least this many times as many low frames
as the constant (or still) ground: its freedom fits some noise too, and on static-camera known truth
(``benchmarks/animation_ground.py``: CMU clips, frame-correlated noise) a varying ground that explained only a
few more frames made the feet skate more."""


def varying_ground(v: np.ndarray, weight: np.ndarray, tolerance: float | np.ndarray, smoothness: float,
                   start: np.ndarray, plane: np.ndarray | None = None) -> np.ndarray:
    """A ground velocity (T, 3) that varies smoothly over time: a camera panning with a runner at a changing speed.

    The observations are the lower foot's velocity v (T, 3) (units per frame), each frame weighted by ``weight``
    (T,) >= 0 (how low the foot is; 0: no foot near the floor, a flight). The fit is a weighted Whittaker smoothing
    over time (``smoothness``: weight of the squared second difference, frames) of the observations, reweighted
    :data:`GROUND_ITERATIONS` times by ``1 / (1 + r^2)``, r the observation's distance from the fit scaled per
    axis by ``tolerance`` (units per frame, scalar or (3,)): a foot landing or taking off while low barely counts.
    ``start`` (3,) (a constant ground velocity) starts the fit and weakly holds the frames without observations.
    With ``plane`` (a, b, c) of the floor ``y = a x + b z + c`` (:func:`floor_plane`), the ground slides along it:
    only x and z are fitted, ``y = a x + b z``."""
    v = np.asarray(v, dtype=np.float64)
    T = v.shape[0]
    start = np.asarray(start, dtype=np.float64)
    g = np.repeat(start[None], T, axis=0)
    axes = [0, 2] if plane is not None else [0, 1, 2]
    for _ in range(GROUND_ITERATIONS):
        r = np.linalg.norm((v - g) / tolerance, axis=-1)
        w = np.asarray(weight, dtype=np.float64) / (1.0 + r ** 2)
        y = (w[:, None] * v[:, axes] + GROUND_PRIOR * start[axes]) / (w[:, None] + GROUND_PRIOR)
        g[:, axes] = whittaker(y, np.repeat((w + GROUND_PRIOR)[:, None], len(axes), axis=1),
                               np.full(len(axes), smoothness))
        if plane is not None:
            g[:, 1] = plane[0] * g[:, 0] + plane[1] * g[:, 2]
    return g


def ground_track(p_world: np.ndarray, tolerance: float | np.ndarray, height: float,
                 smoothness: float | None = None) -> np.ndarray:
    """The ground's velocity per frame (T, 3) (units per frame) in the frame of joints p_world (T, 24, 3), y up.

    :func:`ground_velocity` (constant, or still) unless ``smoothness`` is given and :func:`varying_ground` explains
    far more of the low frames (lower foot within ``height`` of the floor) than it does: of those frames, the lower
    foot moves within ``tolerance`` (scaled speed below 1, as in :func:`ground_velocity`) of the varying ground on
    at least :data:`GROUND_VARYING_GAIN` times as many (and 3 more) as of the constant one (a camera panning with a
    runner at a changing speed, whose stance feet the constant pan leaves moving). The observations are the lower
    foot's velocity, weighted by its lowness ``1 - h / height`` (h its height above the floor, :func:`floor_plane`);
    the fitted ground slides along that floor."""
    T = p_world.shape[0]
    constant = ground_velocity(p_world, tolerance, height)
    if smoothness is None or T < 3:
        return np.repeat(constant[None], T, axis=0)
    feet = p_world[:, list(FOOT_JOINTS)]
    plane = floor_plane(p_world)
    heights = height_above_floor(feet, plane)
    lower = np.argmin(heights, axis=1)
    rows = np.arange(T)
    h = heights[rows, lower]
    v = np.gradient(feet, axis=0)[rows, lower]
    low = h < height
    if not low.any():
        return np.repeat(constant[None], T, axis=0)
    start = np.median(v[low], axis=0)
    fit = varying_ground(v, np.clip(1.0 - h / height, 0.0, 1.0), tolerance, smoothness, start, plane)
    explained = (np.linalg.norm((v - fit) / tolerance, axis=-1) < 1)[low].sum()
    explained_constant = (np.linalg.norm((v - constant) / tolerance, axis=-1) < 1)[low].sum()
    if explained >= max(GROUND_VARYING_GAIN * explained_constant, explained_constant + 3):
        return fit
    return np.repeat(constant[None], T, axis=0)


def ground_of(p_world: np.ndarray, fps: float, cfg: GroundSettings, scale: float = 1.0,
              noise: np.ndarray | None = None) -> np.ndarray:
    """The ground's velocity per frame (T, 3) (p_world's units per frame; :func:`ground_track`, varying with
    ``cfg.ground_smoothness`` at 30 frames/s, scaled by ``(fps / 30) ** 4`` so it spans the same time) when
    ``cfg.ground_moves``, else zeros; p_world (T, 24, 3) in SMPL space, the contact height, speed and the foot
    ``noise`` (3,) (:func:`foot_noise`) in character space (``scale`` times SMPL space)."""
    T = p_world.shape[0]
    if not cfg.ground_moves:
        return np.zeros((T, 3))
    smoothness = None if cfg.ground_smoothness is None else cfg.ground_smoothness * (fps / 30.0) ** 4
    return ground_track(p_world, contact_threshold(cfg, noise) / fps / scale, cfg.contact_height_m / scale,
                        smoothness)


def foot_noise(p_raw: np.ndarray, p_smooth: np.ndarray, fps: float) -> np.ndarray:
    """The clip's foot noise speed per axis (3,) (units/s): the median over frames and both feet of the squared
    velocity of the raw feet's deviation from their smoothed paths, square-rooted (robust to glitches; 0.674
    times the standard deviation of Gaussian noise). p_raw, p_smooth (T, 24, 3).

    A still foot of the smoothed path keeps low-frequency estimator error of about this speed (a monocular
    estimator's depth, from the person's image scale, jitters several times more than the image axes)."""
    idx = list(FOOT_JOINTS)
    if p_raw.shape[0] < 3:
        return np.zeros(3)
    v = np.gradient(p_raw[:, idx] - p_smooth[:, idx], axis=0) * fps  # (T, 2, 3)
    return np.sqrt(np.median(v ** 2, axis=(0, 1)))


def stance_noise(p_world: np.ndarray, fps: float, height: float, share: float = 0.25) -> np.ndarray:
    """The speed per axis (3,) (units/s) that a planted foot of the smoothed joints p_world (T, 24, 3) still
    shows: the rms velocity, per axis, of the slowest ``share`` of the foot-frames within ``height`` of the floor
    (:func:`floor_plane`; both feet). Zeros when no foot is that low.

    A smoothing keeps part of an estimate's noise (most of it where the noise drifts slowly over frames), so on a
    noisy estimate a planted foot moves by this much; on a clean one it is near zero. Standing, walking or landing,
    a quarter of the low foot-frames are planted ones."""
    feet = p_world[:, list(FOOT_JOINTS)]
    if feet.shape[0] < 3:
        return np.zeros(3)
    low = height_above_floor(feet, floor_plane(p_world)) < height
    v = np.gradient(feet, axis=0)[low] * fps  # (N, 3)
    if v.shape[0] < 3:
        return np.zeros(3)
    slow = v[np.argsort(np.linalg.norm(v, axis=-1))[:max(3, int(share * v.shape[0]))]]
    return np.sqrt((slow ** 2).mean(0))


def foot_contacts(p_world: np.ndarray, fps: float, cfg: ContactSettings, ground: np.ndarray | None = None,
                  noise: np.ndarray | None = None) -> np.ndarray:
    """Foot contacts (T, 2) bool (left, right) of joint positions p_world (T, 24, 3) in metres, y up: feet low
    above the floor and slow relative to the ground moving at ``ground`` (3,) or (T, 3) m/frame (constant or per
    frame, :func:`ground_drift`; default: still).

    Slow: per axis, the velocity relative to the ground is scaled by that axis's threshold, the larger of
    ``contact_speed_mps`` and ``contact_noise_ratio`` times ``noise`` (3,) m/s (:func:`foot_noise`; default
    none), and the scaled speed is below 1. Hysteresis: each run extends over neighbouring low frames whose
    scaled speed is below ``contact_release_ratio``; runs shorter than ``contact_min_frames`` are dropped."""
    feet = p_world[:, list(FOOT_JOINTS)]  # (T, 2, 3)
    threshold = contact_threshold(cfg, noise)  # (3,) m/s per axis
    low = height_above_floor(feet, floor_plane(p_world)) < cfg.contact_height_m
    relative = feet - ground_drift(ground, feet.shape[0])[:, None]
    v = (np.gradient(relative, axis=0) if feet.shape[0] >= 2 else np.zeros_like(relative)) * fps
    scaled = np.linalg.norm(v / threshold, axis=-1)  # (T, 2)
    contact = low & (scaled < 1.0)
    loose = low & (scaled < cfg.contact_release_ratio)
    for side in range(2):
        for s, e in _runs(loose[:, side]):  # hysteresis: a loose run holding a strict frame is one contact
            contact[s:e, side] = contact[s:e, side].any()
        for s, e in _runs(contact[:, side]):
            if e - s < cfg.contact_min_frames:
                contact[s:e, side] = False
    return contact


# ----------------------------------------------------------------------------- IK
