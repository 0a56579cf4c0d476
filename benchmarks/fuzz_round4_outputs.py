"""The fuzz campaign's round-4 output and reader cases (issue 45, the "outputs never touch inputs" half).

:func:`round4_output_cases` writes its own small material and returns cases that ``benchmarks/fuzz_campaign.py``
runs with the crafted cases; every one must end as ``clean_error`` (exit 1, one ``error:`` line) and leave its
``keep`` file byte-identical, except the ``r4_budget`` runs, which must be ``accepted`` under 2 GB. Groups (the
``reader`` of each case):

* ``r4_outputs`` (O1-O4): ``track OUT/animation.json --out OUT``; ``track t.json --character OUT/person_0.bvh
  --out OUT --export bvh``; ``scene variants OUT/variant_0.json --out OUT``; ``scene export OUT/scene.json --out
  OUT`` whose skeleton is ``OUT/person_0.bvh``; the same through a symlinked ``--out``; a scene's ``"image":
  "/dev/zero"`` in ``scene render``; a ``--preview`` that is a folder;
* ``r4_gltf`` (GW, GJ, VR): a root ``matrix`` 1e200 times a hips ``scale`` 1e200; a 100,000-joint chain; a
  3-joint skin plus 200,000 nodes; ``--max-joints 10``; ``VRMC_vrm.humanoid = ["x"]``; ``VRM.humanoid = "abc"``;
* ``r4_draco`` (DB): ``scene render`` of a scene whose character is a skinned GLB whose Draco primitive (64 bytes)
  declares 3e8 points (the skeleton path relative to the scene's folder);
* ``r4_errors``: a JSON number of 5000 digits, a glTF node ``rotation`` [0, 0, 0, 0], a NUL in a scene's
  ``image`` path (each message must name the file);
* ``r4_budget``: ``scene variants --k 64 --candidates 1024`` (peak memory), a BVH star of 9,990 children
  (wall time; refused as not a human).

Run alone (each case once, its wall time and peak memory)::

    PYTHONPATH=. python benchmarks/fuzz_round4_outputs.py

writes ``benchmarks/results/fuzz_round4_outputs.json``.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

from fuzz_campaign import ROOT, Case, run_case

RESULTS = ROOT / "benchmarks" / "results" / "fuzz_round4_outputs.json"


def _gltf(path: Path, nodes: list, skins: list | None = None, extensions: dict | None = None) -> Path:
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": nodes}
    if skins is not None:
        doc["skins"] = skins
    if extensions:
        doc["extensions"] = extensions
    path.write_text(json.dumps(doc))
    return path


def _trackers(frames: int = 20) -> dict:
    still = {"head": [0.0, 1.6, 0.0], "left_wrist": [0.25, 0.85, 0.05], "right_wrist": [-0.25, 0.85, 0.05],
             "pelvis": [0.0, 0.95, 0.0]}
    tracks = {n: {"position": [p] * frames, "rotation": [[1.0, 0, 0, 0]] * frames} for n, p in still.items()}
    return {"format": "smplik-trackers", "version": 1, "fps": 60, "trackers": tracks}


def _star_bvh(path: Path, children: int = 9990) -> Path:
    lines = ["HIERARCHY", "ROOT Hips", "{", "  OFFSET 0 0 0",
             "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    for i in range(children):
        lines += [f"  JOINT c{i}", "  {", f"    OFFSET {i % 7} 1 0", "    CHANNELS 3 Zrotation Xrotation Yrotation",
                  "    End Site", "    {", "      OFFSET 0 1 0", "    }", "  }"]
    lines += ["}", "MOTION", "Frames: 1", "Frame Time: 0.033333", " ".join(["0"] * (6 + 3 * children))]
    path.write_text("\n".join(lines) + "\n")
    return path


def _draco_bomb_scene(folder: Path) -> Path:
    """``folder/bomb.glb``: the Mixamo GLB whose skinned primitive is a 64-byte Draco point cloud (google/draco
    bitstream 2.3, as DracoPy encodes it) declaring 3e8 points; ``folder/scene.json`` poses it (relative path)."""
    import DracoPy
    import numpy as np
    import pygltflib

    from workflows.character import CharacterOptions
    from workflows.examples_gen import example_poses
    from workflows.layout_examples import smpl_rest, write_mixamo_gltf
    from workflows.scene import Scene, SceneCharacter, SkeletonSource, save_scene

    bomb = bytearray(DracoPy.encode(np.random.default_rng(0).random((10, 3)).astype(np.float32)))
    bomb[11:15] = (300_000_000).to_bytes(4, "little")  # the point count of the point-cloud header
    bomb = bytes(bomb[:64].ljust(64, b"\0"))
    J, V, F, W = smpl_rest()
    g = pygltflib.GLTF2().load(str(write_mixamo_gltf(folder / "plain.glb", J, (V, F, W))))
    blob = bytearray(g.binary_blob())
    blob.extend(b"\0" * (-len(blob) % 4))
    g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(bomb)))
    blob.extend(bomb)
    g.meshes[0].primitives[0].extensions = {"KHR_draco_mesh_compression": {
        "bufferView": len(g.bufferViews) - 1, "attributes": {"POSITION": 0, "JOINTS_0": 1, "WEIGHTS_0": 2}}}
    g.buffers[0].byteLength = len(blob)
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(folder / "bomb.glb"))
    pose = example_poses()[0].pose
    character = SceneCharacter("hero", pose.gender, pose.betas, 1.0,
                               SkeletonSource.from_options("bomb.glb", CharacterOptions()), (), pose)
    return save_scene(Scene((character,)), folder / "scene.json")


def round4_output_cases(work: Path) -> list[Case]:
    """The cases of the module docstring, with their material written under ``work``."""
    import dataclasses

    import numpy as np

    from smplik.conventions import Gender
    from smplik.effectors import Effector
    from smplik.solver import IKSolver
    from workflows.layout_examples import smpl_rest, write_mixamo_bvh
    from workflows.scene import Scene, SceneCharacter, save_scene
    from workflows.scene.characters import SkeletonSource

    work.mkdir(parents=True, exist_ok=True)
    cases: list[Case] = []
    counter = iter(range(10**6))

    def folder() -> Path:
        d = work / f"r{next(counter):03d}"
        d.mkdir()
        return d

    trackers = work / "trackers.json"
    trackers.write_text(json.dumps(_trackers()))
    bvh = write_mixamo_bvh(work / "hero.bvh", smpl_rest()[0])
    eff = (Effector.position("left_wrist", [0.4, 1.1, 0.2]), Effector.position("pelvis", [0.0, 0.9, 0.1]),
           Effector.position("right_ankle", [-0.1, 0.1, 0.0]))
    pose = IKSolver.load().solve(list(eff))
    scene = Scene((SceneCharacter("person_0", Gender.NEUTRAL, np.zeros(10), 1.0, None, eff, pose),))
    scene_file = save_scene(scene, work / "scene.json")

    # O1-O4 and their variants
    d = folder()
    (d / "animation.json").write_text(json.dumps(_trackers()))
    cases.append(Case("r4_outputs", ["track", str(d / "animation.json"), "--out", str(d)],
                      "O1 track OUT/animation.json --out OUT", keep=d / "animation.json"))
    (work / f"link{d.name}").symlink_to(d, target_is_directory=True)
    cases.append(Case("r4_outputs", ["track", str(d / "animation.json"), "--out", str(work / f"link{d.name}")],
                      "O1 through a symlinked --out", keep=d / "animation.json"))
    d = folder()
    (d / "person_0.bvh").write_bytes(bvh.read_bytes())
    cases.append(Case("r4_outputs", ["track", str(trackers), "--character", str(d / "person_0.bvh"), "--out", str(d),
                                     "--export", "bvh"], "O2 --character OUT/person_0.bvh", keep=d / "person_0.bvh"))
    d = folder()
    (d / "variant_0.json").write_bytes(scene_file.read_bytes())
    cases.append(Case("r4_outputs", ["scene", "variants", str(d / "variant_0.json"), "--out", str(d), "--k", "2"],
                      "O3 scene variants OUT/variant_0.json --out OUT", keep=d / "variant_0.json"))
    d = folder()
    (d / "person_0.bvh").write_bytes(bvh.read_bytes())
    chars = (dataclasses.replace(scene.characters[0], skeleton=SkeletonSource("person_0.bvh")),)
    save_scene(dataclasses.replace(scene, characters=chars), d / "scene.json")
    cases.append(Case("r4_outputs", ["scene", "export", str(d / "scene.json"), "--out", str(d)],
                      "O4 scene export OUT/scene.json, skeleton OUT/person_0.bvh", keep=d / "person_0.bvh"))
    d = folder()
    from workflows.estimators.base import CameraInfo

    save_scene(dataclasses.replace(scene, image="/dev/zero", camera=CameraInfo(image_size=(64, 48))), d / "s.json")
    cases.append(Case("r4_outputs", ["scene", "render", str(d / "s.json"), "--out", str(d / "r.png")],
                      "scene image /dev/zero", keep=d / "s.json"))
    d = folder()
    (d / "p.gif").mkdir()
    cases.append(Case("r4_outputs", ["scene", "animate", str(d / "none.npz"), "--out", str(d / "o"), "--preview",
                                     str(d / "p.gif")], "--preview naming a folder"))

    # GW, GJ, VR
    d = folder()
    gw = _gltf(d / "gw.gltf", [{"name": "root", "matrix": [1e200, 0, 0, 0, 0, 1e200, 0, 0, 0, 0, 1e200, 0, 0, 0, 0, 1],
                                "children": [1]}, {"name": "hips", "scale": [1e200] * 3, "children": [2]},
                               {"name": "spine", "translation": [0, 1, 0]}], [{"joints": [1, 2]}])
    cases.append(Case("r4_gltf", ["invert-shape", str(gw), "--out", str(d / "s.json"), "--bind", "nodes"],
                      "GW root matrix 1e200 x hips scale 1e200", keep=gw))
    n = 100_000
    chain = [{"name": f"j{i}", "translation": [0, 0.01, 0], **({"children": [i + 1]} if i < n - 1 else {})}
             for i in range(n)]
    deep = _gltf(d / "chain.gltf", chain, [{"joints": list(range(n))}])
    cases.append(Case("r4_gltf", ["invert-shape", str(deep), "--out", str(d / "s.json")], "GJ 100,000-joint chain",
                      keep=deep))
    wide = _gltf(d / "wide.gltf", [{"name": "a", "children": [1]}, {"name": "b", "translation": [0, 1, 0],
                                   "children": [2]}, {"name": "c", "translation": [0, 1, 0]}]
                 + [{"name": f"x{i}"} for i in range(200_000)], [{"joints": [0, 1, 2]}])
    cases.append(Case("r4_gltf", ["invert-shape", str(wide), "--out", str(d / "s.json")],
                      "GJ 3-joint skin + 200,000 nodes", keep=wide))
    small = _gltf(d / "small.gltf", chain[:30] + [{"name": "j30"}], [{"joints": list(range(31))}])
    cases.append(Case("r4_gltf", ["invert-shape", str(small), "--out", str(d / "s.json"), "--max-joints", "10"],
                      "GJ --max-joints 10 on 31 joints", keep=small))
    for name, ext in (("vr1", {"VRMC_vrm": {"humanoid": ["x"]}}), ("vr2", {"VRM": {"humanoid": "abc"}})):
        vr = _gltf(d / f"{name}.gltf", [{"name": "a", "children": [1]}, {"name": "b", "translation": [0, 1, 0]}],
                   None, ext)
        cases.append(Case("r4_gltf", ["invert-shape", str(vr), "--out", str(d / "s.json")], f"VR {ext}", keep=vr))

    # DB: a Draco point cloud declaring 3e8 points on the skinned mesh, through scene render
    try:
        import DracoPy  # noqa: F401
    except ImportError:
        pass  # no Draco decoder: such a mesh is never decoded (one warning)
    else:
        d = folder()
        _draco_bomb_scene(d)
        cases.append(Case("r4_draco", ["scene", "render", str(d / "scene.json"), "--out", str(d / "r.png")],
                          "DB Draco buffer declaring 3e8 points", keep=d / "bomb.glb"))

    # errors that must name the file
    d = folder()
    big = d / "effectors.json"
    big.write_text('{"format": "smplik-effectors", "effectors": [{"joint": ' + "9" * 5000 + "}]}")
    cases.append(Case("r4_errors", ["solve", str(big), "--out", str(d / "o.json")], "a 5000-digit JSON integer",
                      keep=big))
    q0 = _gltf(d / "q0.gltf", [{"name": "Hips", "rotation": [0, 0, 0, 0], "children": [1]},
                               {"name": "Spine", "translation": [0, 1, 0]}], [{"joints": [0, 1]}])
    cases.append(Case("r4_errors", ["invert-shape", str(q0), "--out", str(d / "s.json")],
                      "glTF node rotation [0, 0, 0, 0]", keep=q0))
    nul = json.loads(scene_file.read_text())
    nul["image"] = "a\u0000b.png"
    (d / "nul.json").write_text(json.dumps(nul))
    cases.append(Case("r4_errors", ["scene", "render", str(d / "nul.json"), "--out", str(d / "r.png")],
                      "a NUL in a scene's image path", keep=d / "nul.json"))

    # budgets: accepted (variants) or refused (star), measured
    d = folder()
    cases.append(Case("r4_budget", ["scene", "variants", str(scene_file), "--out", str(d / "v"), "--k", "64",
                                    "--candidates", "1024"], "variants --k 64 --candidates 1024"))
    star = _star_bvh(d / "star.bvh")
    cases.append(Case("r4_budget", ["invert-shape", str(star), "--out", str(d / "s.json")],
                      "BVH star of 9,990 children", keep=star))
    return cases


def main() -> None:
    work = Path(tempfile.mkdtemp(prefix="smplik-r4-"))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYOPENGL_PLATFORM": "egl", "OMP_NUM_THREADS": "1",
           "PYTHONWARNINGS": "ignore", "COLUMNS": "80"}
    rows = []
    for case in round4_output_cases(work):
        start = time.perf_counter()
        res = run_case(case, 600.0, env)
        res["wall_s"] = round(time.perf_counter() - start, 2)
        expected = "accepted" if case.note.startswith("variants") else "clean_error"
        res["as_expected"] = res["outcome"] == expected and res["peak_mb"] < 2048
        rows.append(res)
        print(f"{res['outcome']:<13} {res['wall_s']:7.2f} s {res['peak_mb']:7.0f} MB  {case.note[:50]:<50} "
              f"{res['last_line'][:80]}", flush=True)
    report = {"cases": rows, "all_as_expected": all(r["as_expected"] for r in rows),
              "peak_mb": max(r["peak_mb"] for r in rows), "python": sys.version.split()[0]}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
