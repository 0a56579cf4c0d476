"""Configuration of the tracking model (full body from a few VR trackers): one frozen dataclass per component.

Torch-free, so that the CLI can read defaults without importing torch.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

TRACKER_SETS: dict[str, tuple[str, ...]] = {
    "4": ("head", "left_wrist", "right_wrist", "pelvis"),
    "3": ("head", "left_wrist", "right_wrist"),
}
"""Named tracker sets: SMPL joint names, in the network's input order."""

FEATURES_PER_TRACKER = 13
"""Per tracker and frame: position (3), velocity (3), rotation 6D (6), rotation-present flag (1)."""


@dataclass(frozen=True)
class TrackingNetConfig:
    """The conditional VAE over tracker sequences (:class:`smplik.tracking.network.TrackingNet`)."""

    trackers: tuple[str, ...] = TRACKER_SETS["4"]
    """Tracked SMPL joints, in input order; the first one is the heading reference and needs a rotation."""
    hidden: int = 192
    """Width of the condition encoder and of its GRU state."""
    decoder: int = 256
    """Width of the decoder MLP (run once per sample)."""
    latent: int = 16
    """Size of the latent z (per frame; a sample keeps its noise vector over time)."""
    kind: Literal["cvae", "mlp"] = "cvae"
    """``cvae``: the GRU conditional VAE; ``mlp``: the AvatarPoser-style per-frame MLP over a window (baseline)."""
    window: int = 20
    """Frames of tracker features the ``mlp`` baseline sees (ignored by ``cvae``)."""
    fps: float = 60.0
    """Tracker rate the model was trained at."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any) -> TrackingNetConfig:
        """A config from its dict (a model file's ``info.net``), every value checked for type and range
        (:data:`TRACKING_NET_RANGES`, trackers SMPL joint names, ``fps`` a frame rate): ``ValueError`` naming the
        key otherwise, so a file cannot make a 16,000-wide network or divide by a zero frame rate."""
        from smplik.conventions import JOINT_NAMES
        from smplik.limits import check_rate

        if not isinstance(d, dict):
            raise ValueError(f"net: expected an object, got {type(d).__name__}.")
        names = {f for f in cls.__dataclass_fields__}
        unknown = sorted(str(k) for k in set(d) - names)
        if unknown:
            raise ValueError(f"net.{unknown[0]}: unknown key (expected {', '.join(sorted(names))}).")
        values = dict(d)
        for key, (lo, hi) in TRACKING_NET_RANGES.items():
            if key in values:
                v = values[key]
                if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                    raise ValueError(f"net.{key}: expected a whole number in [{lo}, {hi}], got {str(v)[:40]!r}.")
        if "kind" in values and values["kind"] not in ("cvae", "mlp"):
            raise ValueError(f"net.kind: expected 'cvae' or 'mlp', got {str(values['kind'])[:40]!r}.")
        if "fps" in values:
            values["fps"] = check_rate(values["fps"], "net.fps")
        if "trackers" in values:
            trackers = values["trackers"]
            if (not isinstance(trackers, (list, tuple)) or not 1 <= len(trackers) <= len(JOINT_NAMES)
                    or not all(isinstance(t, str) and t in JOINT_NAMES for t in trackers)
                    or len(set(trackers)) != len(trackers)):
                raise ValueError(f"net.trackers: expected distinct SMPL joint names, got {str(trackers)[:60]}.")
            values["trackers"] = tuple(trackers)
        return cls(**values)


TRACKING_NET_RANGES: dict[str, tuple[int, int]] = {"hidden": (1, 1024), "decoder": (1, 2048), "latent": (1, 256),
                                                   "window": (1, 240)}
"""Accepted ranges of a tracking model's sizes (a model file's ``info.net``; the shipped models use 192, 256, 16,
20): at the largest, the network's weights stay under 100 MB."""


