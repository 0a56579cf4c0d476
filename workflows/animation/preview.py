"""Animated previews of an animation: a GIF or MP4, over the source video's frames or in a 3D view.

Each shown frame is the animation's scene at that source frame (:func:`workflows.animation.files.scene_of`:
every track present at the frame, with its effector markers on keyframes), its source frame number in the
top-left corner. With ``video`` (a video file imageio-ffmpeg reads, or a folder of frame images in name order)
and a camera-frame animation, each frame is drawn over the matching video frame through the estimator's camera
(scaled to at most :attr:`PreviewConfig.overlay_max_side` pixels); otherwise a 3D view:

* **from the front**: one camera for the whole clip, on the side the bodies face: the horizontal forward axis
  of the root (pelvis) rotation (SMPL's body faces its +z) averaged over every frame of every track
  (:func:`facing_direction`), 0.25 rad above the horizon, framing every shown frame's joints
  (:func:`world_view`). The camera does not follow the body, so a walk crosses the picture.
* **a floor**: a checkerboard of :attr:`PreviewConfig.tile_m` tiles at the clip's lowest point (the lowest mesh
  vertex over the clip, :func:`floor_height`), horizontal in the animation's y-up frame, so that foot sliding
  shows against it. (In a camera-frame animation the true floor may be tilted; this one is level.)

Cost (:func:`write_preview`): one OpenGL context for all frames (:class:`smplik.render.Renderer`), preview-sized
frames, the floor drawn once (the bodies are drawn over that image), frames streamed to the MP4 encoder; a GIF
gets one 255-colour palette, computed once from frames sampled over the clip, and every frame is mapped to it.
The whole clip is shown: an MP4 every ``every``-th frame, a GIF at most :attr:`PreviewConfig.gif_max_fps` frames
per second of the clip (every 2nd frame of a 30 frames/s clip); beyond :attr:`PreviewConfig.max_frames` frames a
larger step is chosen. :func:`describe_frames` says which frames are shown (``scene animate`` prints it).
``benchmarks/preview_speed.py`` measures the cost against the animation's own.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smplik.atomic import atomic_path
from smplik.limits import MIN_FPS
from workflows.animation.clips import Animation, AnimationError
from workflows.animation.options import PREVIEW_SUFFIXES, check_preview_path  # noqa: F401 (re-exported)

if TYPE_CHECKING:
    from smplik.render import MeshItem, View

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
FLOOR_COLORS = ((0.80, 0.80, 0.80, 1.0), (0.62, 0.62, 0.64, 1.0))
"""The floor's two tile colours."""


@dataclass(frozen=True)
class PreviewConfig:
    """Size and frame selection of an animated preview."""

    size: tuple[int, int] = (480, 360)
    """(width, height) of the 3D view, pixels."""
    overlay_max_side: int = 640
    """Over a video, frames are scaled down so that their longer side is at most this (pixels)."""
    max_frames: int = 1000
    """Most frames in one preview; a longer clip is shown every k-th frame (k chosen, and said)."""
    gif_max_fps: float = 15.0
    """A GIF shows at most this many frames per second of the clip (every k-th frame, said): a GIF's usual rate,
    half the drawing of a 30 frames/s clip. An MP4 shows every frame."""
    tile_m: float = 0.5
    """Floor tile size (metres, times the largest character scale)."""
    palette_samples: int = 8
    """GIF: frames, spread over the clip, whose colours make the one palette."""

    def __post_init__(self) -> None:
        if min(self.size) < 16 or max(self.size) > 4096 or self.overlay_max_side < 16 or self.max_frames < 1:
            raise AnimationError(f"preview size {self.size} / overlay side {self.overlay_max_side} / "
                                 f"max frames {self.max_frames} out of range.")


@dataclass(frozen=True)
class PreviewResult:
    """What :func:`write_preview` wrote: the file, the source frames shown, and their step."""

    path: Path
    frames: tuple[int, ...]
    every: int

    def describe(self) -> str:
        return describe_frames(self.frames, self.every)


# ----------------------------------------------------------------------------- checks and frame choice


MAX_PREVIEW_EVERY = 1000
"""Largest ``--preview-every`` step (a preview always shows at most :attr:`PreviewConfig.max_frames` frames; its
playback rate is at least :data:`smplik.limits.MIN_FPS`)."""


