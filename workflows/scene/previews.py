"""Scene previews through :mod:`smplik.render` (the only pyrender module) and recovery plots (matplotlib, Agg).

Markers, in character space: position effectors are purple spheres; rotation effectors are RGB
axes (x red, y green, z blue) of the target global rotation at the character's posed joint;
look-at effectors are a line from the joint to the target with a small sphere at the target.
``render_scene`` can also draw **ghosts**: the estimator's original pose of each person as a dark
wireframe skeleton over the solved body, so what recovery lost is visible; every panel is labelled
and each person's final error is printed in a legend.
Headless machines need ``PYOPENGL_PLATFORM=egl`` (or ``osmesa``) set before the first render.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from smplik.conventions import PARENTS, EffectorType
from smplik.pose import Pose
from smplik.render import ImageCamera, MeshItem, Segment, Sphere, View, hstack_images, label_image, render
from workflows.character import CustomCharacter, CustomPose
from workflows.scene.characters import SceneCharacter, character_joints
from workflows.scene.document import Scene

PALETTE: tuple[tuple[float, float, float, float], ...] = (
    (0.62, 0.70, 0.86, 1.0), (0.86, 0.70, 0.55, 1.0), (0.62, 0.84, 0.64, 1.0), (0.86, 0.62, 0.74, 1.0),
    (0.80, 0.80, 0.58, 1.0), (0.60, 0.80, 0.84, 1.0),
)
EFFECTOR_COLOR = (0.55, 0.15, 0.75, 1.0)
AXIS_COLORS = ((0.9, 0.1, 0.1, 1.0), (0.1, 0.75, 0.1, 1.0), (0.1, 0.25, 0.95, 1.0))


def character_mesh(character: SceneCharacter, color=PALETTE[0]) -> MeshItem | None:
    """The character's posed SMPL mesh in character space (scaled by ``scale``), or None without a pose."""
    from smplik.body_model import load_body_model

    pose = character.pose
    if pose is None:
        return None
    model = load_body_model(character.gender)

    def t(x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.asarray(x, dtype=np.float32))[None]

    with torch.no_grad():
        verts, _ = model.vertices(t(pose.global_orient), t(pose.body_pose), t(pose.transl), t(pose.betas))
    return MeshItem(verts[0].numpy().astype(np.float64) * character.scale, model.faces, color)


def effector_markers(character: SceneCharacter, radius: float = 0.03) -> tuple[list[Sphere], list[Segment]]:
    """Marker spheres and segments for the character's effectors (character space)."""
    joints = character_joints(character) if character.effectors else None
    spheres: list[Sphere] = []
    segments: list[Segment] = []
    axis_len = 0.15 * character.scale
    for e in character.effectors:
        at = None if joints is None else joints[e.joint]
        if e.type == EffectorType.POSITION:
            spheres.append(Sphere(np.asarray(e.value), radius, EFFECTOR_COLOR))
        elif e.type == EffectorType.ROTATION:
            if at is None:
                continue
            for k in range(3):
                segments.append(Segment(at, at + axis_len * np.asarray(e.value)[:, k], radius * 0.3, AXIS_COLORS[k]))
        else:
            target = np.asarray(e.value)
            if at is not None:
                segments.append(Segment(at, target, radius * 0.25, EFFECTOR_COLOR))
            spheres.append(Sphere(target, radius * 0.7, EFFECTOR_COLOR))
    return spheres, segments


def custom_skeleton_segments(char: CustomCharacter, pose: CustomPose, color=(0.95, 0.5, 0.1, 1.0),
                             radius: float = 0.012) -> list[Segment]:
    """Bones of a posed custom skeleton as segments in character space (canon frame).

    Bones above the pelvis (an unmapped root joint left on the floor, such as Bandai-Namco's ``joint_Root``,
    while the hips move) are not drawn: they are no part of the body and would draw a stray line.
    """
    _, p_file = pose.positions(char)
    p = (p_file * char.units_m) @ char.C_canon_file.T - char.shift
    above = set()  # unmapped joints above the pelvis (Bandai-Namco's joint_Root on the floor): no bone drawn
    pelvis = next((k for k in range(len(char.parents)) if char.smpl_of[k] == 0), -1)
    k = char.parents[pelvis] if pelvis >= 0 else -1
    while k >= 0:
        above.add(k)
        k = char.parents[k]
    return [Segment(p[par], p[k], radius, color) for k, par in enumerate(char.parents) if par >= 0 and par not in above]


