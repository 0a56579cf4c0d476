"""Make docs/demo_edit_before_after.png: the demo's edit (person_0's right wrist raised 25 cm) solved two ways.

``PYOPENGL_PLATFORM=egl PYTHONPATH=. python docs/make_edit_before_after.py [--out docs/demo_edit_before_after.png]``
runs the demo into a temporary folder (``workflows.demo.run_demo``). Top: the same drag with every recovered
effector kept exact and the whole body solved (the drag before ``workflows.scene.edits``); bottom: the demo's own
``character/scene_edited.json`` (the drag of ``workflows.scene.edits.solve_drag``). Each title gives the torso's
largest turn and how far the other wrist moved.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _figures(before, after) -> str:
    from smplik.conventions import JOINT_INDEX
    from smplik.rotations import geodesic_distance
    from workflows.edit_benchmark.pairs import TORSO_JOINTS
    from workflows.scene.recovery import TargetPose

    fk0 = TargetPose.from_pose(dataclasses.replace(before.pose, joints=None))
    fk1 = TargetPose.from_pose(dataclasses.replace(after.pose, joints=None))
    turn = max(float(np.degrees(geodesic_distance(fk0.R_world[JOINT_INDEX[n]].double(),
                                                  fk1.R_world[JOINT_INDEX[n]].double()))) for n in TORSO_JOINTS)
    left = JOINT_INDEX["left_wrist"]
    moved = 100.0 * float(np.linalg.norm((fk1.p_world[left] - fk0.p_world[left]).double().numpy()))
    return f"torso turned up to {turn:.0f} deg, the other wrist moved {moved:.0f} cm"


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from smplik.effectors import Effector
    from smplik.render import save_png
    from smplik.solver import IKSolver
    from workflows.demo import EDIT_JOINT, EDIT_RAISE_M, run_demo
    from workflows.scene import character_joints, load_scene, solve_character
    from workflows.scene.previews import load_image, render_scene

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "demo_edit_before_after.png")
    args = parser.parse_args()
    solver = IKSolver.load()
    with tempfile.TemporaryDirectory() as tmp:
        out = run_demo(Path(tmp), solver)
        photo = load_image(out.examples[1])
        scene = load_scene(out.character.scene)
        edited = load_scene(out.edited_scene)
        first = scene.characters[0]
        wrist = character_joints(first)[Effector.position(EDIT_JOINT, (0, 0, 0)).joint]
        target = Effector.position(EDIT_JOINT, wrist + np.array([0.0, EDIT_RAISE_M, 0.0]))
        kept = tuple(e for e in first.effectors if not (e.joint == target.joint and e.type == target.type))
        old = solve_character(dataclasses.replace(first, effectors=kept + (target,)), solver)
        old_scene = dataclasses.replace(scene, characters=(old,) + scene.characters[1:])
        panels = [("before: every recovered effector kept exact, the whole body solved: " + _figures(first, old),
                   render_scene(old_scene, image=photo)),
                  ("now: the drag relaxes the arm's stale effectors and poses only the arm (two-bone IK with the "
                   "prior's elbow): " + _figures(first, edited.characters[0]), render_scene(edited, image=photo))]
    h, w = panels[0][1].shape[:2]
    fig, axes = plt.subplots(2, 1, figsize=(w / 100, 2 * (h + 30) / 100), dpi=100)
    for ax, (title, img) in zip(axes, panels, strict=True):
        ax.imshow(img)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    buf = Path(tempfile.mkstemp(suffix=".png")[1])
    fig.savefig(buf, dpi=100)
    plt.close(fig)
    save_png(np.asarray(plt.imread(buf) * 255, dtype=np.uint8), args.out)
    buf.unlink()
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
