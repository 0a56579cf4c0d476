"""Animated previews of an animation: a GIF or MP4, over the source video's frames or in a 3D view.

Each shown frame is the animation's scene at that source frame (:func:`workflows.animation_io.scene_of`:
every track present at the frame, with its effector markers on keyframes) drawn by
:func:`workflows.previews.render_scene`. With ``video`` (a video file imageio-ffmpeg reads, or a folder of
frame images in name order) and a camera-frame animation, each frame is drawn over the matching video frame
through the estimator's camera; otherwise one 3D view from the front. Frames are subsampled by ``every``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smplik.atomic import atomic_path
from workflows.animation import Animation, AnimationError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


def _video_frames(video: Path):
    """``frame(i) -> (H, W, 3) uint8`` for a video file or a folder of images."""
    if video.is_dir():
        files = sorted(p for p in video.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise AnimationError(f"{video}: no frame images ({', '.join(IMAGE_SUFFIXES)}) in the folder.")
        from workflows.previews import load_image

        def from_folder(i: int) -> np.ndarray:
            if i >= len(files):
                raise AnimationError(f"{video}: {len(files)} frame images; the animation needs frame {i}.")
            return load_image(files[i])

        return from_folder
    if not video.is_file():
        raise AnimationError(f"--video: no such file or folder: {video}")
    import imageio.v2 as imageio

    try:
        reader = imageio.get_reader(str(video), "ffmpeg")
    except (OSError, ValueError, RuntimeError) as exc:
        raise AnimationError(f"{video}: not a readable video ({type(exc).__name__}: {exc}).") from None

    def from_video(i: int) -> np.ndarray:
        try:
            return np.asarray(reader.get_data(i))[..., :3]
        except (IndexError, OSError, ValueError, RuntimeError):
            raise AnimationError(f"{video}: has no frame {i} (the animation covers it).") from None

    return from_video


def preview_frames(animation: Animation, *, video: str | Path | None = None, every: int = 1,
                   max_frames: int = 300, size: tuple[int, int] = (480, 360)) -> list[np.ndarray]:
    """Rendered frames (RGB uint8) of the animation's source frames (every ``every``-th, at most ``max_frames``)."""
    from workflows.animation_io import scene_of
    from workflows.previews import render_scene

    if every < 1:
        raise AnimationError(f"--preview-every must be >= 1, got {every}.")
    first = min(t.first_frame for t in animation.tracks)
    last = max(t.first_frame + t.num_frames - 1 for t in animation.tracks)
    shown = list(range(first, last + 1, every))[:max_frames]
    background = None
    if video is not None:
        if animation.camera is None:
            raise AnimationError("--video needs an animation in the camera frame (--space camera): a world "
                                 "trajectory does not line up with the video.")
        background = _video_frames(Path(video))
    frames = []
    for f in shown:
        scene = scene_of(animation, f)
        if background is not None:
            frames.append(render_scene(scene, image=background(f), directions=(), labels=False))
        else:
            frames.append(render_scene(scene, size=size, directions=((0.0, 0.2, 1.0),), labels=False))
    return frames


def save_preview(frames: list[np.ndarray], path: str | Path, fps: float) -> Path:
    """Write frames as a GIF (``.gif``) or MP4 (``.mp4``, imageio-ffmpeg) at ``fps``, atomically."""
    import imageio.v2 as imageio

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise AnimationError(f"{path}: a preview is a .gif or .mp4 file.")
    if not frames:
        raise AnimationError("no frames to preview.")
    h = min(f.shape[0] for f in frames)
    w = min(f.shape[1] for f in frames)
    frames = [f[:h - h % 2, :w - w % 2] for f in frames]  # one size; even for the video encoder
    with atomic_path(path) as tmp:
        if suffix == ".gif":
            imageio.mimsave(tmp, frames, format="GIF", duration=1000.0 / fps, loop=0)
        else:
            imageio.mimsave(tmp, frames, format="FFMPEG", fps=fps, macro_block_size=1)
    return path