def scene_items(scene: Scene, *, markers: bool = True,
                base_dir: str | Path | None = None) -> tuple[list[MeshItem], list[Sphere], list[Segment]]:
    """Meshes (one colour per character) and effector markers of every character.

    ``base_dir``: the folder relative skeleton paths are resolved against (the scene file's; default: the
    current folder)."""
    meshes, spheres, segments = [], [], []
    from workflows.character_mesh import scene_character_own_mesh

    for i, c in enumerate(scene.characters):  # a glTF character's own skinned mesh, else its SMPL body
        color = PALETTE[i % len(PALETTE)]
        mesh = scene_character_own_mesh(c, color, base_dir) or character_mesh(c, color)
        if mesh is not None:
            meshes.append(mesh)
        if markers:
            s, g = effector_markers(c, radius=0.03 * c.scale)
            spheres += s
            segments += g
    return meshes, spheres, segments


GHOST_COLOR = (0.12, 0.12, 0.12, 1.0)
"""Colour of the ghost skeletons (the estimator's original poses)."""


def image_camera(scene: Scene, width: int, height: int) -> ImageCamera:
    """The estimator's camera for an image of this size (OpenGL axes; at the origin, or raised by ``--ground``)."""
    if scene.camera is None:
        raise ValueError("The scene has no camera; it cannot be drawn over an image.")
    f = scene.camera.focal_for(width, height)
    cx, cy = scene.camera.principal_for(width, height)
    T_world_camera = np.eye(4)
    if scene.ground is not None:
        T_world_camera[1, 3] = scene.ground.camera_height_m
    # pyrender's principal point is measured from the top-left like OpenCV's
    return ImageCamera(f, f, cx, cy, T_world_camera)


def ghost_segments(pose: Pose, scale: float = 1.0, color=GHOST_COLOR, radius: float = 0.012) -> list[Segment]:
    """A pose's skeleton (SMPL space, drawn in character space ``x scale``) as wireframe bones."""
    from workflows.scene.recovery import TargetPose

    joints = (pose.joints if pose.joints is not None else TargetPose.from_pose(pose).p_world.double().numpy())
    p = np.asarray(joints, dtype=np.float64) * scale
    return [Segment(p[par], p[k], radius * scale, color) for k, par in enumerate(PARENTS) if par >= 0]


def render_scene(scene: Scene, *, image: np.ndarray | None = None, size: tuple[int, int] = (480, 640),
                 directions: Sequence[Sequence[float]] = ((0.0, 0.2, 1.0), (1.0, 0.2, 0.0)),
                 extra_segments: Sequence[Segment] = (), ghosts: Sequence[Pose | None] = (),
                 errors_m: Sequence[float | None] = (), labels: bool = True,
                 base_dir: str | Path | None = None) -> np.ndarray:
    """All characters with markers: over ``image`` (RGB uint8, estimator camera) and/or from ``directions``.

    Args:
        ghosts: per character (scene order), the estimator's original pose (SMPL space of that
            character's body) drawn as a dark wireframe skeleton; None skips one.
        errors_m: per character, its final error (metres) printed in the legend.
        labels: name every panel and list the people (colour, name, final error).
        base_dir: the folder relative skeleton paths are resolved against (the scene file's).

    Returns the panels side by side (RGB uint8). ``size`` = (width, height) of each 3D view.
    """
    meshes, spheres, segments = scene_items(scene, base_dir=base_dir)
    segments = segments + list(extra_segments)
    for c, g in zip(scene.characters, ghosts, strict=False):
        if g is not None:
            segments += ghost_segments(g, c.scale)
    legend = []
    for i, c in enumerate(scene.characters):
        err = errors_m[i] if i < len(errors_m) else None
        legend.append(f"{c.name}: {len(c.effectors)} effectors" + ("" if err is None else
                                                                  f", final error {err * 1000:.0f} mm"))
    colors = [PALETTE[i % len(PALETTE)] for i in range(len(scene.characters))]
    ghost_note = ["dark wireframe: estimator's pose"] if any(g is not None for g in ghosts) else []
    panels = []
    if image is not None:
        h, w = image.shape[:2]
        img = render(meshes, spheres, segments, size=(w, h), view=image_camera(scene, w, h),
                     background=np.ascontiguousarray(image[..., :3]))
        panels.append(label_image(img, ["over the photo (estimator camera)", *legend, *ghost_note],
                                  colors=[None, *colors]) if labels else img)
    for k, d in enumerate(directions):
        img = render(meshes, spheres, segments, size=size, view=View(direction=tuple(d)),
                     background=(1.0, 1.0, 1.0, 1.0))
        if panels and img.shape[0] != panels[0].shape[0]:
            img = _fit_height(img, panels[0].shape[0])
        if labels:
            name = {0: "front view", 1: "side view"}.get(k, f"view {k + 1}")
            extra = [*legend, *ghost_note] if image is None and k == 0 else []
            img = label_image(img, [name, *extra], colors=[None, *colors] if extra else None)
        panels.append(img)
    return hstack_images(panels)