@dataclass(frozen=True)
class TrackingTrainConfig:
    """Training of :class:`TrackingNetConfig` on a pose cache (:mod:`smplik.tracking.train`)."""

    cache: str = ""
    """Pose cache (``smplik data build --fps 60``) with train and validation splits."""
    net: TrackingNetConfig = field(default_factory=TrackingNetConfig)
    """The network."""
    batch: int = 24
    """Windows per batch."""
    length: int = 64
    """Frames per training window (the GRU starts from a zero state at its first frame)."""
    lr: float = 1e-3
    """Adam learning rate (cosine decay to 5 % over ``minutes``)."""
    minutes: float = 25.0
    """Wall-clock training budget."""
    max_steps: int = 1_000_000
    """Step budget (whichever of the two ends first)."""
    kl_weight: float = 1e-3
    """Weight of the KL(q || p) term (summed over latent dimensions, mean over frames)."""
    free_bits: float = 0.25
    """KL below this many nats per latent dimension (batch mean) is not penalised (keeps the latent in use)."""
    contact_weight: float = 0.1
    """Weight of the foot-contact binary cross-entropy (the paper's gamma)."""
    rotation_weight: float = 0.1
    """Weight of the local 6D rotation L1 term."""
    matrix_weight: float = 1.0
    """Weight of the L1 of the normalised local rotation matrices (what the pose shows: penalises a joint twisted
    by pi and undone by its child, which the 6D L1 of small raw columns barely sees)."""
    foot_weight: float = 1.0
    """Weight of the contact-aware foot loss: predicted ankle and foot speed (m/s / 10) on the truth's contact
    frames (feet that should stand still)."""
    leg_weight: float = 1.0
    """Extra weight of the leg joints' (hips to feet) position error (the trackers say least about them)."""
    velocity_weight: float = 1.0
    """Weight of the joint-velocity term (positions in the heading frame, frame to frame)."""
    noise_m: float = 0.01
    """Upper bound of the per-window tracker position noise (Gaussian sigma drawn in [0, noise_m])."""
    rotation_dropout: float = 0.1
    """Probability that a non-reference tracker comes without rotation in a window."""
    beta_noise: float = 1.0
    """Body shape: dataset beta plus this times N(0, I) (BVH clips: N(0, I)), gender uniform (DESIGN section 4)."""
    validate_every: int = 250
    """Steps between validations (deterministic MPJPE on fixed validation windows; the best is kept)."""
    seed: int = 0
    """Seed of the batch stream and initialisation."""
    threads: int = 1
    """Torch CPU threads."""
    device: str = "cpu"
    """Torch device of the network and its batches (``"cuda"`` on a GPU machine); batches are drawn on the CPU."""
    workers: int = 0
    """Processes drawing batches in the background (0: drawn in the training loop). Each worker has its own seeded
    batch stream, so a run with workers is reproducible for a given worker count, not equal to one without."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class FitConfig:
    """The end-effector fit (:mod:`smplik.tracking.fit`): head and wrists onto their trackers through a noise band."""

    head: bool = True
    """Bend the spine (CCD over spine1 to neck) to bring the head joint to its tracker, and give the head the
    tracker's rotation."""
    wrists: bool = True
    """Two-bone arm IK to the wrist trackers, and the wrists' rotations from theirs."""
    noise_window: int = 60
    """Frames over which each tracker's jitter is estimated (median of its second differences)."""
    jitter_floor_m: float = 0.002
    """Tracker jitter (sigma, metres) below this counts as none (gain 1: the fit follows exactly); the jitter
    above it sets the gain. Exact trackers of real motion show well under it (fast motion's own second
    differences), 1 cm of noise far above."""
    jitter_floor_deg: float = 0.5
    """The same for rotations (degrees)."""
    process_m: float = 0.003
    """How far (metres per frame) the network's miss may drift: the random walk of the steady-state Kalman gain
    (gain 1 on exact trackers; about 0.3 under 1 cm of jitter)."""
    process_deg: float = 1.5
    """The same for rotations (degrees per frame)."""
    band_sigmas: float = 6.0
    """The correction stays within this many jitter sigmas of the measured one ..."""
    band_min_m: float = 0.005
    """... and at least within this many metres (the hands' and head's largest miss on exact trackers) ..."""
    band_min_deg: float = 2.0
    """... or degrees for rotations."""
    spine_passes: int = 3
    """CCD passes over the spine for the head."""
    root_shift: bool = True
    """Move the whole body (the root's translation) by what the spine leaves of the head's miss."""
    bend_filter: bool = True
    """Arms: follow the elbow's change of angle at the wrist tracker's gain, then aim the arm at the target
    (the elbow's angle is what the target's distance sets, sensitively near full extension: under jitter it would
    swing); False: plain two-bone IK to the target."""
    joint_filter: bool = False
    """Follow the fit's changes of the spine, shoulder and elbow rotations (rotation vectors) at the tracker's gain
    instead of filtering the targets (smoother under jitter, but slow to follow: an ablation; gain 1, no effect,
    on exact trackers)."""