def shown_frames(animation: Animation, every: int = 1, max_frames: int = 1000, max_fps: float | None = None
                 ) -> tuple[list[int], int]:
    """The source frames a preview shows and their step: every ``every``-th of the clip's first..last frame, the
    step raised (to the smallest multiple of ``every`` that fits) when that is more than ``max_frames`` frames or
    (``max_fps``) more than ``max_fps`` frames per second of the clip."""
    if isinstance(every, bool) or not isinstance(every, int) or not 1 <= every <= MAX_PREVIEW_EVERY:
        raise AnimationError(f"--preview-every must be a whole number in 1..{MAX_PREVIEW_EVERY}, got {every!r:.40}.")
    first = min(t.first_frame for t in animation.tracks)
    last = max(t.first_frame + t.num_frames - 1 for t in animation.tracks)
    span = last - first + 1
    step = every * max(1, math.ceil(math.ceil(span / every) / max_frames))
    if max_fps is not None and animation.fps / step > max_fps * (1 + 1e-9):
        step = max(step, every * math.ceil(animation.fps / max_fps / every))
    return list(range(first, last + 1, step)), step


def describe_frames(frames: tuple[int, ...] | list[int], every: int) -> str:
    """One line: which source frames a preview shows."""
    if every == 1:
        return f"preview: frames {frames[0]}..{frames[-1]} ({len(frames)} frames, all of them)"
    nth = {2: "2nd", 3: "3rd"}.get(every, f"{every}th")
    return f"preview: every {nth} frame of {frames[0]}..{frames[-1]} ({len(frames)} frames)"


# ----------------------------------------------------------------------------- the 3D view


def _track_joints(track) -> np.ndarray:
    """(T, 24, 3) joints of a track in character space (SMPL space times its scale)."""
    from workflows.animation.clips import axis_angle_to_local, joints_of, rest_joints

    R = axis_angle_to_local(track.global_orient, track.body_pose)
    return joints_of(R, track.transl, rest_joints(track.betas, track.gender)) * track.scale


def facing_direction(animation: Animation) -> np.ndarray:
    """(3,) unit horizontal direction (y-up world) the bodies face, averaged over every frame of every track:
    the root rotation's +z axis (SMPL's body faces +z), its vertical part dropped. +z when they turn evenly."""
    from scipy.spatial.transform import Rotation

    total = np.zeros(3)
    for t in animation.tracks:
        forward = Rotation.from_rotvec(np.asarray(t.global_orient, float)).apply([0.0, 0.0, 1.0])  # (T, 3)
        forward[:, 1] = 0.0
        norms = np.linalg.norm(forward, axis=1, keepdims=True)
        total += (forward / np.maximum(norms, 1e-9))[norms[:, 0] > 1e-6].sum(0)
    n = float(np.linalg.norm(total))
    return total / n if n > 1e-6 else np.array([0.0, 0.0, 1.0])


def floor_height(animation: Animation, joints: list[np.ndarray], candidates: int = 4) -> float:
    """The clip's lowest mesh vertex (y, character space): the meshes of the ``candidates`` frames of each track
    whose foot joints are lowest (``joints``: per track (T, 24, 3), character space)."""
    from workflows.animation.files import scene_of
    from workflows.scene.previews import scene_items

    feet = [7, 8, 10, 11]  # ankles and feet
    frames: set[int] = set()
    for t, p in zip(animation.tracks, joints, strict=True):
        low = p[:, feet, 1].min(1)
        frames.update(t.first_frame + int(k) for k in np.argsort(low)[:candidates])
    lowest = np.inf
    for f in sorted(frames):
        meshes, _, _ = scene_items(scene_of(animation, f), markers=False)
        for m in meshes:
            lowest = min(lowest, float(np.asarray(m.vertices)[:, 1].min()))
    if not np.isfinite(lowest):  # no mesh: the lowest foot joint
        lowest = min(float(p[:, feet, 1].min()) for p in joints)
    return lowest


