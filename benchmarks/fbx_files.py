"""Real FBX files -> benchmarks/results/fbx_files.json: each read with no option, as every command reads it.

Files: the committed ones (``tests/data/fbx``: ufbx's test data, a Kenney character) and, with ``--dir DIR``,
every ``.fbx`` below DIR (files whose licence keeps them out of the repository, such as the Mixamo clips of
three.js's examples). Per file:

* read: FBX version, ASCII/binary, exporting tool, the file's unit and up axis, joints, the take read and its
  frames and frame rate, where the rest pose came from, and the seconds to read it (the ufbx child process,
  one take evaluated at the file's frame rate);
* character (``invert-shape``): the map's size, units, height (``Character.height_m``: feet to the top of the
  head), SMPL-SI scale, largest feature residual, whether it was read at its own size;
* posed error: the example poses retargeted onto the character against its SMPL pose (mapped joints after a
  rigid alignment, mean over joints, % of the character's height; per pose, the largest, and whether it is
  within the 3 % bar);
* training data (``data build``): frames retargeted per CPU second and the mean bone-direction error of the
  retargeted clip against the file's own skeleton (degrees);
* commands: every command a user runs on it with no option, through the CLI (``invert-shape``, ``scene
  from-estimate --character`` on a ROMP file of one person, ``scene export`` of that scene, and for an animated
  file ``data build`` on a folder holding it and ``data preview``): exit code, seconds, the last output line.

Run: ``python benchmarks/fbx_files.py [--dir DIR]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from smplik.atomic import write_json_atomic  # noqa: E402


def measure(path: Path) -> dict:
    import numpy as np

    from shape_inversion.auto_preset import auto_preset
    from shape_inversion.estimator import ShapeInversionError
    from shape_inversion.skeleton_io import _neutral_estimator, read_character
    from smplik.data.fbx import read_fbx_info
    from smplik.data.retarget import bone_direction_errors, retarget_bvh
    from workflows.character import build_character, retarget_error_m
    from workflows.examples_gen import example_poses

    row: dict = {"file": path.name}
    t0 = time.perf_counter()
    motion, info = read_fbx_info(path)
    row["read"] = {"seconds": round(time.perf_counter() - t0, 3), "version": info.version, "ascii": info.ascii,
                   "creator": info.creator, "unit_m": info.unit_m, "up": info.up, "joints": motion.num_joints,
                   "take": info.take, "takes": [t.name for t in info.takes], "frames": motion.num_frames,
                   "fps": round(motion.fps, 3), "rest": info.rest}
    char = read_character(path)
    height = char.height_m
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            est = _neutral_estimator().estimate(char.features, char.mapped_rest())
        except ShapeInversionError as exc:
            row["character"] = {"refused": str(exc)}
            return row
    row["character"] = {"mapped_joints": len(char.joint_map), "units_m": char.units_m, "height_m": round(height, 3),
                        "scale": round(est.scale, 3),
                        "max_feature_residual_mm": round(1000 * est.max_feature_residual_m, 1),
                        "own_size": any("read at its own size" in str(w.message) for w in caught)}
    cc = build_character(char.skeleton, est, rig=char.rig)
    posed = {p.name: round(100 * float(retarget_error_m(dataclasses.replace(p.pose, betas=cc.betas, gender=cc.gender),
                                                       cc).mean()) / height, 2) for p in example_poses()}
    row["posed_error_pct_of_height"] = {"per_pose": posed, "max": max(posed.values()),
                                        "within_3pct": max(posed.values()) <= 3.0}
    if motion.num_frames > 1:
        t0 = time.process_time()
        clip = retarget_bvh(motion, preset="auto", rig_mapper=auto_preset)
        cpu = time.process_time() - t0
        errors = bone_direction_errors(clip, frames=slice(0, None, 5))
        row["data_build"] = {"frames": clip.num_frames,
                             "frames_per_cpu_second": round(clip.num_frames / max(cpu, 1e-9)),
                             "bone_direction_error_deg_mean": round(float(np.mean(errors.mean())), 2)}
    row["commands"] = commands(path, animated=motion.num_frames > 1)
    return row


def commands(path: Path, animated: bool) -> dict:
    """Each command on ``path`` through the CLI, no option: {command: {exit, seconds, said}}."""
    import tempfile

    from typer.testing import CliRunner

    sys.path.insert(0, str(ROOT / "tests"))
    from estimator_fixtures import framing, people, write_romp

    from smplik.cli.main import app

    runner, out = CliRunner(), {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        aa, transl, betas = people(seed=3, n=1, **framing("romp"))
        romp = write_romp(tmp, aa, transl, betas).path
        clips = tmp / "clips"
        clips.mkdir()
        (clips / path.name).symlink_to(path.resolve())
        runs = {"invert-shape": ["invert-shape", str(path), "--out", str(tmp / "shape.json")],
                "scene from-estimate --character": ["scene", "from-estimate", str(romp), "--out", str(tmp / "scene"),
                                                    "--character", str(path), "--no-previews"],
                "scene export": ["scene", "export", str(tmp / "scene" / "scene.json"), "--out", str(tmp / "exp")]}
        if animated:
            runs["data build"] = ["data", "build", "--bvh", str(clips), "--out", str(tmp / "train.npz")]
            runs["data preview"] = ["data", "preview", str(path), "--out", str(tmp / "strip.png")]
        for name, args in runs.items():
            t0 = time.perf_counter()
            res = runner.invoke(app, args)
            lines = [ln for ln in res.output.splitlines() if ln.strip()]
            said = lines[-1] if lines else (repr(res.exception) if res.exception else "")
            out[name] = {"exit": res.exit_code, "seconds": round(time.perf_counter() - t0, 2),
                         "said": said.replace(str(tmp), "TMP")[:300]}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, default=None, help="Another folder of .fbx files (searched recursively).")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "fbx_files.json")
    args = parser.parse_args()
    files = sorted((ROOT / "tests" / "data" / "fbx").glob("*.fbx"))
    if args.dir is not None:
        files += sorted(p for p in args.dir.rglob("*") if p.suffix.lower() == ".fbx")
    rows = []
    for path in files:
        try:
            rows.append(measure(path))
        except ValueError as exc:  # a rig refusal: the file holds no humanoid (a cube's bones, a slime)
            rows.append({"file": path.name, "refused": str(exc).splitlines()[0]})
        print(rows[-1], flush=True)
    write_json_atomic(args.out, {"machine": machine(), "files": rows})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