@dataclass(frozen=True)
class TrackerRuntimeConfig:
    """Streaming inference (:class:`smplik.tracking.runtime.Tracker`)."""

    samples: int = 1
    """Latent samples run in one batch; 1 = deterministic (the prior's mean), no look-ahead."""
    lookahead: int = 10
    """Frames of look-ahead (tau) for sample selection when ``samples`` > 1 (output latency)."""
    blend: int = 10
    """Frames over which the latent noise is interpolated when switching samples."""
    contact_threshold: float = 0.5
    """Predicted contact probability above which a foot is locked (streaming locks; the offline locks use
    ``contact_on`` / ``contact_off``)."""
    release_frames: int = 5
    """Frames over which a released foot blends back from its lock to the network's foot."""
    lock_height_m: float = 0.12
    """A contact locks a foot only while the network's foot is at most this far above the floor."""
    lock_speed_mps: float = 0.35
    """... and slower than this (the animation pipeline's contact speed); a lock holds below 1.5 times it."""
    lock_drift_m: float = 0.08
    """A lock is released when the network's foot moves farther than this from it (a contact the pose disagrees
    with is dropped rather than stretching the leg)."""
    floor_y: float = 0.0
    """Floor height (y up, metres) for the anomaly score's below-floor term and the foot locks' height."""
    seed: int = 0
    """Seed of the latent noise vectors (sample 0 is always the zero vector: the prior's mean)."""
    fast: bool = True
    """Run the per-frame geometry (features, 6D -> FK, anomaly score, leg IK) as numba kernels
    (:mod:`smplik.tracking.kernels`) when numba is installed; False (or no numba): the numpy reference."""
    foot_lock: bool = True
    """Lock feet on predicted contacts (two-bone leg IK)."""
    offline_lock: bool = True
    """When the whole recording is known (:func:`smplik.tracking.runtime.track_sequence`, ``smplik track``), lock
    the feet offline (:func:`smplik.tracking.runtime.offline_foot_lock`) instead of causally; :meth:`Tracker.step`
    stays causal either way."""
    contact_on: float = 0.35
    """Offline locks: a contact segment starts where the predicted probability exceeds this ..."""
    contact_off: float = 0.3
    """... and ends where it falls below this (hysteresis)."""
    min_contact_frames: int = 4
    """Offline locks: contact segments shorter than this are dropped."""
    lock_spread_m: float = 0.4
    """Offline locks: a segment over which the network's foot strays farther than this (horizontally) from its
    median is not locked (the pose disagrees with the contact; locking it would stretch the leg)."""
    lock_blend_frames: int = 15
    """Offline locks: frames before and after a segment over which the lock is blended in and out (smoothstep)."""
    lock_reach: float = 0.98
    """Offline locks: the farthest the ankle may be from the hip, as a share of the leg's length; beyond it the foot
    pivots about its foot joint (heel rise) instead of straightening the knee. 1 (or more): no heel rise."""
    lock_smooth_frames: float = 1.5
    """Offline locks: Gaussian sigma (frames) over which the legs' lock corrections are smoothed in time (0: off)."""
    lock_repin: bool = True
    """Offline locks: after smoothing (``lock_smooth_frames`` > 0), pin the feet again on the contact segments'
    frames (the blends keep the smoothed legs)."""
    lock_centre: str = "median"
    """Offline locks: the lock's height, ``"median"`` (the median of the network's foot over the segment, like the
    horizontal position) or ``"min"`` (the segment's low point)."""
    effector_fit: bool = True
    """Put the head and the wrists on their trackers with the causal, noise-banded end-effector fit
    (:mod:`smplik.tracking.fit`, settings in ``fit``); legs and root untouched."""
    fit: FitConfig = field(default_factory=FitConfig)
    """Settings of the end-effector fit."""
    tracker_fit: bool = False
    """Meet the trackers exactly where the skeleton allows: the root from the pelvis tracker (position, and
    rotation when given), the wrists by two-bone arm IK to their positions and their rotations (when given), the
    head's rotation (the paper's suggested extra IK pass on the arms). Off by default: it lowers the error on exact
    trackers but passes tracker noise straight through and unlocks feet (benchmarks/results/tracking.json,
    ``ours_fit``); ``effector_fit`` is the one to use."""
