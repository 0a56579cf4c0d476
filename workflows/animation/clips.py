"""A video's estimates -> per-track animations on the chosen body or custom character (``smplik scene animate``).

Steps (:func:`animate_file`):

1. **Read every frame** with the estimator readers (:func:`workflows.estimators.people_from_data`,
   the same per-frame rule as ``scene from-estimate --frame N``), the file loaded once. People are
   grouped into tracks by the estimator's track id. A track's frames must be contiguous (a gap is an
   error naming the missing frames); with ``--frames A:B`` every kept track must cover A..B-1.
2. **Body per track**: the track's mean betas and first gender at scale 1, or the custom
   character's SMPL-SI body (``betas``, ``gender``, ``scale``); each frame is retargeted onto it as
   ``from-estimate`` does (:func:`workflows.scene.pipeline.retarget_to_body`: local rotations kept, pelvis
   at its world position).
3. **Cleaning** (:mod:`workflows.animation.clean`): glitch repair, then (default) a sequence solve over all frames
   with the foot locks (:func:`workflows.animation.clean.sequence_clean`), or a filter and foot locking.
4. **Keyframes** (:func:`select_keyframes`): the first and last frame, then, worst interval first, the frame
   where interpolating the neighbouring keyframes' poses (slerp of local rotations, linear root)
   errs most, while that error (mean joint distance, character space) is above a threshold (at least the
   estimate's noise, :func:`keyframe_threshold`) and the keyframes are at most ``max_keyframe_share`` of the frames.
5. **Effectors on keyframes**: :func:`workflows.scene.recovery.recover_many` on all keyframes of all
   tracks in one batch.

Spaces: as in scenes, poses are in SMPL space (character = SMPL body scaled by ``scale``), effectors in
character space; the world is the estimator's world trajectory when it gives one (WHAM and GVHMR by
default, ``--space camera`` for their camera frame; AIST++, AMASS), else its camera frame (converted to y-up).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from smplik.conventions import Gender
from smplik.effectors import Effector
from smplik.pose import Pose
from smplik.rotations import axis_angle_to_matrix_np, matrix_to_axis_angle_scipy
from workflows.animation.clean import (
    FOOT_JOINTS,
    CleanConfig,
    bridge_short_gaps,
    floor_plane,
    foot_contacts,
    foot_noise,
    glitch_frames,
    ground_drift,
    ground_of,
    height_above_floor,
    lock_feet,
    lock_plan,
    root_shift_from_locks,
    sequence_clean,
    smooth_motion,
    split_on_lift,
    stance_noise,
    trim_sliding_runs,
    turn_from_locks,
)
from workflows.animation.options import AnimationError, parse_frames  # noqa: F401 (re-exported)
from workflows.estimators.base import CameraInfo, EstimatedPerson, EstimateFormatError
from workflows.scene import SkeletonSource
from workflows.scene.recovery import RecoveryConfig, TargetPose, TensorSolver

MAX_FRAMES = 100_000
"""Most frames read from one file by default (55 minutes at 30 frames/s; ``max_frames`` raises it)."""
NORMAL_FOV_DEG = 60.0
"""Field of view (degrees, over the larger image side) of the realistic camera a near-orthographic track is
placed for (:func:`realistic_depth`); a phone or action camera's video is about 55-75 degrees wide."""
NEAR_ORTHOGRAPHIC_FOV_DEG = 20.0
"""Cameras narrower than this (degrees) are treated as near-orthographic: 4D-Humans/PHALP (focal
5000/256 * max(W, H): 2.9 degrees) and HMR2-style crops. ROMP/BEV, VIBE (60), WHAM (the image diagonal), HybrIK
(1000/256 of the box width), TRAM (calibrated) and the world-trajectory formats are not touched."""
KNOWN_FPS = {"aist": 60.0}
"""Frame rates fixed by a format (AIST++ motions are 60 frames/s); AMASS files store theirs."""
ASSUMED_FPS = {"gvhmr": 30.0}
"""Frame rates assumed, with a note, when the file stores none and ``--fps`` is not given: GVHMR's demo
(``tools/demo/demo.py``) works on 30 frames/s video and its ``hmr4d_results.pt`` holds no rate."""




