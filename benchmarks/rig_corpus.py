"""Real-rig corpus -> benchmarks/results/rig_corpus.json: every humanoid through the default path, no options.

The rigs are listed in ``benchmarks/rig_corpus/manifest.json`` with their source, licence, the tool or
pipeline that made them and a hand-checked expected map (SMPL joint -> rig joint; VRM files: their own
humanoid table). Files come from three places: ``repo:`` (committed, ``tests/data/rigs/``), ``shared:``
(the shared data folder, ``$SMPLIK_SHARED_DIR`` or ``../shared``) and ``local:`` (a folder of rigs whose
licence keeps them out of the repository: ``--corpus DIR`` or ``$SMPLIK_RIG_CORPUS``, default
``<cache>/real/rigs``, see ``smplik/paths.py``); a missing file is reported as skipped.

Per humanoid, exactly as ``smplik invert-shape`` / ``scene from-estimate --character`` read it (no option):

* map correct: the map used equals the expected one (for VRM files also the rig mapper's own map,
  the humanoid table ignored);
* units, up, rest pose, scale -> stature (the SMPL-SI estimate's scale and the skeleton's stature);
* fit residual (largest of the six SMPL-SI features, mm) and effective samples;
* pose error: the example pose retargeted onto the character against its SMPL pose (mapped joints after a
  rigid alignment, mean and largest distance in % of the stature; a BVH character should be within 3 %), and
  the same measure for SMPL's rest pose (what the rig's joint placement against its SMPL body costs before
  any pose: the part no retarget of rotations can remove, only a map choosing other joints or another body);
* SMPL-SI's joint fit: whether the second stage was kept and the rest residual of the first stage;
* export round trip: a pose (the example ``reach`` pose) retargeted onto the character, written as BVH
  (re-read with smplik's BVH reader) and, for glTF/VRM characters, as GLB (re-read with pygltflib and
  trimesh; the GLB is in the scene's world frame and keeps the source's animation clips); largest joint
  position error against the retargeted pose (mm).

Rigs whose file is absent here but which have a row in the previous results keep that row, marked
``"stale": true`` (measured by an earlier run, not now); the summary counts only the rigs run now.

Non-humanoids (a real rig made non-human: arms 2.5 x longer, legs 0.3 x) must be refused in one line
naming the features out of range.

Run: ``python benchmarks/rig_corpus.py [--corpus DIR] [--bank-samples 20000]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository's packages

import numpy as np  # noqa: E402

from benchmarks._common import save, shared_dir  # noqa: E402
from smplik.paths import rig_corpus_dir  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MANIFEST = Path(__file__).resolve().parent / "rig_corpus" / "manifest.json"


def resolve(file: str, corpus: Path) -> Path:
    kind, _, rel = file.partition(":")
    return {"repo": REPO, "shared": shared_dir(), "local": corpus}[kind] / rel


def round_trip(char, estimate, tmp: Path) -> dict:
    """Retarget the example pose onto the character, export BVH (+ GLB), re-read, compare joint positions."""
    from shape_inversion.gltf_io import load_gltf
    from smplik.data.bvh import read_bvh
    from workflows.character import build_character, custom_bvh_text, smpl_to_custom
    from workflows.examples_gen import example_poses
    from workflows.scene.export import posed_character_glb

    cc = build_character(char.skeleton, estimate, rig=char.rig)
    pose = dataclasses.replace(example_poses()[1].pose, betas=cc.betas, gender=cc.gender)
    custom = smpl_to_custom(pose, cc)
    _, p_file = custom.positions(cc)
    to_mm = 1000 * cc.units_m
    out: dict = pose_error(pose, cc, float(char.head_ankle_height_m / 0.84))
    bvh = tmp / "posed.bvh"
    bvh.write_text(custom_bvh_text(cc, [custom]))
    motion = read_bvh(bvh)
    order = [motion.index(n) for n in cc.names]  # names as written (3ds Max style names keep their spaces)
    out["bvh_max_error_mm"] = float(np.abs(motion.positions[0, order] - p_file).max() * to_mm)
    if cc.skeleton.gltf is not None:
        import pygltflib
        import trimesh

        glb = tmp / "posed.glb"
        glb.write_bytes(posed_character_glb(cc, [custom]))
        doc = load_gltf(glb)
        nodes = list(cc.skeleton.gltf.joint_nodes)
        world = cc.file_to_canon_points(p_file)  # the GLB is in the scene's world frame (metres)
        out["glb_max_error_mm"] = float(np.abs(doc.world[nodes, :3, 3] - world).max() * 1000)
        g = pygltflib.GLTF2.load_binary(str(glb))
        out["glb_animations"] = [a.name for a in g.animations or []]
        source_clips = [a.name for a in cc.skeleton.gltf.doc.gltf.animations or []]
        out["glb_keeps_source_clips"] = out["glb_animations"][:len(source_clips)] == source_clips \
            and len(out["glb_animations"]) == len(source_clips) + 1
        scene = trimesh.load(glb, force="scene")
        out["glb_trimesh_geometries"] = len(scene.geometry)
    return out


def pose_error(pose, cc, stature: float) -> dict:
    """Mean and largest distance (% of the stature) of the retargeted character's mapped joints from its SMPL
    pose after a rigid alignment (:func:`workflows.character.retarget_error_m`)."""
    from workflows.character import retarget_error_m

    err = retarget_error_m(pose, cc)
    rest = dataclasses.replace(pose, global_orient=np.zeros(3), body_pose=np.zeros_like(pose.body_pose))
    return {"pose_error_mean_pct": float(100 * err.mean() / stature),
            "pose_error_max_pct": float(100 * err.max() / stature),
            "rest_pose_error_mean_pct": float(100 * retarget_error_m(rest, cc).mean() / stature)}


def run_humanoid(entry: dict, path: Path, estimator, tmp: Path) -> dict:
    from shape_inversion.rig_mapper import map_skeleton
    from shape_inversion.skeleton_io import read_character

    row: dict = {"id": entry["id"], "tool": entry["tool"], "file": entry["file"]}
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        char = read_character(path)
        estimate = estimator.estimate(char.features, char.mapped_rest())
    expected = entry["expected"]
    got = char.joint_map
    row.update(rig=char.rig.name, root=char.rig.root, map_correct=got == expected,
               map_differences={k: [got.get(k), expected.get(k)] for k in sorted(set(got) | set(expected))
                                if got.get(k) != expected.get(k)},
               units_m=char.units_m, units_source=char.units_source, up=char.up, rest=char.skeleton.rest,
               joints=len(char.skeleton.names), mapped=len(got),
               stature_m=float(char.head_ankle_height_m / 0.84), scale=float(estimate.scale),
               smpl_stature_m=float(estimate.scale * 1.7),
               fit_residual_mm=float(estimate.max_feature_residual_m * 1000),
               effective_samples=float(estimate.effective_samples), joint_fit=bool(estimate.joint_fit),
               first_stage_rest_joint_residual_pct=float(100 * estimate.first_stage_rest_joint_residual_m
                                                         / (char.head_ankle_height_m / 0.84)),
               warnings=[str(w.message) for w in caught] + [f"map: {w}" for w in char.rig.warnings])
    if char.skeleton.humanoid:
        from shape_inversion.rig_mapper import RigMappingError

        sk = char.skeleton
        try:
            mapping = map_skeleton(sk.names, sk.parents, sk.positions)
        except RigMappingError as exc:  # a table-only humanoid (e.g. legs spread 180 deg): the table maps it
            row.update(mapper_without_table_correct=False, mapper_without_table_error=str(exc))
        else:
            mine = {s: sk.names[j] for s, j in mapping.joints.items()}
            row["mapper_without_table_correct"] = mine == expected
    row.update(round_trip(char, estimate, tmp))
    row["seconds"] = time.perf_counter() - t0
    row["passed"] = bool(row["map_correct"] and row["bvh_max_error_mm"] < 1.0
                         and row.get("glb_max_error_mm", 0.0) < 1.0 and row.get("glb_keeps_source_clips", True))
    return row


def run_non_humanoid(name: str, base: Path, limbs: dict[str, float], estimator) -> dict:
    """A real rig made non-human (the bones below a limb's first joint scaled) must be refused in one line."""
    from shape_inversion.rig_names import is_ancestor
    from shape_inversion.skeleton_io import prepare_character, read_character

    char = read_character(base)
    sk = char.skeleton
    P = sk.positions.copy()
    for start, factor in limbs.items():
        top = char.smpl_joints[start]
        for j in range(len(sk.names)):
            if j != top and is_ancestor(top, j, sk.parents):
                P[j] = P[top] + factor * (P[j] - P[top])
    row: dict = {"id": name, "from": base.name, "limbs": limbs}
    try:
        changed = prepare_character(dataclasses.replace(sk, positions=P), rig=char.rig)
        estimator.estimate(changed.features)
        row.update(refused=False, message="accepted as a human")
    except ValueError as exc:
        row.update(refused=True, one_line="\n" not in str(exc), message=str(exc))
    row["passed"] = bool(row.get("refused") and row.get("one_line"))
    return row


def run_real_non_humanoid(entry: dict, path: Path, estimator) -> dict:
    """A real non-humanoid rig (a quadruped) read as ``invert-shape`` reads it must be refused in one line."""
    from shape_inversion.skeleton_io import read_character

    row: dict = {"id": entry["id"], "tool": entry["tool"], "file": entry["file"]}
    try:
        estimator.estimate(read_character(path).features)
        row.update(refused=False, message="accepted as a human")
    except ValueError as exc:
        row.update(refused=True, one_line="\n" not in str(exc), message=str(exc))
    row["passed"] = bool(row.get("refused") and row.get("one_line"))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, default=rig_corpus_dir(),
                        help="folder of the local (not committed) rigs")
    parser.add_argument("--bank-samples", type=int, default=20_000)
    args = parser.parse_args()

    from shape_inversion.bank import BankConfig
    from shape_inversion.estimator import ShapeEstimator
    from smplik.body_model import load_body_model

    estimator = ShapeEstimator.build(load_body_model("neutral"), BankConfig(num_samples=args.bank_samples))
    manifest = json.loads(MANIFEST.read_text())
    previous = REPO / "benchmarks" / "results" / "rig_corpus.json"
    earlier = {r["id"]: r for r in json.loads(previous.read_text()).get("rigs", [])} if previous.is_file() else {}
    rows, skipped, carried = [], [], []
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        for entry in manifest["rigs"]:
            path = resolve(entry["file"], args.corpus)
            if not path.is_file():
                skipped.append({"id": entry["id"], "file": entry["file"], "why": f"{path} not found"})
                if entry["id"] in earlier:  # kept from the previous run, marked as not measured now
                    carried.append({**earlier[entry["id"]], "stale": True})
                continue
            try:
                row = run_humanoid(entry, path, estimator, tmp)
            except ValueError as exc:
                row = {"id": entry["id"], "tool": entry["tool"], "passed": False, "error": str(exc)}
            rows.append(row)
            ok = "PASS" if row["passed"] else "FAIL"
            if "error" in row:
                print(f"{ok} {row['id']:<28} error: {row['error']}")
                continue
            print(f"{ok} {row['id']:<28} rig {row['rig']:<9} map {'ok' if row['map_correct'] else 'WRONG'} "
                  f"units {row['units_m']:.4g} m ({row['units_source']}) up {row['up']:<2} "
                  f"stature {row['stature_m']:.2f} m -> scale {row['scale']:.3f}  residual "
                  f"{row['fit_residual_mm']:5.1f} mm  n_eff {row['effective_samples']:5.1f}  round trip bvh "
                  f"{row['bvh_max_error_mm']:.2g} mm" + (f", glb {row['glb_max_error_mm']:.2g} mm"
                                                         if "glb_max_error_mm" in row else "")
                  + f"  pose {row['pose_error_mean_pct']:.2f}% of stature (at rest "
                  f"{row['rest_pose_error_mean_pct']:.2f}%)")
        non_human = []
        for entry in manifest.get("non_humanoids", []):  # real non-humanoid rigs: refused in one line
            path = resolve(entry["file"], args.corpus)
            if not path.is_file():
                skipped.append({"id": entry["id"], "file": entry["file"], "why": f"{path} not found"})
                continue
            row = run_real_non_humanoid(entry, path, estimator)
            non_human.append(row)
            print(f"{'PASS' if row['passed'] else 'FAIL'} non-human {entry['id']:<18} "
                  f"{'refused' if row.get('refused') else 'ACCEPTED'}: {row['message'][:160]}")
        bases = [resolve(e["file"], args.corpus) for e in manifest["rigs"] if e["file"].endswith(".bvh")]
        base = next((b for b in bases if b.is_file()), None)
        if base is not None:
            for name, limbs in (("long_arms", {"left_shoulder": 2.5, "right_shoulder": 2.5}),
                                ("stub_legs", {"left_hip": 0.15, "right_hip": 0.15})):
                row = run_non_humanoid(name, base, limbs, estimator)
                non_human.append(row)
                print(f"{'PASS' if row['passed'] else 'FAIL'} non-human {name:<18} "
                      f"{'refused' if row.get('refused') else 'ACCEPTED'}: {row['message'][:160]}")
    tools = sorted({r["tool"].split(",")[0] for r in rows})
    summary = {"humanoids": len(rows), "passed": sum(r["passed"] for r in rows), "skipped": len(skipped),
               "tools": len(tools), "non_humanoids_refused": sum(r["passed"] for r in non_human),
               "non_humanoids": len(non_human),
               "bvh_pose_within_3pct": sum(r.get("pose_error_mean_pct", 99) <= 3.0 for r in rows
                                           if r.get("file", "").endswith(".bvh")),
               "bvh_characters": sum(r.get("file", "").endswith(".bvh") and "error" not in r for r in rows)}
    print(f"{summary['passed']}/{summary['humanoids']} humanoid rigs pass with no options ({summary['tools']} tools "
          f"or pipelines, {len(skipped)} skipped); {summary['non_humanoids_refused']}/{len(non_human)} non-humanoids "
          "refused in one line")
    summary["stale_rows_from_previous_run"] = len(carried)
    path = save("rig_corpus", {"summary": summary, "rigs": rows + carried, "non_humanoids": non_human,
                               "skipped": skipped,
                               "corpus": str(args.corpus), "bank_samples": args.bank_samples})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