def floor_meshes(height: float, lo: np.ndarray, hi: np.ndarray, tile: float) -> list[MeshItem]:
    """A checkerboard (two :class:`smplik.render.MeshItem`, one per colour) of ``tile``-sized squares at
    ``y = height`` covering x in ``[lo[0], hi[0]]`` and z in ``[lo[1], hi[1]]`` (tile-aligned)."""
    from smplik.render import MeshItem

    i0, i1 = math.floor(lo[0] / tile), math.ceil(hi[0] / tile)
    k0, k1 = math.floor(lo[1] / tile), math.ceil(hi[1] / tile)
    verts: list[list[np.ndarray]] = [[], []]
    for i in range(i0, i1):
        for k in range(k0, k1):
            x, z = i * tile, k * tile
            verts[(i + k) % 2].append(np.array([[x, height, z], [x, height, z + tile], [x + tile, height, z + tile],
                                                [x + tile, height, z]]))
    out = []
    for color, quads in zip(FLOOR_COLORS, verts, strict=True):
        if not quads:
            continue
        v = np.concatenate(quads)
        base = 4 * np.arange(len(quads))[:, None]
        faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])  # counter-clockwise seen from above
        out.append(MeshItem(v, faces, color))
    return out


@dataclass(frozen=True)
class WorldView:
    """The 3D view of a clip: a camera per shown frame (:class:`smplik.render.View`) that follows the bodies, and the
    floor (its height and meshes)."""

    views: dict[int, View]
    """Per shown source frame: looks from :attr:`facing`, slightly above, at the bodies' smoothed path
    (:func:`follow_centers`), from one distance for the whole clip (the closest that frames every shown frame)."""
    floor_y: float
    """Height of the floor (the clip's lowest mesh vertex), character space."""
    floor: tuple[MeshItem, ...]
    facing: np.ndarray
    """(3,) unit horizontal direction the bodies face (:func:`facing_direction`); the camera sits on that side."""

    @property
    def view(self) -> View:
        """The first shown frame's view."""
        return next(iter(self.views.values()))


FOLLOW_SECONDS = 1.0
"""The camera's follow keeps the bodies' horizontal motion slower than one period of this many seconds (a walk's
travel) and drops faster sway (each step's)."""


def follow_centers(paths: np.ndarray, present: np.ndarray, fps: float, height: float) -> np.ndarray:
    """Where the camera looks at each frame (T, 3): the mean horizontal position of the bodies present (``paths``
    (K, T, 3) pelvises of K tracks, ``present`` (K, T) bool), smoothed over time (Whittaker-Henderson, zero-phase,
    cut-off period :data:`FOLLOW_SECONDS`: a walk is followed without the camera swaying with each step), at a fixed
    ``height`` (the camera does not bounce with a jump). Frames without a body hold the nearest followed position."""
    from smplik.smoothing import whittaker

    T = paths.shape[1]
    count = present.sum(0)  # (T,)
    mean = np.where(count[:, None] > 0, (paths * present[..., None]).sum(0) / np.maximum(count, 1)[:, None], 0.0)
    rows = np.nonzero(count > 0)[0]
    if rows.size == 0:
        return np.tile([0.0, height, 0.0], (T, 1))
    mean = np.stack([np.interp(np.arange(T), rows, mean[rows, k]) for k in range(3)], -1)  # bridge the gaps
    period = FOLLOW_SECONDS * fps  # frames; the smoother's gain is 1/2 at lam = (period / (2 pi))^4
    smoothed = whittaker(mean, np.ones_like(mean), np.full(3, (period / (2 * np.pi)) ** 4))
    smoothed[:, 1] = height
    return smoothed


