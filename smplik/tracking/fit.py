"""The end-effector fit: a final causal pass that puts the head and the wrists on their trackers without passing
tracker noise through (:class:`EffectorFit`, on by default in :class:`smplik.tracking.runtime.Tracker`, so in
``Tracker.step``, :func:`smplik.tracking.runtime.track_sequence` and ``smplik track``).

Per frame, after the network's pose:

1. **Head**: the head joint is brought toward its target by bending the spine (CCD over spine1, spine2 and
   spine3, the swing spread over the three joints: each takes ``1 / (joints left)`` of what is still missing,
   :attr:`FitConfig.spine_passes` passes); what the spine cannot reach (it does not stretch) moves the whole body
   (the root's translation; the foot locks, after the fit, keep standing feet in place); the head takes the
   tracker's world rotation (when it has one).
2. **Wrists**: two-bone arm IK (shoulder, elbow, wrist) to the wrist target: by default
   (:attr:`FitConfig.bend_filter`) the elbow opens or closes about the arm's plane by the followed change of the
   angle the target's distance needs, then the shoulder aims the wrist at the target
   (:meth:`EffectorFit._bend_and_aim`); otherwise :func:`smplik.limb_ik.two_bone_ik` (or its numba kernel
   :func:`smplik.tracking.kernels.two_bone_ik`), the network's elbow plane kept. The wrist takes the tracker's
   world rotation (when it has one).

Targets are not the raw trackers: the *correction* (tracker minus the network's joint, a position or a rotation
vector) goes through a noise band. Each tracker's jitter sigma is estimated causally from its own second
differences (the median of the last :attr:`FitConfig.noise_window` frames, robust to the few frames of real
fast motion; less a floor, below which jitter counts as none; a new stream starts from a prior of 1 cm, weighted
as :attr:`FitConfig.prior_frames` frames; smoothed over time, so the gain does not step); the correction follows
the measured one through :data:`FOLLOWER_STAGES` cascaded steps of the steady-state Kalman gain for a random walk
of ``process`` per frame under that jitter (gain 1 on exact trackers, about 0.3 under 1 cm of noise), and is then
held within a band of ``band_sigmas`` x sigma (at least ``band_min``) of the measured correction: tracker jitter
inside the band is not followed, a drift beyond it is. On exact trackers the hands and the head land on their
trackers (the gain is 1); on noisy ones they follow slowly and the motion stays as smooth as the network's
(``benchmarks/results/tracking.json``, ``ours`` against ``ours_nofit``).

The legs and the root's rotation are left alone (the foot locks come after the fit).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from smplik.conventions import JOINT_INDEX, PARENTS
from smplik.tracking.config import FitConfig

SPINE = tuple(JOINT_INDEX[n] for n in ("spine1", "spine2", "spine3"))
HEAD = JOINT_INDEX["head"]
ARMS = {s: (JOINT_INDEX[f"{s}_collar"], JOINT_INDEX[f"{s}_shoulder"], JOINT_INDEX[f"{s}_elbow"],
            JOINT_INDEX[f"{s}_wrist"]) for s in ("left", "right")}
FOLLOWER_STAGES = 3
"""Gain steps in cascade (2: critically damped)."""
SIGMA_RATE = 0.05
"""Per-frame rate of the exponential smoothing of each jitter estimate."""
_CHI3_MEDIAN = 1.5382
"""Median of the chi distribution with 3 degrees of freedom (|N(0, I3)|)."""


def _subtree_mask() -> np.ndarray:
    """(24, 24) bool: [j, k] when joint k is j or below it."""
    m = np.eye(len(PARENTS), dtype=np.bool_)
    for k in range(len(PARENTS)):
        a = PARENTS[k]
        while a >= 0:
            m[a, k] = True
            a = PARENTS[a]
    return m


SUBTREE = _subtree_mask()
_PARENTS = np.array(PARENTS, dtype=np.int64)
_SPINE = np.array(SPINE, dtype=np.int64)

try:  # the geometry below runs as numba kernels when numba is installed (pip install 'smplik[fast]')
    import numba

    _jit = numba.njit(cache=True, nogil=True)
except ImportError:  # the same code as plain Python (slower, same results)
    def _jit(f):  # noqa: ANN001, ANN202
        return f


@_jit
def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vector (3,) -> (3, 3)."""
    angle = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    out = np.eye(3)
    if angle < 1e-12:
        return out
    x, y, z = v[0] / angle, v[1] / angle, v[2] / angle
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return out + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


