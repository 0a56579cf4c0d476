"""``scene animate``'s option checks, importable without numpy or torch.

Every option that can be judged from its text (the frame range, the frame rate, the export formats, the estimator
format, the space, the smoothing method, the preview's path) is refused here, with one :class:`AnimationError`
line, before the command imports numpy, torch or the model (``tests/test_animate_startup.py`` guards it). The
names checked mirror the modules that use them (:data:`EXPORT_FORMATS` is
:data:`workflows.scene.export.FORMATS`, :data:`ESTIMATOR_FORMATS` :data:`workflows.estimators.FORMATS`,
:data:`SMOOTHING_METHODS` :class:`workflows.animation.clean.CleanConfig`'s; a test keeps them equal).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path


class AnimationError(ValueError):
    """Bad animation input (frame range, track, frame rate, missing frames); one line."""


EXPORT_FORMATS: tuple[str, ...] = ("bvh", "glb")
"""Animated export formats (:data:`workflows.scene.export.FORMATS`)."""
ESTIMATOR_FORMATS: tuple[str, ...] = ("romp", "bev", "hybrik", "phalp", "wham", "pymafx", "vibe", "gvhmr", "glamr",
                                      "aist", "amass", "sam3d", "easymocap", "tram", "smplerx", "agora", "humandata",
                                      "smplifyx", "plain", "pose_array")
"""Estimator formats ``--format`` names (:data:`workflows.estimators.FORMATS`)."""
SMOOTHING_METHODS: tuple[str, ...] = ("auto", "adaptive", "sequence", "one_euro", "savgol", "none")
"""``--smoothing`` values: ``auto`` and :class:`workflows.animation.clean.CleanConfig`'s methods."""
PREVIEW_SUFFIXES = (".gif", ".mp4")
"""Preview files ``--preview`` writes."""


def parse_frames(spec: str) -> tuple[int, int] | None:
    """``"all"`` -> None; ``"A:B"`` -> (A, B): frames A..B-1 (Python slice), 0 <= A < B."""
    spec = str(spec).strip()
    if spec == "all":
        return None
    parts = spec.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        start, stop = int(parts[0]), int(parts[1])
    except ValueError:
        raise AnimationError(f"--frames must be 'all' or 'A:B' (frames A..B-1), got {spec!r}.") from None
    if start < 0 or stop <= start:
        raise AnimationError(f"--frames {spec}: need 0 <= A < B (frames A..B-1).")
    return start, stop


def check_animate_options(*, frames: str = "all", fps: float | None = None, formats: Sequence[str] = ("bvh",),
                          format: str = "auto", space: str | None = None, smoothing: str = "auto",
                          smoothness: float = 2.0, pose_budget: float = 0.0, keyframe_threshold: float = 0.03,
                          character: str | Path | None = None) -> tuple[int, int] | None:
    """Refuse bad ``scene animate`` options (one :class:`AnimationError` line) before anything heavy loads (numpy,
    torch, the model, the file); returns the frame range (:func:`parse_frames`)."""
    import math

    if not (math.isfinite(smoothness) and smoothness > 0):
        raise AnimationError(f"--smoothness must be a positive number, got {smoothness:g}.")
    if not (math.isfinite(pose_budget) and pose_budget >= 0):
        raise AnimationError(f"--pose-budget must be a number of mm >= 0 (0: no cap), got {pose_budget:g}.")
    if not (math.isfinite(keyframe_threshold) and keyframe_threshold > 0):
        raise AnimationError(f"--keyframe-threshold: the keyframe threshold must be a positive number of metres, "
                             f"got {keyframe_threshold:g}.")
    if character is not None and not Path(character).exists():
        raise AnimationError(f"--character {character}: no such file.")
    bad = [f for f in formats if f not in EXPORT_FORMATS]
    if bad:
        raise AnimationError(f"unknown export format(s) {bad}; choose from {', '.join(EXPORT_FORMATS)}.")
    if format not in ("auto", *ESTIMATOR_FORMATS):
        raise AnimationError(f"--format must be one of auto, {', '.join(ESTIMATOR_FORMATS)}, got {format!r}.")
    if space not in (None, "camera", "world"):
        raise AnimationError(f"--space must be 'camera' or 'world', got {space!r}.")
    if smoothing not in SMOOTHING_METHODS:
        raise AnimationError(f"--smoothing must be one of {', '.join(SMOOTHING_METHODS)}, got {smoothing!r}.")
    if fps is not None:
        from smplik.limits import LimitError, check_rate

        try:
            check_rate(fps, "--fps")
        except LimitError as exc:
            raise AnimationError(str(exc)) from None
    return parse_frames(frames)


def check_preview_path(path: str | Path) -> None:
    """Refuse, before any work, a preview file that cannot be written: a suffix other than .gif / .mp4, or an
    MP4 without the ffmpeg writer (package ``imageio-ffmpeg``, a dependency of smplik)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in PREVIEW_SUFFIXES:
        raise AnimationError(f"--preview {path}: a preview is a .gif or .mp4 file.")
    if path.is_dir():
        raise AnimationError(f"--preview {path}: is a folder; give a .gif or .mp4 file path.")
    if path.exists() and not path.is_file():
        raise AnimationError(f"--preview {path}: is not a regular file (a device, pipe or socket).")
    for parent in path.parents:  # the nearest existing folder above it must be a folder
        if parent.exists():
            if not parent.is_dir():
                raise AnimationError(f"--preview {path}: {parent} is a file, not a folder.")
            break
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg

            imageio_ffmpeg.get_ffmpeg_exe()
        except (ImportError, RuntimeError, OSError) as exc:
            raise AnimationError(f"--preview {path}: no MP4 writer ({type(exc).__name__}: "
                                 f"{' '.join(str(exc).split())[:160]}); pip install imageio-ffmpeg, or use a .gif."
                                 ) from None