def world_view(animation: Animation, frames: list[int], config: PreviewConfig = PreviewConfig()) -> WorldView:
    """The cameras (on the side the bodies face, following them: :func:`follow_centers`; one distance that frames
    every shown frame's bodies around its followed centre, so the bodies fill the picture) and the floor."""
    from smplik.render import View, fit_distance

    joints = [_track_joints(t) for t in animation.tracks]
    floor_y = floor_height(animation, joints)
    first = min(t.first_frame for t in animation.tracks)
    T = max(t.first_frame + t.num_frames for t in animation.tracks) - first
    paths = np.zeros((len(joints), T, 3))
    present = np.zeros((len(joints), T), dtype=bool)
    for k, (t, p) in enumerate(zip(animation.tracks, joints, strict=True)):
        paths[k, t.first_frame - first:t.first_frame - first + t.num_frames] = p[:, 0]
        present[k, t.first_frame - first:t.first_frame - first + t.num_frames] = True
    scale = max(t.scale for t in animation.tracks)
    top = max(float(p[..., 1].max()) for p in joints) + 0.15 * scale  # the head's top above its joint
    centers = follow_centers(paths, present, animation.fps, 0.5 * (floor_y + top))
    facing = facing_direction(animation)
    direction = facing + np.array([0.0, math.tan(0.25), 0.0])
    distance = 0.0
    for f in frames:
        points = [p[f - t.first_frame] for t, p in zip(animation.tracks, joints, strict=True)
                  if 0 <= f - t.first_frame < t.num_frames]
        if not points:
            continue
        pts = np.concatenate(points)
        pad = 0.15 * scale  # the mesh around the joints (head top, hands, feet)
        lo, hi = pts.min(0) - pad, pts.max(0) + pad
        lo[1] = floor_y
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        distance = max(distance, fit_distance(corners, direction, centers[f - first], size=config.size))
    views = {f: View(tuple(direction), center=tuple(centers[f - first]), distance=distance) for f in frames}
    tile = config.tile_m * scale
    margin = 1.5 * tile + distance  # the floor reaches the picture's edges wherever the camera goes
    path = centers[[f - first for f in frames]]
    floor = floor_meshes(floor_y - 0.002 * scale, np.array([path[:, 0].min() - margin, path[:, 2].min() - margin]),
                         np.array([path[:, 0].max() + margin, path[:, 2].max() + margin]), tile)
    return WorldView(views, floor_y, tuple(floor), facing)


# ----------------------------------------------------------------------------- frames


