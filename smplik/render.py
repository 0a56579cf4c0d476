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
    """Camera placement: look at the scene's centre from ``direction`` (world, y-up)."""

    direction: Sequence[float] = (0.0, 0.0, 1.0)
    yfov: float = np.pi / 5
    margin: float = 1.15


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


def render(
    meshes: Sequence[MeshItem] = (),
    spheres: Sequence[Sphere] = (),
    segments: Sequence[Segment] = (),
    *,
    size: tuple[int, int] = (480, 640),
    view: View | ImageCamera = View(),
    background: np.ndarray | RGBA = (1.0, 1.0, 1.0, 1.0),
) -> np.ndarray:
    """Render the items; returns an RGB uint8 image (H, W, 3) with ``size = (width, height)``.

    ``background`` is a colour, or an RGB image of the output size to draw over (overlay).
    """
    pyrender = _pyrender()
    import trimesh

    width, height = size
    bg_image = None
    if isinstance(background, np.ndarray) and background.ndim == 3:
        bg_image, bg_color = background[..., :3], (0.0, 0.0, 0.0, 0.0)
    else:
        bg_color = tuple(float(c) for c in background)  # pyrender wants floats
    scene = pyrender.Scene(bg_color=bg_color, ambient_light=(0.35, 0.35, 0.35))
    points = []
    for m in meshes:
        tm = trimesh.Trimesh(np.asarray(m.vertices, float), np.asarray(m.faces), process=False)
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=m.color, metallicFactor=0.0, roughnessFactor=0.7)
        scene.add(pyrender.Mesh.from_trimesh(tm, material=mat, smooth=True))
        points.append(tm.vertices)
    prims = [(trimesh.creation.icosphere(subdivisions=2, radius=s.radius).apply_translation(np.asarray(s.center)),
              s.color) for s in spheres]
    prims += [(_segment_mesh(s), s.color) for s in segments]
    for tm, color in prims:
        mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=color, metallicFactor=0.0, roughnessFactor=0.5)
        scene.add(pyrender.Mesh.from_trimesh(tm, material=mat, smooth=False))
        points.append(tm.vertices)
    if not points:
        raise RenderError("Nothing to render.")
    allp = np.concatenate(points)
    if isinstance(view, ImageCamera):
        camera = pyrender.IntrinsicsCamera(view.fx, view.fy, view.cx, view.cy, znear=0.05, zfar=100.0)
        T_world_camera = np.asarray(view.T_world_camera, float)
    else:
        lo, hi = allp.min(0), allp.max(0)
        center, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
        aspect = width / height
        d = np.asarray(view.direction, float)
        d = d / np.linalg.norm(d)
        axes = _look_at(center + d, center)[:3, :3]
        local = (allp - center) @ axes  # camera-aligned coordinates: x right, y up, z towards camera
        half_x, half_y = np.abs(local[:, 0]).max(), np.abs(local[:, 1]).max()
        tan_y = np.tan(view.yfov / 2)
        dist = view.margin * max(half_y / tan_y, half_x / (tan_y * aspect)) + local[:, 2].max()
        T_world_camera = _look_at(center + dist * d, center)
        camera = pyrender.PerspectiveCamera(yfov=view.yfov, aspectRatio=aspect, znear=0.05, zfar=dist + 4 * radius)
    scene.add(camera, pose=T_world_camera)
    light = pyrender.DirectionalLight(color=np.ones(3), intensity=3.0)
    scene.add(light, pose=T_world_camera)
    try:
        renderer = pyrender.OffscreenRenderer(width, height)
    except Exception as exc:
        raise RenderError(
            f"No OpenGL backend for offscreen rendering ({type(exc).__name__}: {exc}). On a headless machine set "
            "PYOPENGL_PLATFORM=egl (needs libEGL, e.g. Mesa) or PYOPENGL_PLATFORM=osmesa before running."
        ) from exc
    try:
        if bg_image is not None:
            color, _ = renderer.render(scene, flags=pyrender.RenderFlags.RGBA)
            alpha = color[..., 3:4].astype(np.float32) / 255.0
            out = color[..., :3] * alpha + bg_image.astype(np.float32) * (1 - alpha)
            return out.astype(np.uint8)
        color, _ = renderer.render(scene)
        return np.ascontiguousarray(color[..., :3])
    finally:
        renderer.delete()


def save_png(image: np.ndarray, path: str | Path) -> Path:
    """Write an RGB(A) uint8 image as PNG, atomically."""
    import matplotlib.image

    with atomic_path(path, suffix=".png") as tmp:
        matplotlib.image.imsave(tmp, image)
    return Path(path)


def hstack_images(images: Sequence[np.ndarray]) -> np.ndarray:
    """Place images of equal height side by side."""
    return np.concatenate(list(images), axis=1)