@_jit
def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> rotation vector (3,) (the log map; exact away from pi, where the fit never operates)."""
    cos = min(max((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    angle = math.acos(cos)
    s = math.sin(angle)
    k = angle / (2.0 * s) if s > 1e-6 else 0.5
    return np.array([(R[2, 1] - R[1, 2]) * k, (R[0, 2] - R[2, 0]) * k, (R[1, 0] - R[0, 1]) * k])


@_jit
def swing_matrix(a: np.ndarray, b: np.ndarray, fraction: float) -> np.ndarray:
    """The least rotation (3, 3) turning direction a (3,) toward b (3,), ``fraction`` of the way."""
    axis = np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
    s = math.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
    if s < 1e-12:
        return np.eye(3)
    angle = math.atan2(s, a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) * fraction
    return rotvec_to_matrix(axis * (angle / s))


@_jit
def forward_kinematics(R: np.ndarray, transl: np.ndarray, offsets: np.ndarray, root: np.ndarray,
                       parents: np.ndarray, G: np.ndarray, p: np.ndarray) -> None:
    """FK of local rotations R (24, 3, 3) with transl (3,), bone offsets (24, 3) (joint minus parent, rest) and
    the rest root (3,) into world rotations ``G`` (24, 3, 3) and joints ``p`` (24, 3)."""
    G[0] = R[0]
    p[0] = root + transl
    for j in range(1, R.shape[0]):
        a = parents[j]
        G[j] = G[a] @ R[j]
        p[j] = p[a] + G[a] @ offsets[j]


@_jit
def turn_subtree(R: np.ndarray, G: np.ndarray, p: np.ndarray, j: int, D: np.ndarray, subtree: np.ndarray,
                 parents: np.ndarray) -> None:
    """Turn joint j and everything below it by the world rotation D (3, 3) about joint j, in place: R (24, 3, 3)
    local, G (24, 3, 3) world, p (24, 3) joints; subtree (24, 24) from :data:`SUBTREE`."""
    pj = p[j].copy()
    for k in range(R.shape[0]):
        if subtree[j, k]:
            p[k] = pj + D @ (p[k] - pj)
            G[k] = D @ G[k]
    R[j] = G[parents[j]].T @ G[j]


@_jit
def spine_ccd(R: np.ndarray, G: np.ndarray, p: np.ndarray, target: np.ndarray, chain: np.ndarray, end: int,
              passes: int, subtree: np.ndarray, parents: np.ndarray) -> None:
    """CCD of joint ``end`` toward target (3,) over the joints ``chain`` (root first), in place; each joint turns
    ``1 / (joints left in the chain)`` of the way, so the bend spreads over the chain."""
    n = chain.shape[0]
    for _ in range(passes):
        for i in range(n):
            j = chain[i]
            D = swing_matrix(p[end] - p[j], target - p[j], 1.0 / (n - i))
            turn_subtree(R, G, p, j, D, subtree, parents)


@_jit
def _median(a: np.ndarray) -> float:
    return np.median(a)


def steady_gain(sigma: float, process: float) -> float:
    """The steady-state Kalman gain of a random walk with step sigma ``process`` seen under white jitter of sigma
    ``sigma`` (1 without jitter)."""
    r, q = sigma * sigma, process * process
    if r <= q * 1e-6:
        return 1.0
    return min(1.0, (-q + math.sqrt(q * q + 4.0 * q * r)) / (2.0 * r))


class _Follower:
    """Cascaded gain steps on a 3-vector (:data:`FOLLOWER_STAGES` of them: under white jitter the output's
    acceleration falls with a power of the gain, not the gain)."""

    def __init__(self) -> None:
        self.stages: list[np.ndarray] | None = None

    @property
    def c(self) -> np.ndarray:
        return np.zeros(3) if self.stages is None else self.stages[-1]

    @c.setter
    def c(self, value: np.ndarray) -> None:
        self.stages = [value.copy() for _ in range(FOLLOWER_STAGES)]

    def update(self, e: np.ndarray, gain: float) -> np.ndarray:
        if self.stages is None:
            self.c = e
        else:
            x = e
            for i, s in enumerate(self.stages):
                x = self.stages[i] = s + gain * (x - s)
        return self.stages[-1]


class _Band:
    """One tracker's noise band for a 3-vector correction (a position or a rotation vector), causal."""

    def __init__(self, window: int, floor: float, prior: float = 0.0, prior_frames: int = 0) -> None:
        self.floor, self.prior, self.prior_frames = floor, prior, prior_frames
        self.smooth: float | None = None
        self.history: deque[np.ndarray] = deque(maxlen=3)
        self.d2 = np.zeros(window)
        self.n = 0
        self.follow = _Follower()
        self.gain = 1.0

    def sigma(self, signal: np.ndarray) -> float:
        """Feed the tracker's signal (3,) of this frame; returns its jitter sigma (per axis) from the median of
        its second differences over the window, less the floor (jitter below it counts as none)."""
        h = self.history
        h.append(signal)
        if len(h) == 3:
            d = h[2] - 2.0 * h[1] + h[0]
            self.d2[self.n % self.d2.shape[0]] = math.sqrt(float(d @ d))
            self.n += 1
        n = min(self.n, self.d2.shape[0])
        measured = _median(self.d2[:n]) / (math.sqrt(6.0) * _CHI3_MEDIAN) if n else 0.0
        # until frames have shown otherwise, the trackers are taken to jitter by the prior
        weight = n + self.prior_frames
        sigma = max((n * measured + self.prior_frames * self.prior) / weight - self.floor, 0.0) if weight else 0.0
        # smoothed: the median steps as frames enter and leave the window, and a gain that steps scales corrections
        self.smooth = sigma if self.smooth is None else self.smooth + SIGMA_RATE * (sigma - self.smooth)
        return self.smooth

    def update(self, e: np.ndarray, sigma: float, process: float, band_sigmas: float, band_min: float
               ) -> np.ndarray:
        """The filtered correction (3,) for the measured one e (3,): the follower at the steady gain
        (:attr:`gain`), then held within the band of e."""
        self.gain = steady_gain(sigma, process)
        c = self.follow.update(e, self.gain)
        band = max(band_min, band_sigmas * sigma)
        miss = e - c
        n = math.sqrt(float(miss @ miss))
        if n > band:
            c = self.follow.c = e - miss * (band / n)
        return c