def render_custom_character(char: CustomCharacter, pose: CustomPose, character: SceneCharacter,
                            size: tuple[int, int] = (480, 640)) -> np.ndarray:
    """Custom skeleton (orange bones, over its own posed mesh for glTF characters) beside its SMPL approximation."""
    from workflows.character_mesh import own_mesh_item

    bones = custom_skeleton_segments(char, pose)
    spheres, segments = effector_markers(character, radius=0.03 * character.scale)
    mesh = character_mesh(character)
    own = own_mesh_item(char, pose)
    left = render([mesh] if mesh is not None else [], spheres, segments, size=size, view=View((0.3, 0.2, 1.0)))
    right = render([own] if own is not None else [], spheres, segments + bones, size=size,
                   view=View((0.3, 0.2, 1.0)))
    return hstack_images([left, right])


def _fit_height(img: np.ndarray, height: int) -> np.ndarray:
    """Nearest-neighbour resize to ``height`` keeping the aspect ratio."""
    h, w = img.shape[:2]
    new_w = max(1, round(w * height / h))
    rows = (np.arange(height) * h / height).astype(int)
    cols = (np.arange(new_w) * w / new_w).astype(int)
    return img[rows][:, cols]


def plot_recovery_errors(errors_m: Sequence[float], path: str | Path, *, title: str = "Effector recovery",
                         threshold_m: float | None = None) -> Path:
    """Mean per-joint error (mm) versus the number of recovered effectors, as a PNG (atomic)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from smplik.atomic import atomic_path

    fig, ax = plt.subplots(figsize=(4.5, 3.2), dpi=100)
    k = np.arange(1, len(errors_m) + 1)
    ax.plot(k, np.asarray(errors_m) * 1000.0, "o-", color="#7b2cbf")
    if threshold_m is not None:
        ax.axhline(threshold_m * 1000.0, ls="--", color="grey", label=f"threshold {threshold_m * 1000:.0f} mm")
        ax.legend()
    ax.set_xlabel("recovered effectors")
    ax.set_ylabel("mean joint error (mm)")
    ax.set_title(title)
    ax.set_xticks(k)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp)
    plt.close(fig)
    return Path(path)


def load_image(path: str | Path) -> np.ndarray:
    """An image file as RGB uint8 (H, W, 3), decoded straight to uint8 (never float32). Before decoding: a
    regular file (:func:`smplik.limits.check_input_file`), its pixel count (from the header) within
    :data:`smplik.limits.IMAGE_PIXELS` and its decoded size (4 bytes a pixel, twice: the decoded image and
    its RGB copy) within :data:`smplik.limits.MEMORY_BYTES`."""
    from PIL import Image

    from smplik.limits import IMAGE_PIXELS, MEMORY_BYTES, check_input_file

    check_input_file(path, "image")
    with warnings.catch_warnings():  # PIL warns over 89 Mpx (several stderr lines); the limits below decide
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        with Image.open(path) as img:  # reads the header only
            width, height = img.size
            IMAGE_PIXELS.check(width * height, f"{path} ({width} x {height} image)")
            MEMORY_BYTES.check(width * height * 8, f"{path} ({width} x {height} image decoded at 8 bytes a pixel)")
            if img.mode in ("I", "I;16", "I;16B", "I;16L", "I;16N"):  # 16-bit grey: keep the top 8 bits
                grey = (np.asarray(img).astype(np.uint32) >> 8).clip(0, 255).astype(np.uint8)
                return np.ascontiguousarray(np.repeat(grey[..., None], 3, axis=-1))
            if img.mode == "F":
                grey = (np.clip(np.asarray(img), 0.0, 1.0) * 255).astype(np.uint8)
                return np.ascontiguousarray(np.repeat(grey[..., None], 3, axis=-1))
            return np.ascontiguousarray(np.asarray(img.convert("RGB"), dtype=np.uint8))