@dataclass(frozen=True)
class AnimateConfig:
    """Settings of :func:`animate_file` beyond the estimator reading options."""

    clean: CleanConfig = field(default_factory=CleanConfig)
    """Smoothing and foot locking."""
    keyframe_threshold_m: float = 0.03
    """Add a keyframe where interpolating the neighbouring ones errs more than this (mean joint error, m)."""
    max_keyframe_gap: int = 0
    """Also split any keyframe interval longer than this many frames (0: no limit)."""
    max_keyframe_share: float = 0.15
    """Most keyframes per track, as a share of its frames (the worst-interpolated intervals are split first; the
    threshold itself is also raised to the estimate's noise, :func:`keyframe_threshold`)."""
    recovery: RecoveryConfig = field(default_factory=lambda: RecoveryConfig(max_effectors=6, threshold=0.03))
    """Effector recovery on keyframes."""
    model_motion_smoothing: str | None = "none"
    """Smoothing of joint motion made by a model (HumanML3D joints or features, MDM, T2M-GPT: smooth already, so
    smoothing only moves the joints off their targets; on held-out CMU joints ``adaptive`` cost 4-9 mm of MPJPE for
    nothing, ``benchmarks/joints_to_smpl.py``) instead of ``clean.smoothing``; glitch repair and foot locks still
    run. None: ``clean.smoothing`` (``--smoothing`` given). A BVH's joints (a capture) use ``clean.smoothing``."""
    camera_fov_deg: float | None = NORMAL_FOV_DEG
    """Camera-space tracks from a near-orthographic camera (field of view below :data:`NEAR_ORTHOGRAPHIC_FOV_DEG`,
    e.g. 4D-Humans/PHALP): place the body as a camera of this field of view (over the larger image side) sees it
    at the same pixel with the same apparent size (:func:`realistic_depth`); None keeps the estimator's depth."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.keyframe_threshold_m) and self.keyframe_threshold_m > 0):
            raise AnimationError(f"keyframe threshold must be a positive number of metres, got "
                                 f"{self.keyframe_threshold_m}.")
        if self.camera_fov_deg is not None and not (np.isfinite(self.camera_fov_deg)
                                                    and NEAR_ORTHOGRAPHIC_FOV_DEG <= self.camera_fov_deg < 170):
            raise AnimationError(f"camera field of view must be in [{NEAR_ORTHOGRAPHIC_FOV_DEG:g}, 170) degrees, got "
                                 f"{self.camera_fov_deg}.")
        if not 0 < self.max_keyframe_share <= 1:
            raise AnimationError(f"max keyframe share must be in (0, 1], got {self.max_keyframe_share}.")
        if self.max_keyframe_gap < 0:
            raise AnimationError(f"max keyframe gap must be >= 0, got {self.max_keyframe_gap}.")


@dataclass(frozen=True)
class Keyframe:
    """Recovered effectors (character space) at one frame and the mean joint error of their solve (m)."""

    frame: int
    effectors: tuple[Effector, ...]
    error_m: float


@dataclass(frozen=True)
class AnimationTrack:
    """One person's animation. Arrays are per frame of the track (T frames from ``first_frame``), SMPL space.

    Attributes:
        global_orient: (T, 3) axis-angle; body_pose: (T, 23, 3); transl: (T, 3) smplx translation.
        contacts: (T, 2) bool foot contacts (left, right), or None when not detected.
        repaired: source frames whose estimate was an implausible glitch, replaced by interpolation.
        keyframes: sorted by frame (source frame numbers, within the track's frames).
    """

    name: str
    track_id: str
    gender: Gender
    betas: np.ndarray
    scale: float
    skeleton: SkeletonSource | None
    first_frame: int
    global_orient: np.ndarray
    body_pose: np.ndarray
    transl: np.ndarray
    keyframes: tuple[Keyframe, ...] = ()
    contacts: np.ndarray | None = None
    repaired: tuple[int, ...] = ()
    """Source frames flagged as glitches and replaced by interpolating their neighbours."""

    @property
    def num_frames(self) -> int:
        return int(self.global_orient.shape[0])

    @property
    def frames(self) -> range:
        """The source frame numbers of the track's rows."""
        return range(self.first_frame, self.first_frame + self.num_frames)

    def pose(self, row: int) -> Pose:
        """Row ``row`` (0-based within the track) as a :class:`~smplik.pose.Pose`."""
        return Pose(self.global_orient[row].copy(), self.body_pose[row].copy(), self.transl[row].copy(),
                    np.asarray(self.betas, dtype=np.float64).copy(), self.gender)

    def poses(self) -> list[Pose]:
        return [self.pose(i) for i in range(self.num_frames)]


@dataclass(frozen=True)
class Animation:
    """Tracks plus what they came from: the source file and format, frame rate, space and camera."""

    tracks: tuple[AnimationTrack, ...]
    fps: float
    source: str | None = None
    source_format: str | None = None
    space: str = "camera"
    camera: CameraInfo | None = None
    clean: CleanConfig | None = None
    depth_change: DepthChange | None = field(default=None, compare=False)
    """How the reading placed a near-orthographic camera's track at a realistic depth (:func:`realistic_depth`;
    not stored in the animation file, whose camera is already the realistic one)."""
    notes: tuple[str, ...] = field(default=(), compare=False)
    """What the reading assumed (a frame rate, a file read as a sequence, a folder's frames), one line each; not
    stored in the animation file."""


# ----------------------------------------------------------------------------- reading a clip


def clip_length(data: Any, fmt: str, space: str | None = None) -> int:
    """How many video frames a loaded estimator file holds (1 for single-image formats)."""
    try:
        if fmt == "gvhmr":
            from workflows.estimators.gvhmr import _nest

            params = _nest(data)["smpl_params_global" if space == "world" else "smpl_params_incam"]
            return len(params["body_pose"])
        if fmt == "wham":
            return 1 + max(int(np.max(t.get("frame_ids", np.arange(len(t["pose"]))))) for t in data.values())
        if fmt == "phalp":
            return len(data)
        if fmt in ("romp", "bev") and isinstance(data.get("results"), dict) and "smpl_thetas" not in data["results"]:
            return len(data["results"])
        if fmt == "hybrik":
            return len(data["pred_thetas"])
        if fmt == "aist":
            return len(data["smpl_poses"])
        if fmt == "amass":
            return len(data["poses"])
        if fmt == "humandata":
            from workflows.estimators.humandata import frames_of

            return len(frames_of(data))
        if fmt == "plain":
            from workflows.estimators.plain import sequence_length

            return sequence_length(data) or 1
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError):  # inf/1e300 frame ids, ...
        pass  # the per-frame reader names the problem
    return 1


