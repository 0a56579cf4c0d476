"""Offscreen rendering with pyrender: the only module that imports pyrender.

Scenes are described with plain data (:class:`MeshItem`, :class:`Sphere`, :class:`Segment`)
so that the math modules never touch a renderer. Headless machines need an OpenGL backend:
set ``PYOPENGL_PLATFORM=egl`` (Mesa or NVIDIA EGL) or ``osmesa`` *before* the first render
(the ``smplik`` CLI defaults it to ``egl``); this module never sets it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from smplik.atomic import atomic_path

RGBA = tuple[float, float, float, float]


class RenderError(RuntimeError):
    """No usable OpenGL backend, or the render failed."""


@dataclass(frozen=True)
class MeshItem:
    """A triangle mesh: vertices (V, 3), faces (F, 3), a flat colour."""

    vertices: np.ndarray
    faces: np.ndarray
    color: RGBA = (0.62, 0.7, 0.86, 1.0)


@dataclass(frozen=True)
class Sphere:
    center: Sequence[float]
    radius: float = 0.03
    color: RGBA = (0.9, 0.2, 0.2, 1.0)


@dataclass(frozen=True)
class Segment:
    """A thin cylinder from ``start`` to ``end`` (bones, axes, look-at rays)."""

    start: Sequence[float]
    end: Sequence[float]
    radius: float = 0.008
    color: RGBA = (0.1, 0.1, 0.1, 1.0)


@dataclass(frozen=True)
class View:
    """Camera placement: look at the scene's centre from ``direction`` (world, y-up).

    ``center`` and ``distance`` default to fitting the rendered items; :func:`fit_views` sets them so
    that several views of the same items share one scale."""

    direction: Sequence[float] = (0.0, 0.0, 1.0)
    yfov: float = np.pi / 5
    margin: float = 1.15
    center: Sequence[float] | None = None
    distance: float | None = None


@dataclass(frozen=True)
class ImageCamera:
    """A pinhole camera in the world frame, for overlays on a source image.

    ``T_world_camera`` (4, 4) with OpenGL axes (x right, y up, looking down -z).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    T_world_camera: np.ndarray = field(default_factory=lambda: np.eye(4))


def _pyrender():  # imported lazily: importing OpenGL fixes the platform
    try:
        import pyrender
    except Exception as exc:  # pragma: no cover - depends on the machine
        raise RenderError(f"pyrender/OpenGL cannot be imported ({exc}); set PYOPENGL_PLATFORM=egl or osmesa.") from exc
    if not hasattr(np, "infty"):  # pyrender still uses the alias removed in numpy 2
        np.infty = np.inf  # type: ignore[attr-defined]
    return pyrender


def _segment_mesh(seg: Segment):
    import trimesh

    start, end = np.asarray(seg.start, float), np.asarray(seg.end, float)
    if np.linalg.norm(end - start) < 1e-9:
        return trimesh.creation.icosphere(subdivisions=1, radius=seg.radius).apply_translation(start)
    return trimesh.creation.cylinder(radius=seg.radius, segment=np.stack([start, end]), sections=10)


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    forward = eye - target
    forward /= np.linalg.norm(forward)
    up = np.array([0.0, 1.0, 0.0])
    if abs(forward @ up) > 0.99:
        up = np.array([0.0, 0.0, -1.0])
    right = np.cross(up, forward)
    right /= np.linalg.norm(right)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, np.cross(forward, right), forward, eye
    return T


def _unit(direction: Sequence[float]) -> np.ndarray:
    d = np.asarray(direction, float)
    n = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
    if not n > 1e-9 or not np.isfinite(n):
        raise RenderError(f"View direction {tuple(direction)} is not a non-zero 3-vector.")
    return d / n


