"""Scripted edits: a wrist raised 25 cm by a script, solved as a drag (today) or re-solved exactly (before).

``python benchmarks/scripted_edits.py [--checkpoint FILE]`` writes benchmarks/results/scripted_edits.json and
prints one row per edit.

* Scenes: the demo's two people (``write_romp_example`` through ``from_estimate`` with the demo's recovery
  settings), on the SMPL body and on the demo's Mixamo character. Each wrist of each person is moved (or added)
  25 cm above where the stored pose has it, as a script editing ``scene.json`` does, then solved by
  ``scene solve`` (:func:`workflows.scene.edits.solve_scene_edits`) and by ``scene solve --exact``
  (:func:`workflows.scene.solve_scene`). Figures: the wrist's distance to its target, the head's and the other
  wrist's move relative to the pelvis, the pelvis's move (mm).
* Animations: ``scene animate`` of a 30-frame GVHMR clip in GVHMR's layout (``tests/animation_fixtures.py``),
  on the SMPL body and the Mixamo character; at every keyframe and at one frame between keyframes, an effector
  file naming only one wrist, raised 25 cm: :func:`workflows.animation.keyframe_edit.keyframe_edit` (merge + drag) and
  the previous command (the file's effector alone, solved exactly: the same call on the track without its
  keyframes, ``exact=True``). Figures: the wrist's distance to its target, the pelvis's and the feet's (ankles
  and feet, largest) move at that frame (mm).

No timing: these are accuracy figures. One torch thread.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _common import save  # noqa: E402

from smplik.conventions import JOINT_INDEX  # noqa: E402
from smplik.effectors import Effector  # noqa: E402

RAISE = np.array([0.0, 0.25, 0.0])
WRISTS = ("left_wrist", "right_wrist")
FEET = [JOINT_INDEX[n] for n in ("left_ankle", "right_ankle", "left_foot", "right_foot")]


def scenes(solver, folder: Path) -> list[dict]:
    from workflows.examples_gen import write_mixamo_character, write_romp_example
    from workflows.scene import character_joints, load_scene, solve_scene
    from workflows.scene.edits import solve_scene_edits
    from workflows.scene.pipeline import from_estimate
    from workflows.scene.recovery import RecoveryConfig

    npz = write_romp_example(folder / "romp_two_people.npz")
    bvh = write_mixamo_character(folder / "mixamo_character.bvh")
    config = RecoveryConfig(max_effectors=6, threshold=0.02)
    rows = []
    for body, extra in (("smpl", {}), ("character", {"character_path": bvh, "rig": "mixamo"})):
        out = from_estimate(npz, folder / body, solver, format="romp", config=config, previews=False, **extra)
        scene = load_scene(out.scene)
        for n, c in enumerate(scene.characters):
            J0 = character_joints(c)
            for wrist in WRISTS:
                other = WRISTS[1 - WRISTS.index(wrist)]
                target = Effector.position(wrist, J0[JOINT_INDEX[wrist]] + RAISE)
                effs = [e for e in c.effectors if not (e.joint == target.joint and e.type == target.type)]
                edited = dataclasses.replace(scene, characters=scene.characters[:n] + (
                    dataclasses.replace(c, effectors=(*effs, target)),) + scene.characters[n + 1:])
                for method, solved in (("drag", solve_scene_edits(edited, solver)[0]),
                                       ("exact", solve_scene(edited, solver))):
                    J1 = character_joints(solved.characters[n])
                    rel = (J1 - J1[0]) - (J0 - J0[0])
                    rows.append({"body": body, "person": c.name, "wrist": wrist, "method": method,
                                 "reach_mm": 1000 * float(np.linalg.norm(J1[target.joint] - target.value)),
                                 "head_mm": 1000 * float(np.linalg.norm(rel[JOINT_INDEX["head"]])),
                                 "other_wrist_mm": 1000 * float(np.linalg.norm(rel[JOINT_INDEX[other]])),
                                 "pelvis_mm": 1000 * float(np.linalg.norm(J1[0] - J0[0]))})
    return rows


def animations(solver, folder: Path) -> list[dict]:
    from animation_fixtures import video_motion, write_gvhmr_video

    from shape_inversion.options import CharacterOptions
    from workflows.animation.files import scene_of
    from workflows.animation.keyframe_edit import keyframe_edit
    from workflows.animation.run import animate_file
    from workflows.examples_gen import write_mixamo_character
    from workflows.scene import character_joints

    aa, transl = video_motion(30, seed=11)
    results = write_gvhmr_video(folder, aa, transl)
    bvh = write_mixamo_character(folder / "mixamo_character.bvh")
    rows = []
    for body, extra in (("smpl", {}), ("character", {"character_path": bvh,
                                                     "character_options": CharacterOptions(rig="mixamo")})):
        anim = animate_file(results, folder / body, solver, fps=30, formats=[], **extra).animation
        track = anim.tracks[0]
        keys = [k.frame for k in track.keyframes]
        bare = dataclasses.replace(anim, tracks=(dataclasses.replace(track, keyframes=()),))
        frames = keys + [next(f for f in track.frames if f > keys[1] and f not in keys)]
        for frame in frames:
            J0 = character_joints(scene_of(anim, frame).characters[0])
            for wrist in WRISTS:
                target = Effector.position(wrist, J0[JOINT_INDEX[wrist]] + RAISE)
                for method, source, exact in (("merge_drag", anim, False), ("previous", bare, True)):
                    edit = keyframe_edit(source, track.name, frame, [target], solver, window=4, exact=exact)
                    J1 = character_joints(scene_of(edit.animation, frame).characters[0])
                    rows.append({"body": body, "frame": frame, "keyframe": frame in keys, "wrist": wrist,
                                 "method": method,
                                 "reach_mm": 1000 * float(np.linalg.norm(J1[target.joint] - target.value)),
                                 "pelvis_mm": 1000 * float(np.linalg.norm(J1[0] - J0[0])),
                                 "feet_mm": 1000 * float(np.linalg.norm(J1[FEET] - J0[FEET], axis=-1).max())})
    return rows


def summary(rows: list[dict], keys: list[str]) -> dict:
    out = {}
    for method in sorted({r["method"] for r in rows}):
        sel = [r for r in rows if r["method"] == method]
        out[method] = {k: {"max": max(r[k] for r in sel), "mean": float(np.mean([r[k] for r in sel]))} for k in keys}
        out[method]["count"] = len(sel)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    from smplik.solver import IKSolver

    solver = IKSolver.load(args.checkpoint)
    with tempfile.TemporaryDirectory() as tmp:
        scene_rows = scenes(solver, Path(tmp))
        anim_rows = animations(solver, Path(tmp))
    for r in scene_rows:
        print(f"scene {r['body']:9s} {r['person']} {r['wrist']:11s} {r['method']:5s}: reach {r['reach_mm']:6.1f} "
              f"head {r['head_mm']:6.1f} other wrist {r['other_wrist_mm']:6.1f} pelvis {r['pelvis_mm']:6.1f} mm")
    for r in anim_rows:
        print(f"anim {r['body']:9s} frame {r['frame']:2d}{'*' if r['keyframe'] else ' '} {r['wrist']:11s} "
              f"{r['method']:10s}: reach {r['reach_mm']:6.1f} pelvis {r['pelvis_mm']:6.1f} feet {r['feet_mm']:6.1f} mm")
    result = {"scenes": {"summary": summary(scene_rows, ["reach_mm", "head_mm", "other_wrist_mm", "pelvis_mm"]),
                         "edits": scene_rows},
              "animations": {"summary": summary(anim_rows, ["reach_mm", "pelvis_mm", "feet_mm"]), "edits": anim_rows}}
    for part in ("scenes", "animations"):
        for method, s in result[part]["summary"].items():
            print(part, method, {k: (round(v["max"], 1) if isinstance(v, dict) else v) for k, v in s.items()})
    print(f"wrote {save('scripted_edits', result)}")


if __name__ == "__main__":
    main()