def frames_present(data: Any, fmt: str) -> list[int] | None:
    """The frame numbers a sparse format holds (WHAM: the union of its tracks' ``frame_ids``), else None (every
    frame of :func:`clip_length`)."""
    if fmt != "wham" or not isinstance(data, dict):
        return None
    ids: set[int] = set()
    for t in data.values():
        if isinstance(t, dict) and "frame_ids" in t:
            try:
                ids.update(int(f) for f in np.asarray(t["frame_ids"]).reshape(-1)[:MAX_FRAMES + 1] if f >= 0)
            except (TypeError, ValueError, OverflowError):
                return None  # the reader names the problem
        elif isinstance(t, dict) and "pose" in t:
            ids.update(range(min(len(t["pose"]), MAX_FRAMES + 1)))
    return sorted(ids)


def stored_fps(data: Any, fmt: str, source: str = "clip") -> float | None:
    """The frame rate a file states or its format fixes (AMASS ``mocap_framerate``, AIST++ 60), else None; a stated
    rate outside [``MIN_FPS``, ``MAX_FPS``] (:mod:`smplik.limits`) is refused naming ``source`` and the key."""
    if fmt == "amass":
        from smplik.limits import LimitError, check_rate

        for key in ("mocap_framerate", "mocap_frame_rate"):
            if isinstance(data, dict) and key in data:
                values = np.asarray(data[key]).reshape(-1)
                if values.size != 1 or values.dtype.kind not in "iuf":
                    raise AnimationError(f"{source}: {key}: must be one number (frames per second), got "
                                         f"{values.size} values of {values.dtype}.")
                try:
                    return check_rate(float(values[0]), f"{source}: {key}")
                except LimitError as exc:
                    raise AnimationError(str(exc)) from None
    return KNOWN_FPS.get(fmt)


def has_world_trajectory(data: Any, fmt: str) -> bool:
    """Whether a WHAM / GVHMR output holds its world-frame trajectory (WHAM ``pose_world``/``trans_world`` in
    every track, GVHMR ``smpl_params_global``)."""
    if fmt == "gvhmr":
        from workflows.estimators.gvhmr import _nest

        return isinstance(_nest(data), dict) and "smpl_params_global" in _nest(data)
    if fmt == "wham":
        return isinstance(data, dict) and all(isinstance(t, dict) and "pose_world" in t and "trans_world" in t
                                              for t in data.values())
    return False


@dataclass(frozen=True)
class Clip:
    """Every frame's people of an estimator file, grouped by track id (each track's rows in frame order)."""

    source: str
    format: str
    length: int
    tracks: dict[str, list[tuple[int, EstimatedPerson]]]
    fps: float | None
    space: str
    notes: tuple[str, ...] = ()
    """The readers' notes (:class:`workflows.estimators.pose_array.EstimateNote`), each once."""


def _noted(read: Callable[[], Any], notes: dict[str, None]) -> Any:
    """``read()``, its readers' notes (EstimateNote warnings) collected into ``notes`` instead of shown."""
    import warnings

    from workflows.estimators.pose_array import EstimateNote

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", EstimateNote)
        out = read()
    for w in caught:
        if issubclass(w.category, EstimateNote):
            notes.setdefault(str(w.message), None)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return out


def read_folder_clip(path: Path, *, format: str = "auto", trust_pickle: bool = False, space: str | None = None,
                     max_people: int | None = None, max_bytes: int | None = None, solver: Any = None,
                     frames: tuple[int, int] | None = None, max_frames: int = MAX_FRAMES) -> Clip:
    """:func:`read_clip` of a folder of per-frame outputs (:mod:`workflows.estimators.reading`): every frame read,
    moved into the first person's camera, people linked into tracks by nearest pelvis."""
    from workflows.estimators.reading import match_tracks, read_folder_frame, scan_folder, to_camera

    notes: dict[str, None] = {}
    folder = scan_folder(path, format=format, trust_pickle=trust_pickle, max_bytes=max_bytes)
    length = folder.length
    if frames is not None and frames[1] > length:
        raise AnimationError(f"{path}: --frames {frames[0]}:{frames[1]} is outside the clip (frames 0..{length - 1}).")
    start, stop = frames if frames is not None else (0, length)
    wanted = [f for f in range(start, stop) if f in folder.files]
    if len(wanted) > max_frames:
        raise AnimationError(f"{path}: {len(wanted)} frames to read; refusing more than {max_frames} "
                             "(--frames A:B reads a part; max_frames / --max-frames raises the cap).")
    per_frame = []
    camera = None
    for f in wanted:
        people = _noted(lambda f=f: read_folder_frame(folder, f, trust_pickle=trust_pickle, max_people=max_people,
                                                      max_bytes=max_bytes, space=space, solver=solver), notes)
        if people and camera is None:
            camera = people[0].camera
        per_frame.append((f, [to_camera(p, camera) for p in people]))
    tracks = match_tracks(per_frame)
    if not tracks:
        raise AnimationError(f"{path}: no people in frames {start}..{stop - 1}.")
    first = folder.describe(0).split(";")[0]
    notes = {f"{first}; {len(tracks)} track(s) linked across frames by nearest pelvis": None, **notes}
    is_world = folder.format in ("aist", "amass")
    return Clip(str(path), folder.format, length, tracks, None, "world" if is_world else "camera", tuple(notes))