def _fit(points: np.ndarray, view: View, aspect: float) -> tuple[np.ndarray, float, float]:
    """Centre, camera distance and radius that fit ``points`` (P, 3) in ``view``."""
    lo, hi = points.min(0), points.max(0)
    center = (lo + hi) / 2 if view.center is None else np.asarray(view.center, float)
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.05)
    d = _unit(view.direction)
    axes = _look_at(center + d, center)[:3, :3]
    local = (points - center) @ axes  # camera-aligned coordinates: x right, y up, z towards camera
    half_x, half_y = max(np.abs(local[:, 0]).max(), 0.05), max(np.abs(local[:, 1]).max(), 0.05)
    tan_y = np.tan(view.yfov / 2)
    dist = view.margin * max(half_y / tan_y, half_x / (tan_y * aspect)) + max(local[:, 2].max(), 0.0)
    return center, dist, radius


def fit_distance(points: np.ndarray, direction: Sequence[float], center: Sequence[float], *, size: tuple[int, int],
                 yfov: float = np.pi / 5, margin: float = 1.15) -> float:
    """The camera distance at which a :class:`View` from ``direction`` looking at ``center`` shows every point of
    ``points`` (P, 3) in an image of ``size = (width, height)`` (with ``margin``)."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) == 0 or size[0] < 1 or size[1] < 1:
        raise RenderError(f"Cannot fit a view of {len(points)} points in an image of size {size}.")
    return _fit(points, View(tuple(direction), yfov, margin, tuple(center)), size[0] / size[1])[1]


def fit_views(points: np.ndarray, directions: Sequence[Sequence[float]], *, size: tuple[int, int],
              yfov: float = np.pi / 5, margin: float = 1.15) -> list[View]:
    """Views from ``directions`` that all show ``points`` (P, 3) at one common scale (same centre and
    distance: the largest any single view needs), for side-by-side panels of ``size = (width, height)``."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) == 0 or size[0] < 1 or size[1] < 1:
        raise RenderError(f"Cannot fit views of {len(points)} points in an image of size {size}.")
    aspect = size[0] / size[1]
    fits = [_fit(points, View(tuple(d), yfov, margin), aspect) for d in directions]
    center = (points.min(0) + points.max(0)) / 2
    distance = max(f[1] for f in fits)
    return [View(tuple(d), yfov, margin, tuple(center), distance) for d in directions]