def _video_frames(video: Path) -> Callable[[int], np.ndarray]:
    """``frame(i) -> (H, W, 3) uint8`` for a video file or a folder of images."""
    if video.is_dir():
        files = sorted(p for p in video.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise AnimationError(f"{video}: no frame images ({', '.join(IMAGE_SUFFIXES)}) in the folder.")
        from workflows.scene.previews import load_image

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


def _resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    if img.shape[1] == width and img.shape[0] == height:
        return np.ascontiguousarray(img)
    from PIL import Image

    return np.asarray(Image.fromarray(np.ascontiguousarray(img)).resize((width, height), Image.Resampling.BILINEAR))


def _stamp(img: np.ndarray, frame: int) -> np.ndarray:
    from workflows.scene.previews import label_image

    return label_image(img, [f"frame {frame}"])


def iter_preview_frames(animation: Animation, frames: list[int], *, video: str | Path | None = None,
                        config: PreviewConfig = PreviewConfig(), order: list[int] | None = None
                        ) -> Iterator[tuple[int, np.ndarray]]:
    """``(source frame, RGB uint8 image)`` for each of ``frames`` (in ``order`` when given, a permutation of
    them), drawn with one reused renderer (module docstring)."""
    from smplik.render import ImageCamera, Renderer, render
    from workflows.animation.files import scene_of
    from workflows.scene.previews import image_camera, scene_items

    background = None
    world = None
    if video is not None:
        if animation.camera is None:
            raise AnimationError("--video needs an animation in the camera frame (--space camera): a world "
                                 "trajectory does not line up with the video.")
        background = _video_frames(Path(video))
        h0, w0 = background(frames[0]).shape[:2]
        s = min(1.0, config.overlay_max_side / max(h0, w0))
        size = (max(2, int(round(w0 * s / 2)) * 2), max(2, int(round(h0 * s / 2)) * 2))  # even: video encoders
    else:
        world = world_view(animation, frames, config)
        size = (config.size[0] - config.size[0] % 2, config.size[1] - config.size[1] % 2)
    with Renderer(size) as renderer:
        for f in frames if order is None else order:
            scene = scene_of(animation, f)
            meshes, spheres, segments = scene_items(scene)
            if background is not None:
                img = background(f)
                h, w = img.shape[:2]
                cam = image_camera(scene, w, h)  # the estimator's camera at the video's size, then scaled
                sx, sy = size[0] / w, size[1] / h
                cam = ImageCamera(cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy, cam.T_world_camera)
                bg = _resize(img, *size)
                out = render(meshes, spheres, segments, size=size, view=cam, background=bg,
                             renderer=renderer) if (meshes or spheres or segments) else bg
            else:  # the floor lies under the clip's lowest vertex: it hides no body
                out = render([*world.floor, *meshes], spheres, segments, size=size, view=world.views[f],
                             background=(1.0, 1.0, 1.0, 1.0), renderer=renderer)
            yield f, _stamp(out, f)


def preview_frames(animation: Animation, *, video: str | Path | None = None, every: int = 1,
                   config: PreviewConfig = PreviewConfig()) -> list[np.ndarray]:
    """Rendered frames (RGB uint8) of the animation's source frames (:func:`shown_frames`), in frame order."""
    frames, _ = shown_frames(animation, every, config.max_frames)
    return [img for _, img in iter_preview_frames(animation, frames, video=video, config=config)]


def write_preview(animation: Animation, path: str | Path, *, video: str | Path | None = None, every: int = 1,
                  config: PreviewConfig = PreviewConfig()) -> PreviewResult:
    """Render and write the preview (``.gif`` or ``.mp4``) at ``animation.fps / step``, atomically."""
    path = Path(path)
    check_preview_path(path)
    gif = path.suffix.lower() == ".gif"
    frames, step = shown_frames(animation, every, config.max_frames, config.gif_max_fps if gif else None)
    # a sparse preview plays at least MIN_FPS (each frame held at most 1 s): a GIF frame's duration is a 16-bit
    # count of centiseconds, and a 1-frames/s clip shown every 1000th frame would hold each frame 17 minutes
    fps = max(animation.fps / step, MIN_FPS)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".mp4":
            import imageio.v2 as imageio

            writer = imageio.get_writer(str(tmp), format="FFMPEG", fps=fps, macro_block_size=1)
            try:
                for _, img in iter_preview_frames(animation, frames, video=video, config=config):
                    writer.append_data(img)
            finally:
                writer.close()
        else:
            _write_gif(animation, frames, tmp, fps, video=video, config=config)
    return PreviewResult(path, tuple(frames), step)


def _write_gif(animation: Animation, frames: list[int], tmp: Path, fps: float, *, video: str | Path | None,
               config: PreviewConfig) -> None:
    """A GIF of one palette: the sampled frames are drawn first, their colours make the palette (median cut,
    once), then every frame is mapped to it (no dithering) as it is drawn; Pillow writes the file."""
    from PIL import Image

    picks = sorted({frames[round(k * (len(frames) - 1) / max(1, config.palette_samples - 1))]
                    for k in range(min(config.palette_samples, len(frames)))})
    order = picks + [f for f in frames if f not in set(picks)]
    stream = iter_preview_frames(animation, frames, video=video, config=config, order=order)
    sampled = [next(stream) for _ in picks]
    mosaic = np.concatenate([img for _, img in sampled], axis=0)
    palette = Image.fromarray(mosaic).quantize(colors=255, method=Image.Quantize.MEDIANCUT)
    indexed: dict[int, Image.Image] = {}

    def to_palette(img: np.ndarray) -> Image.Image:
        return Image.fromarray(img).quantize(palette=palette, dither=Image.Dither.NONE)

    for f, img in sampled:
        indexed[f] = to_palette(img)
    for f, img in stream:
        indexed[f] = to_palette(img)
    save_gif([indexed[f] for f in frames], tmp, fps)


GIF_TICK_MS = 10
"""A GIF frame's delay is stored in hundredths of a second."""


def gif_durations(n: int, fps: float) -> list[int]:
    """Per-frame delays (ms, multiples of :data:`GIF_TICK_MS`) of ``n`` frames shown at ``fps``: frame k ends at the
    tick nearest ``(k + 1) * 1000 / fps``, so the delays alternate (66.7 ms frames: 70, 60, 70, ...) and the whole
    clip plays in its own time to within half a tick (one delay of ``round(1000 / fps, -1)`` ms would play a 15
    frames/s clip 11 % fast or slow)."""
    ends = np.rint(np.arange(n + 1) * (1000.0 / fps) / GIF_TICK_MS).astype(int) * GIF_TICK_MS
    return [max(GIF_TICK_MS, int(d)) for d in np.diff(ends)]


def save_gif(images: list, path: str | Path, fps: float) -> None:
    """Write PIL ``images`` as a looping GIF played at ``fps`` (:func:`gif_durations`)."""
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:], duration=gif_durations(len(images),
                                                                                                         fps),
                   loop=0)