def read_clip(path: str | Path, *, format: str = "auto", trust_pickle: bool = False, space: str | None = None,
              max_people: int | None = None, max_bytes: int | None = None, solver: Any = None,
              frames: tuple[int, int] | None = None, max_frames: int = MAX_FRAMES,
              progress: Callable[[int, int, str], None] | None = None) -> Clip:
    """Read the people of every frame (or frames A..B-1; at most ``max_frames``) of an estimator file, by track;
    ``progress(done, total, "reading frames")`` is called every 1 % of the frames."""
    from workflows.estimators import MAX_BYTES, _load_raw, detect_format

    path = Path(path)
    if path.is_dir():
        return read_folder_clip(path, format=format, trust_pickle=trust_pickle, space=space, max_people=max_people,
                                max_bytes=max_bytes, solver=solver, frames=frames, max_frames=max_frames)
    if not path.is_file():
        raise EstimateFormatError(f"Estimator output not found: {path}")
    data = _load_raw(path, trust_pickle, MAX_BYTES if max_bytes is None else max_bytes)
    fmt = detect_format(data) if format == "auto" else format
    fps = stored_fps(data, fmt, str(path))  # checked before any frame is read
    if fmt in ("wham", "gvhmr"):
        if space is None:  # an animation follows the world trajectory when the estimator gives one
            space = "world" if has_world_trajectory(data, fmt) else "camera"
        elif space == "world" and not has_world_trajectory(data, fmt):
            raise AnimationError(f"{path}: this {fmt} output has no world trajectory; use --space camera.")
    is_world = space == "world" and fmt in ("wham", "gvhmr") or fmt in ("aist", "amass")
    length = clip_length(data, fmt, space)
    if frames is not None and frames[1] > length:
        raise AnimationError(f"{path}: --frames {frames[0]}:{frames[1]} is outside the clip (frames 0..{length - 1}).")
    start, stop = frames if frames is not None else (0, length)
    present = frames_present(data, fmt)
    wanted = range(start, stop) if present is None else [f for f in present if start <= f < stop]
    if len(wanted) > max_frames:
        raise AnimationError(f"{path}: {len(wanted)} frames to read; refusing more than {max_frames} "
                             "(--frames A:B reads a part; max_frames / --max-frames raises the cap).")
    every = max(1, len(wanted) // 100)
    from workflows.estimators.base import reading_frames

    notes: dict[str, None] = {}
    if fmt == "phalp" and isinstance(data, dict) and data:  # frames are named: say how the numbers map to names
        names = sorted(data, key=str)
        notes[f"{path}: {length} frames, numbered 0..{length - 1} in name order (frame 0 is {str(names[0])!r}, "
              f"frame {length - 1} is {str(names[-1])!r}); --frames A:B counts the same way."] = None
    with reading_frames():  # each array converted once, not once per frame
        tracks = _read_frames(data, path, fmt, wanted, max_people, space, solver, progress, every, notes)
    if not tracks:
        raise AnimationError(f"{path}: no people in frames {start}..{stop - 1}.")
    return Clip(str(path), fmt, length, tracks, fps, "world" if is_world else "camera",
                tuple(notes))


def _read_frames(data: Any, path: Path, fmt: str, wanted: Sequence[int], max_people: int | None, space: str | None,
                 solver: Any, progress: Callable[[int, int, str], None] | None, every: int,
                 notes: dict[str, None]) -> dict[str, list[tuple[int, EstimatedPerson]]]:
    """The people of the ``wanted`` frames by track; the readers' notes are added to ``notes``."""
    from workflows.estimators import MAX_PEOPLE, people_from_data

    tracks: dict[str, list[tuple[int, EstimatedPerson]]] = {}
    for n, f in enumerate(wanted):
        if progress is not None and n % every == 0:
            progress(n, len(wanted), "reading frames")
        try:
            people = _noted(lambda f=f: people_from_data(
                data, source=str(path), format=fmt, frame=f,  # type: ignore[arg-type]
                max_people=MAX_PEOPLE if max_people is None else max_people,
                space=space, path=path, solver=solver), notes)  # type: ignore[arg-type]
        except EstimateFormatError as exc:
            if "no people" in str(exc) or "no track covers" in str(exc):
                continue  # an empty frame: the tracks' coverage is checked below
            raise
        for p in people:
            tracks.setdefault(str(p.person_id), []).append((f, p))
    return tracks


def check_track(track_id: str, rows: list[tuple[int, EstimatedPerson]], frames: tuple[int, int] | None,
                source: str) -> None:
    """A track must cover its frames without gaps (and all of ``frames`` A..B-1 when given)."""
    have = [f for f, _ in rows]
    first, last = have[0], have[-1]
    if frames is not None and (first > frames[0] or last < frames[1] - 1):
        where = f"starts at frame {first}" if first > frames[0] else f"ends at frame {last}"
        raise AnimationError(f"{source}: track {track_id} {where}, inside the requested frames {frames[0]}.."
                             f"{frames[1] - 1} (choose --frames within the track's frames or another --track).")
    if len(have) != last - first + 1:
        missing: list[int] = []  # the first few missing frames, without enumerating a huge span
        for a, b in zip(have[:-1], have[1:], strict=True):
            missing += range(a + 1, min(b, a + 10))
            if len(missing) > 8:
                break
        shown = ", ".join(map(str, missing[:8])) + (", ..." if len(missing) > 8 else "")
        raise AnimationError(f"{source}: track {track_id} has no pose at frame(s) {shown} inside its span "
                             f"{first}..{last} (missing frames; choose --frames around them).")


def camera_fov(camera: CameraInfo | None) -> float | None:
    """A camera's field of view (degrees) over its image's larger side, None when unknown."""
    if camera is None:
        return None
    if camera.focal_px is None:
        return camera.default_fov_deg if camera.focal_rule == "fov" else None
    if camera.image_size is None:
        return None
    return float(np.degrees(2.0 * np.arctan(max(camera.image_size) / 2.0 / camera.focal_px)))


@dataclass(frozen=True)
class DepthChange:
    """How :func:`realistic_depth` moved a camera-space clip: ``factor`` times every pelvis's depth (x and y
    kept), from a ``fov_from_deg`` camera to a ``fov_to_deg`` one (focal lengths in pixels; median depths, m)."""

    factor: float
    fov_from_deg: float
    fov_to_deg: float
    focal_from_px: float
    focal_to_px: float
    depth_from_m: float
    depth_to_m: float

    def describe(self) -> str:
        """One line for the user."""
        return (f"depth: the estimator's camera is near-orthographic ({self.fov_from_deg:.1f} deg field of view, "
                f"focal {self.focal_from_px:.0f} px), so the body is placed for a {self.fov_to_deg:g} deg camera "
                f"(focal {self.focal_to_px:.0f} px; same pixels, same apparent size): median depth "
                f"{self.depth_from_m:.1f} m -> {self.depth_to_m:.2f} m (x{self.factor:.4f}, depth noise too)")


def realistic_depth(clip: Clip, camera: CameraInfo | None, fov_deg: float | None = NORMAL_FOV_DEG
                    ) -> tuple[Clip, CameraInfo | None, DepthChange | None]:
    """A camera-space clip from a near-orthographic camera, placed for a camera of a normal field of view.

    A pinhole camera of focal f sees a point (x, y, z) at pixel (f x / z, f y / z) + principal point, and a body
    of height h at depth z with apparent height f h / z. Scaling every pelvis's depth z by k = f' / f and
    keeping its x and y keeps both for the camera of focal f' (f' x / (k z) = f x / z): the same pixel position
    and apparent size, the depth (and its frame-to-frame noise, which a near-orthographic camera leaves almost
    unconstrained) k times smaller. Local rotations, and hence the pose, are unchanged.

    Returns the clip (unchanged when it is in a world frame, when ``fov_deg`` is None, or when its camera is
    not narrower than :data:`NEAR_ORTHOGRAPHIC_FOV_DEG` or unknown), its camera (the new focal length) and the
    change made (None when nothing changed).
    """
    fov_from = camera_fov(camera)
    if (clip.space != "camera" or fov_deg is None or camera is None or camera.focal_px is None
            or camera.image_size is None or fov_from is None or fov_from >= NEAR_ORTHOGRAPHIC_FOV_DEG):
        return clip, camera, None
    from workflows.estimators.base import rest_pelvis

    focal_to = max(camera.image_size) / 2.0 / np.tan(np.radians(fov_deg) / 2.0)
    k = float(focal_to / camera.focal_px)
    tracks, depths = {}, []
    for tid, rows in clip.tracks.items():
        people = [p for _, p in rows]
        pelvis = np.stack([p.transl for p in people])  # + J0(betas): (T, 3) camera frame (y up, -z forward)
        for gender in {p.gender for p in people}:
            rows_g = [i for i, p in enumerate(people) if p.gender == gender]
            pelvis[rows_g] += rest_pelvis(np.stack([people[i].betas for i in rows_g]), gender)
        moved = pelvis * [1.0, 1.0, k]
        depths.append(-pelvis[:, 2])
        new_camera = None if people[0].camera is None else dataclasses.replace(people[0].camera, focal_px=focal_to)
        tracks[tid] = [(f, dataclasses.replace(p, transl=p.transl + moved[i] - pelvis[i],
                                               camera=new_camera if p.camera is not None else None))
                       for i, (f, p) in enumerate(rows)]
    median = float(np.median(np.concatenate(depths)))
    change = DepthChange(k, fov_from, float(fov_deg), float(camera.focal_px), float(focal_to), median, k * median)
    return dataclasses.replace(clip, tracks=tracks), dataclasses.replace(camera, focal_px=focal_to), change


# ----------------------------------------------------------------------------- motion math


def axis_angle_to_local(global_orient: np.ndarray, body_pose: np.ndarray) -> np.ndarray:
    """(T, 3), (T, 23, 3) axis-angle -> local rotations (T, 24, 3, 3)."""
    aa = np.concatenate([global_orient[:, None], body_pose], axis=1)
    return axis_angle_to_matrix_np(aa)


def rest_joints(betas: np.ndarray, gender: Gender) -> np.ndarray:
    """Rest joints J(betas) (24, 3) of our body model, float64."""
    from smplik.body_model import load_body_model

    model = load_body_model(gender)
    return model.rest_joints(torch.as_tensor(np.asarray(betas), dtype=torch.float32)).double().numpy()


def joints_of(R_parent_joint: np.ndarray, transl: np.ndarray, J_rest: np.ndarray) -> np.ndarray:
    """Posed joints (T, 24, 3) of local rotations (T, 24, 3, 3), smplx transl (T, 3), rest joints (24, 3)."""
    from smplik.kinematics import forward_kinematics

    _, p = forward_kinematics(torch.as_tensor(R_parent_joint), torch.as_tensor(J_rest, dtype=torch.float64),
                              torch.as_tensor(transl, dtype=torch.float64))
    return p.numpy()


def interpolate_poses(R_a: np.ndarray, R_b: np.ndarray, t_a: np.ndarray, t_b: np.ndarray, w: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Slerp of local rotations (24, 3, 3) and lerp of transl (3,) at weights w (n,) -> (n, 24, 3, 3), (n, 3)."""
    rel = Rotation.from_matrix(np.swapaxes(R_a, -1, -2) @ R_b).as_rotvec()  # (24, 3)
    steps = Rotation.from_rotvec((w[:, None, None] * rel[None]).reshape(-1, 3)).as_matrix().reshape(-1, 24, 3, 3)
    return R_a[None] @ steps, (1.0 - w[:, None]) * t_a + w[:, None] * t_b


def select_keyframes(R_parent_joint: np.ndarray, transl: np.ndarray, J_rest: np.ndarray, threshold_m: float, *,
                     scale: float = 1.0, max_gap: int = 0, max_keys: int | None = None) -> list[int]:
    """Keyframe rows (sorted) of a motion (see the module docstring, step 4). Errors in character space
    (``scale`` times SMPL space). R_parent_joint (T, 24, 3, 3), transl (T, 3), J_rest (24, 3).

    The interval whose interpolation errs most is split first, so with ``max_keys`` (at least 2) the keyframes
    kept are those that matter most."""
    import heapq

    T = R_parent_joint.shape[0]
    if T <= 2:
        return list(range(T))
    p = joints_of(R_parent_joint, transl, J_rest)
    keys = {0, T - 1}
    heap: list[tuple[float, int, int, int]] = []

    def push(a: int, b: int) -> None:
        if b - a < 2:
            return
        rows = np.arange(a + 1, b)
        w = (rows - a) / (b - a)
        R_i, t_i = interpolate_poses(R_parent_joint[a], R_parent_joint[b], transl[a], transl[b], w)
        err = scale * np.linalg.norm(joints_of(R_i, t_i, J_rest) - p[rows], axis=-1).mean(-1)
        worst = int(np.argmax(err))
        if err[worst] > threshold_m:
            heapq.heappush(heap, (-float(err[worst]), int(rows[worst]), a, b))
        elif max_gap and b - a > max_gap:
            heapq.heappush(heap, (0.0, (a + b) // 2, a, b))

    push(0, T - 1)
    while heap and (max_keys is None or len(keys) < max(2, max_keys)):
        _, k, a, b = heapq.heappop(heap)
        keys.add(k)
        push(a, k)
        push(k, b)
    return sorted(keys)


def keyframe_threshold(raw: np.ndarray, clean: np.ndarray, threshold_m: float) -> float:
    """The keyframe threshold of a track (m): ``threshold_m``, raised to the estimate's noise (the mean joint
    distance between the raw and the cleaned joints, pelvis-aligned, the median over frames; raw, clean
    (T, 24, 3) character space): keyframes finer than the estimator's own noise would only follow it."""
    if raw.shape[0] == 0:
        return threshold_m
    moved = np.linalg.norm((raw - raw[:, :1]) - (clean - clean[:, :1]), axis=-1).mean(-1)
    return max(threshold_m, float(np.median(moved)))


# ----------------------------------------------------------------------------- the pipeline


Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class TrackMotion:
    """A track's motion before and after cleaning (joints in character space, metres) for reports."""

    name: str
    raw_joints: np.ndarray
    clean_joints: np.ndarray
    contacts: np.ndarray


def camera_clean(cfg: CleanConfig, space: str) -> CleanConfig:
    """The cleaning of a clip in ``space``: in a camera frame the ground may move through the frame (a camera
    following the person, a treadmill), so contacts and locks follow it (``ground_moves``)."""
    return dataclasses.replace(cfg, ground_moves=True) if space == "camera" else cfg


def repair_frames(R_parent_joint: np.ndarray, transl: np.ndarray, bad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Replace the rows flagged in ``bad`` (T,) by interpolating the nearest good rows on either side
    (slerp / lerp; at an end, the nearest good row). R (T, 24, 3, 3), transl (T, 3)."""
    R, t = R_parent_joint.copy(), transl.copy()
    good = np.nonzero(~bad)[0]
    if good.size == 0:
        return R, t
    for row in np.nonzero(bad)[0]:
        after = good[np.searchsorted(good, row):]
        before = good[:np.searchsorted(good, row)]
        a = before[-1] if before.size else after[0]
        b = after[0] if after.size else before[-1]
        w = np.array([0.0 if a == b else (row - a) / (b - a)])
        R_i, t_i = interpolate_poses(R_parent_joint[a], R_parent_joint[b], transl[a], transl[b], w)
        R[row], t[row] = R_i[0], t_i[0]
    return R, t


ROOT_SHIFT_BLEND_SHARE = 0.9
"""Share of ``blend_max_m`` a lock's blend may change the foot's offset by per frame when the root also moves by the
locks' offsets (:func:`root_shift_from_locks`, smooth but not still): the shift's own step stays within the rest."""


def clean_track(poses: Sequence[Pose], fps: float, cfg: CleanConfig, scale: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Repair glitches, smooth and foot-lock one track's poses (SMPL space, one body).

    Returns: local rotations (T, 24, 3, 3), transl (T, 3), contacts (T, 2), raw joints and clean joints
    (T, 24, 3) in character space, and the repaired glitch rows (T,) bool.
    """
    go = np.stack([p.global_orient for p in poses])
    bp = np.stack([p.body_pose for p in poses])
    transl = np.stack([p.transl for p in poses])
    J_rest = rest_joints(poses[0].betas, poses[0].gender)
    R = axis_angle_to_local(go, bp)
    raw = joints_of(R, transl, J_rest) * scale
    glitches = np.zeros(len(poses), dtype=bool)
    if cfg.repair_glitches:
        glitches = glitch_frames(raw, cfg.glitch_min_m, cfg.glitch_ratio, cfg.glitch_sigmas, R,
                                 cfg.glitch_rotation_sigmas)
        if glitches.any():
            R, transl = repair_frames(R, transl, glitches)
    if cfg.smoothing == "sequence":
        R_s, t_s, contacts = sequence_clean(R, transl, J_rest, fps, cfg, scale)
        return R_s, t_s, contacts, raw, joints_of(R_s, t_s, J_rest) * scale, glitches
    R_s, t_s = smooth_motion(R, transl, fps, cfg)
    p_s = joints_of(R_s, t_s, J_rest)
    noise = foot_noise(raw, p_s * scale, fps)
    ground = ground_of(p_s, fps, cfg, scale, noise)
    release = cfg.release_m
    if cfg.smoothing == "adaptive" and not cfg.ground_moves:  # its paths keep little of the raw noise: contacts
        noise = None  # on their own speed (in a camera frame the depth's slow wobble stays: the noise still counts)
        if cfg.stance_noise_ratio is not None:  # ... but what they keep moves a planted foot: the threshold and the
            # lift release grow with it (a clean estimate's planted feet barely move: 0.35 m/s and 3 cm stay)
            noise = (stance_noise(p_s * scale, fps, cfg.contact_height_m, cfg.stance_share)
                     * (cfg.stance_noise_ratio / cfg.contact_noise_ratio))
            share = float(np.max(cfg.contact_noise_ratio * noise / cfg.contact_speed_mps))
            release = cfg.release_m * max(1.0, cfg.release_noise_gain * share)
    contacts = (foot_contacts(p_s * scale, fps, cfg, ground * scale, noise)
                if cfg.foot_lock
                else np.zeros((len(poses), 2), dtype=bool))
    if cfg.foot_lock and contacts.any():
        drift = ground_drift(ground, len(poses))[:, None]
        contacts = split_on_lift((p_s[:, list(FOOT_JOINTS)] - drift) * scale, contacts, release,
                                 cfg.contact_min_frames, both_ways=True)
        if release > cfg.release_m:  # a raised threshold admits noisy planted feet: runs must be still on average
            low = height_above_floor(p_s[:, list(FOOT_JOINTS)] * scale, floor_plane(p_s * scale)) < cfg.contact_height_m
            contacts = bridge_short_gaps((p_s[:, list(FOOT_JOINTS)] - drift) * scale, contacts, cfg.bridge_frames,
                                         release, low)
            contacts = trim_sliding_runs((p_s[:, list(FOOT_JOINTS)] - drift) * scale, contacts,
                                         cfg.slide_speed_mps / fps, cfg.contact_min_frames)
        hold = cfg.hold_frames if cfg.smoothing == "adaptive" else 0
        ease = cfg.blend_ease and cfg.smoothing == "adaptive"
        within = cfg.hold_within_m / scale if cfg.hold_within_m is not None else None
        blend_max = cfg.blend_max_m / scale
        if cfg.root_from_locks and cfg.smoothing == "adaptive":
            # the smoothness weighs squared second differences per frame: (fps / 30)^4 keeps its span in seconds
            t_s = t_s + root_shift_from_locks(p_s, contacts, cfg.blend_frames, ground, blend_max,
                                              cfg.root_lock_smoothness * (fps / 30.0) ** 4, hold, ease, within)
            p_s = joints_of(R_s, t_s, J_rest)
            blend_max *= ROOT_SHIFT_BLEND_SHARE  # the root's shift moves a blending foot a little too
            if cfg.lock_turn_prior is not None:  # ... and the whole body's turn what the feet ask differently
                R_s, t_s = turn_from_locks(R_s, t_s, p_s, contacts, cfg.blend_frames, ground, blend_max,
                                           cfg.lock_turn_prior / scale ** 2,
                                           cfg.root_lock_smoothness * (fps / 30.0) ** 4, hold, ease, within)
                p_s = joints_of(R_s, t_s, J_rest)
        # the contacts reported are the frames the locks hold still (a hand-over between two locks moves the foot)
        held = lock_plan(p_s, contacts, cfg.blend_frames, ground, blend_max, hold, ease, within)[2]
        knee_turn = (np.deg2rad(cfg.lock_knee_turn_deg)
                     if cfg.lock_knee_turn_deg is not None and cfg.smoothing == "adaptive" else None)
        R_s = lock_feet(R_s, p_s, contacts, cfg.blend_frames, ground, blend_max, hold, ease, within, knee_turn)
        contacts = held
        p_s = joints_of(R_s, t_s, J_rest)
    return R_s, t_s, contacts, raw, p_s * scale, glitches


def animation_from_clip(clip: Clip, solver: TensorSolver, *, fps: float | None = None, track: str | None = None,
                        frames: tuple[int, int] | None = None, character: Any = None,
                        skeleton: SkeletonSource | None = None, config: AnimateConfig | None = None,
                        camera: CameraInfo | None = None, progress: Progress | None = None
                        ) -> tuple[Animation, list[TrackMotion]]:
    """Build the :class:`Animation` of a read clip (module docstring, steps 2-5)."""
    from workflows.scene.pipeline import retarget_to_body
    from workflows.scene.recovery import recover_many

    config = AnimateConfig() if config is None else config
    rate = fps if fps is not None else clip.fps
    notes = list(clip.notes)
    if rate is None and clip.format in ASSUMED_FPS:
        rate = ASSUMED_FPS[clip.format]
        notes.append(f"{clip.source}: the {clip.format} output does not store its frame rate; {rate:g} frames/s "
                     "assumed (--fps F sets the video's).")
    if rate is None:
        raise AnimationError(f"{clip.source}: the {clip.format} output does not store its frame rate; pass --fps "
                             "(the source video's frames per second).")
    from smplik.limits import LimitError, check_rate

    try:
        rate = check_rate(rate, "--fps" if fps is not None else f"{clip.source}: its frame rate")
    except LimitError as exc:
        raise AnimationError(str(exc)) from None
    ids = list(clip.tracks)
    if track is not None:
        if str(track) not in clip.tracks:
            raise AnimationError(f"{clip.source}: no track {track!r} (tracks: {', '.join(ids[:20])}).")
        ids = [str(track)]
    elif frames is not None:  # only tracks that appear in the range are exported; they must cover it
        ids = [i for i in ids if clip.tracks[i]]
    for i in ids:
        check_track(i, clip.tracks[i], frames, clip.source)
    if camera is None and clip.space == "camera":
        camera = next(iter(clip.tracks.values()))[0][1].camera
    clip, camera, depth_change = realistic_depth(clip, camera, config.camera_fov_deg)
    clean_cfg = camera_clean(config.clean, clip.space)
    tracks, motions, targets, scales, owners = [], [], [], [], []
    for n, tid in enumerate(ids):
        if progress is not None:
            progress(n, len(ids), "cleaning")
        rows = clip.tracks[tid]
        people = [p for _, p in rows]
        if character is None:
            body = (np.mean([p.betas for p in people], axis=0), people[0].gender, 1.0)
        else:
            body = (np.asarray(character.betas, dtype=np.float64), character.gender, float(character.scale))
        poses = [retarget_to_body(p, *body) for p in people]
        R, transl, contacts, raw, clean, glitches = clean_track(poses, rate, clean_cfg, body[2])
        J_rest = rest_joints(body[0], body[1])
        keys = select_keyframes(R, transl, J_rest, keyframe_threshold(raw, clean, config.keyframe_threshold_m),
                                scale=body[2], max_gap=config.max_keyframe_gap,
                                max_keys=int(config.max_keyframe_share * len(poses)))
        aa = matrix_to_axis_angle_scipy(R)
        name = f"person_{tid}"
        tracks.append(AnimationTrack(name, tid, body[1], body[0], body[2], skeleton, rows[0][0], aa[:, 0],
                                     aa[:, 1:], transl, (), contacts if config.clean.foot_lock else None,
                                     tuple(int(rows[0][0] + r) for r in np.nonzero(glitches)[0])))
        motions.append(TrackMotion(name, raw, clean, contacts))
        for k in keys:
            targets.append(TargetPose.from_pose(tracks[-1].pose(k)))
            scales.append(body[2])
            owners.append((n, k))
        if progress is not None:
            progress(n + 1, len(ids), "cleaning")
    recs = recover_many(solver, targets, config.recovery, scales=scales,
                        progress=None if progress is None else lambda k, m: progress(k, m, "keyframe effectors"))
    keyframes: dict[int, list[Keyframe]] = {}
    for (n, k), rec in zip(owners, recs, strict=True):
        keyframes.setdefault(n, []).append(Keyframe(tracks[n].first_frame + k, rec.effectors, rec.final_error))
    tracks = [dataclasses.replace(t, keyframes=tuple(keyframes.get(n, ()))) for n, t in enumerate(tracks)]
    return Animation(tuple(tracks), float(rate), clip.source, clip.format, clip.space,
                     camera if clip.space == "camera" else None, clean_cfg, depth_change, tuple(notes)), motions