class Renderer:
    """One offscreen OpenGL context of ``size = (width, height)``, reused for many images (an animation's
    frames): creating and deleting a context costs more than drawing a frame. Use as a context manager, or
    call :meth:`close`. :func:`render` draws one image with a renderer of its own."""

    def __init__(self, size: tuple[int, int] = (480, 640)) -> None:
        width, height = int(size[0]), int(size[1])
        if width < 1 or height < 1 or width > 16384 or height > 16384:
            raise RenderError(f"Image size {width} x {height} is outside 1..16384 pixels.")
        from smplik.limits import check_render_size

        check_render_size(width, height)  # the buffers a render of this size takes, before any is made
        self.size = (width, height)
        self._meshes: dict[int, tuple[MeshItem, object]] = {}  # id -> (item, pyrender mesh): items drawn again
        pyrender = _pyrender()
        try:
            self._renderer = pyrender.OffscreenRenderer(width, height)
        except Exception as exc:
            raise RenderError(
                f"No OpenGL backend for offscreen rendering ({type(exc).__name__}: {exc}). On a headless machine set "
                "PYOPENGL_PLATFORM=egl (needs libEGL, e.g. Mesa) or PYOPENGL_PLATFORM=osmesa before running."
            ) from exc

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None

    def _mesh(self, m: MeshItem):
        """The pyrender mesh of ``m``, made once per item object while the item is among the last few drawn (an
        item passed again, such as a floor, is not converted and uploaded again)."""
        key = id(m)
        if key in self._meshes and self._meshes[key][0] is m:
            self._meshes[key] = self._meshes.pop(key)  # most recently used last
            return self._meshes[key][1]
        pyrender = _pyrender()
        import trimesh

        tm = trimesh.Trimesh(np.asarray(m.vertices, float), np.asarray(m.faces), process=False)
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=m.color, metallicFactor=0.0, roughnessFactor=0.7)
        mesh = pyrender.Mesh.from_trimesh(tm, material=mat, smooth=True)
        self._meshes[key] = (m, mesh)  # holding the item keeps its id from being reused
        while len(self._meshes) > 16:
            self._meshes.pop(next(iter(self._meshes)))
        return mesh

    def render(self, meshes: Sequence[MeshItem] = (), spheres: Sequence[Sphere] = (),
               segments: Sequence[Segment] = (), *, view: View | ImageCamera = View(),
               background: np.ndarray | RGBA = (1.0, 1.0, 1.0, 1.0), markers_on_top: bool = True) -> np.ndarray:
        """Render the items at this renderer's size: RGB uint8 (H, W, 3); the arguments as in :func:`render`."""
        if self._renderer is None:
            raise RenderError("This renderer is closed.")
        width, height = self.size
        pyrender = _pyrender()
        import trimesh

        bg_image = None
        if isinstance(background, np.ndarray) and background.ndim == 3:
            if background.shape[:2] != (height, width):
                raise RenderError(f"Background image of shape {background.shape[:2]} does not match the size "
                                  f"{height} x {width}.")
            bg_image, bg_color = background[..., :3], (0.0, 0.0, 0.0, 0.0)
        else:
            bg_color = tuple(float(c) for c in background)  # pyrender wants floats
        scene = pyrender.Scene(bg_color=bg_color, ambient_light=(0.35, 0.35, 0.35))
        marker_scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(0.35, 0.35, 0.35))
        points = []
        for m in meshes:
            scene.add(self._mesh(m))
            points.append(np.asarray(m.vertices, float))
        prims = [(trimesh.creation.icosphere(subdivisions=2, radius=s.radius).apply_translation(np.asarray(s.center)),
                  s.color) for s in spheres]
        prims += [(_segment_mesh(s), s.color) for s in segments]
        for tm, color in prims:
            mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=color, metallicFactor=0.0, roughnessFactor=0.5)
            scene.add(pyrender.Mesh.from_trimesh(tm, material=mat, smooth=False))
            marker_scene.add(pyrender.Mesh.from_trimesh(tm, material=mat, smooth=False))
            points.append(tm.vertices)
        if not points:
            raise RenderError("Nothing to render.")
        allp = np.concatenate(points)
        if not np.isfinite(allp).all():
            raise RenderError("The items to render contain NaN or inf coordinates.")
        if isinstance(view, ImageCamera):
            if not all(np.isfinite(v) and v > 0 for v in (view.fx, view.fy)):
                raise RenderError(f"Image camera focal lengths must be positive and finite, got {view.fx}, "
                                  f"{view.fy}.")
            camera = pyrender.IntrinsicsCamera(view.fx, view.fy, view.cx, view.cy, znear=0.05, zfar=100.0)
            T_world_camera = np.asarray(view.T_world_camera, float)
        else:
            center, dist, radius = _fit(allp, view, width / height)
            if view.distance is not None:
                dist = float(view.distance)
            d = _unit(view.direction)
            T_world_camera = _look_at(center + dist * d, center)
            camera = pyrender.PerspectiveCamera(yfov=view.yfov, aspectRatio=width / height, znear=0.05,
                                                zfar=dist + 4 * radius)
        light = pyrender.DirectionalLight(color=np.ones(3), intensity=3.0)
        for sc in (scene, marker_scene):
            sc.add(camera, pose=T_world_camera)
            sc.add(light, pose=T_world_camera)
        renderer = self._renderer
        if bg_image is not None:
            color, _ = renderer.render(scene, flags=pyrender.RenderFlags.RGBA)
            alpha = color[..., 3:4].astype(np.float32) / 255.0
            out = color[..., :3] * alpha + bg_image.astype(np.float32) * (1 - alpha)
        else:
            color, _ = renderer.render(scene)
            out = color[..., :3].astype(np.float32)
        if markers_on_top and prims and meshes:
            marks, _ = renderer.render(marker_scene, flags=pyrender.RenderFlags.RGBA)
            a = 0.7 * marks[..., 3:4].astype(np.float32) / 255.0  # hidden markers show through at 70 %
            out = marks[..., :3] * a + out * (1 - a)
        return np.ascontiguousarray(np.clip(out, 0, 255).astype(np.uint8))