class EffectorFit:
    """The causal end-effector fit (module docstring) for one recording: create per recording (or :meth:`reset`),
    then :meth:`apply` once per frame, in order."""

    def __init__(self, trackers: tuple[str, ...], has_rotation: np.ndarray, J_rest: np.ndarray, cfg: FitConfig,
                 *, fast: bool = True) -> None:
        self.cfg = cfg
        self.trackers = tuple(trackers)
        self.has_rot = np.asarray(has_rotation, bool)
        self.J_rest = np.asarray(J_rest, dtype=np.float64)
        self.offsets = self.J_rest - self.J_rest[[max(p, 0) for p in PARENTS]]
        self.offsets[0] = 0.0
        self.head = self.trackers.index("head") if "head" in self.trackers and cfg.head else None
        self.arms = [(s, self.trackers.index(f"{s}_wrist")) for s in ("left", "right")
                     if f"{s}_wrist" in self.trackers and cfg.wrists]
        two_bone_ik = None
        if fast:
            try:
                from smplik.tracking.kernels import two_bone_ik
            except ImportError:
                two_bone_ik = None
        if two_bone_ik is None:
            from smplik.limb_ik import two_bone_ik
        self.two_bone_ik = two_bone_ik
        self.reset()

    def reset(self) -> None:
        """Forget the recording so far (noise estimates and corrections)."""
        w = self.cfg.noise_window
        c = self.cfg
        self.pos = {k: _Band(w, c.jitter_floor_m, c.prior_jitter_m, c.prior_frames) for k in range(len(self.trackers))}
        self.rot = {k: _Band(w, math.radians(c.jitter_floor_deg), math.radians(c.prior_jitter_deg), c.prior_frames)
                    for k in range(len(self.trackers))}
        self.prev_R: dict[int, np.ndarray] = {}
        self.turned = {k: np.zeros(3) for k in range(len(self.trackers))}
        self.joints = {(k, j): _Follower() for k in range(len(self.trackers)) for j in range(24)}
        self.shift = _Follower()

    def _rotation_sigma(self, k: int, R: np.ndarray) -> float:
        """Jitter of tracker k's rotation: the band sees the sum of its frame-to-frame rotation vectors (an
        unwrapped rotation), whose second differences are the increments' changes."""
        prev = self.prev_R.get(k)
        self.prev_R[k] = R
        if prev is not None:
            self.turned[k] = self.turned[k] + matrix_to_rotvec(R @ prev.T)
        return self.rot[k].sigma(self.turned[k])

    def _position(self, k: int, target: np.ndarray, current: np.ndarray, process: float) -> np.ndarray:
        c = self.cfg
        sigma = self.pos[k].sigma(target)
        if c.joint_filter:  # the target as measured; the joints' changes are followed instead (:meth:`_follow`)
            self.pos[k].gain = steady_gain(sigma, process)
            return target
        return current + self.pos[k].update(target - current, sigma, process, c.band_sigmas, c.band_min_m)

    def _follow(self, R: np.ndarray, G: np.ndarray, p: np.ndarray, k: int, joints: tuple[int, ...],
                before: np.ndarray) -> None:
        """Replace the fit's change of each joint's local rotation (from ``before`` (n, 3, 3)) by its followed
        version at tracker k's gain, root first, in place."""
        for n, j in enumerate(joints):
            d = self.joints[k, j].update(matrix_to_rotvec(R[j] @ before[n].T), self.pos[k].gain)
            turn_subtree(R, G, p, j, G[PARENTS[j]] @ rotvec_to_matrix(d) @ before[n] @ G[j].T, SUBTREE, _PARENTS)

    def _rotation(self, k: int, R_target: np.ndarray, G: np.ndarray) -> np.ndarray:
        c = self.cfg
        sigma = self._rotation_sigma(k, R_target)
        e = matrix_to_rotvec(R_target @ G.T)
        corr = self.rot[k].update(e, sigma, math.radians(c.process_deg), c.band_sigmas, math.radians(c.band_min_deg))
        return rotvec_to_matrix(corr) @ G

    def _bend_and_aim(self, R: np.ndarray, G: np.ndarray, p: np.ndarray, k: int, ja: int, jb: int, jw: int,
                      target: np.ndarray) -> None:
        """Two-bone arm IK with the elbow's change followed at tracker k's gain: the elbow opens or closes by the
        followed change of its angle (what reaching the target needs, less the network's bend), then the shoulder
        aims the wrist at the target. Under jitter the elbow, whose angle the arm's length to the target sets
        (sensitively near full extension), stays smooth; the wrist still points at the target."""
        u, v = p[ja] - p[jb], p[jw] - p[jb]
        l1, l2 = math.sqrt(float(u @ u)), math.sqrt(float(v @ v))
        n = np.cross(u, v)
        nn = math.sqrt(float(n @ n))
        normal = n / nn if nn > 1e-9 * l1 * l2 else G[jb][:, 1] / max(np.linalg.norm(G[jb][:, 1]), 1e-12)
        theta0 = math.atan2(nn, float(u @ v))
        d = min(max(float(np.linalg.norm(target - p[ja])), abs(l1 - l2) + 1e-6), l1 + l2 - 1e-6)
        theta1 = math.acos(min(max((l1 * l1 + l2 * l2 - d * d) / (2.0 * l1 * l2), -1.0), 1.0))
        delta = self.joints[k, jb].update(np.array([theta1 - theta0, 0.0, 0.0]), self.pos[k].gain)[0]
        turn_subtree(R, G, p, jb, rotvec_to_matrix(normal * delta), SUBTREE, _PARENTS)
        turn_subtree(R, G, p, ja, swing_matrix(p[jw] - p[ja], target - p[ja], 1.0), SUBTREE, _PARENTS)

    def apply(self, R_local: np.ndarray, transl: np.ndarray, p_trk: np.ndarray, R_trk: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One pose, fitted: R_local (24, 3, 3) (root in world), transl (3,), the frame's trackers p_trk (K, 3) and
        world rotations R_trk (K, 3, 3) in :attr:`trackers` order -> ``(R_local, transl, R_world (24, 3, 3), joints
        (24, 3))``, float64."""
        R = np.array(R_local, dtype=np.float64)
        transl = np.array(transl, dtype=np.float64)
        G, p = np.empty((24, 3, 3)), np.empty((24, 3))
        forward_kinematics(R, transl, self.offsets, self.J_rest[0], _PARENTS, G, p)
        p_trk = np.asarray(p_trk, dtype=np.float64)
        R_trk = np.asarray(R_trk, dtype=np.float64)
        if self.head is not None:
            k = self.head
            target = self._position(k, p_trk[k], p[HEAD], self.cfg.head_process_m)
            target = p[HEAD] + self.pos[k].gain * (target - p[HEAD])  # under jitter the network's head is close
            before = R[_SPINE]
            spine_ccd(R, G, p, target, _SPINE, HEAD, self.cfg.spine_passes, SUBTREE, _PARENTS)
            if self.cfg.joint_filter:
                self._follow(R, G, p, k, SPINE, before)
            if self.cfg.root_shift:  # what the spine cannot reach (it does not stretch): the whole body moves
                gain = self.pos[k].gain  # scaled by the gain too: under jitter the spine's remainder is mostly noise
                shift = gain * self.shift.update(target - p[HEAD], gain)
                transl = transl + shift
                p += shift
            if self.has_rot[k]:
                G_head = self._rotation(k, R_trk[k], G[HEAD])
                turn_subtree(R, G, p, HEAD, G_head @ G[HEAD].T, SUBTREE, _PARENTS)
        if self.arms:
            rows = []
            for side, k in self.arms:
                _, a, b, w = ARMS[side]
                rows.append(self._position(k, p_trk[k], p[w], self.cfg.process_m))
            chains = np.array([ARMS[s][1:] for s, _ in self.arms])
            a, b, w = chains.T
            R_a, R_b = self.two_bone_ik(p[a], p[b], p[w], np.stack(rows), G[b][:, :, 1])
            for i, (side, k) in enumerate(self.arms):
                _, ja, jb, jw = ARMS[side]
                before = R[[ja, jb]]
                if self.cfg.bend_filter and not self.cfg.joint_filter:
                    self._bend_and_aim(R, G, p, k, ja, jb, jw, rows[i])
                else:
                    turn_subtree(R, G, p, ja, R_a[i], SUBTREE, _PARENTS)
                    turn_subtree(R, G, p, jb, R_a[i] @ R_b[i] @ R_a[i].T, SUBTREE, _PARENTS)
                if self.cfg.joint_filter:
                    self._follow(R, G, p, k, (ja, jb), before)
                if self.has_rot[k]:
                    G_w = self._rotation(k, R_trk[k], G[jw])
                    turn_subtree(R, G, p, jw, G_w @ G[jw].T, SUBTREE, _PARENTS)
        return R, transl, G, p