def camera_pose(points: np.ndarray, view: View, size: tuple[int, int]) -> np.ndarray:
    """``T_world_camera`` (4, 4; OpenGL axes, looking down -z) that :func:`render` uses for ``view`` of items whose
    vertices are ``points`` (P, 3) in an image of ``size = (width, height)``."""
    center, dist, _ = _fit(np.asarray(points, float).reshape(-1, 3), view, size[0] / size[1])
    if view.distance is not None:
        dist = float(view.distance)
    return _look_at(center + dist * _unit(view.direction), center)


def render(
    meshes: Sequence[MeshItem] = (),
    spheres: Sequence[Sphere] = (),
    segments: Sequence[Segment] = (),
    *,
    size: tuple[int, int] = (480, 640),
    view: View | ImageCamera = View(),
    background: np.ndarray | RGBA = (1.0, 1.0, 1.0, 1.0),
    markers_on_top: bool = True,
    renderer: Renderer | None = None,
) -> np.ndarray:
    """Render the items; returns an RGB uint8 image (H, W, 3) with ``size = (width, height)``.

    ``background`` is a colour, or an RGB image of the output size to draw over (overlay). With
    ``markers_on_top`` the spheres and segments stay visible where a mesh hides them (a met position
    target sits inside the body): a second pass of the markers alone is blended over the image.
    ``renderer``: a :class:`Renderer` of this ``size`` to reuse (default: one made and freed for this image).
    """
    if renderer is not None:
        if tuple(renderer.size) != (int(size[0]), int(size[1])):
            raise RenderError(f"The renderer is {renderer.size[0]} x {renderer.size[1]}; the image is to be "
                              f"{size[0]} x {size[1]}.")
        return renderer.render(meshes, spheres, segments, view=view, background=background,
                               markers_on_top=markers_on_top)
    with Renderer(size) as own:
        return own.render(meshes, spheres, segments, view=view, background=background, markers_on_top=markers_on_top)


def save_png(image: np.ndarray, path: str | Path) -> Path:
    """Write an RGB(A) uint8 image as PNG, atomically."""
    import matplotlib.image

    with atomic_path(path, suffix=".png") as tmp:
        matplotlib.image.imsave(tmp, image)
    return Path(path)


def hstack_images(images: Sequence[np.ndarray]) -> np.ndarray:
    """Place images of equal height side by side."""
    return np.concatenate(list(images), axis=1)


def label_image(img: np.ndarray, lines: Sequence[str], *, colors: Sequence[tuple[float, ...]] | None = None
                ) -> np.ndarray:
    """``img`` with text lines in its top-left corner on a light box (PIL's default font)."""
    from PIL import Image, ImageDraw

    pil = Image.fromarray(np.ascontiguousarray(img))
    draw = ImageDraw.Draw(pil)
    line_h = 13
    width = max((int(draw.textlength(t)) for t in lines), default=0) + 20
    draw.rectangle([2, 2, 6 + width, 6 + line_h * len(lines)], fill=(255, 255, 255))
    for k, text in enumerate(lines):
        y = 4 + k * line_h
        x = 6
        if colors is not None and k < len(colors) and colors[k] is not None:
            c = tuple(int(255 * v) for v in colors[k][:3])
            draw.rectangle([x, y + 2, x + 8, y + 10], fill=c, outline=(0, 0, 0))
            x += 12
        draw.text((x, y), text, fill=(0, 0, 0))
    return np.asarray(pil)
