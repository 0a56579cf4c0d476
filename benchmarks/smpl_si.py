"""SMPL-SI benchmark -> benchmarks/results/shape_inversion.json.

1. Held-out synthetic bodies of the built-in model (1,000 random (beta, scale) drawn like the bank
   but with another seed): six-feature error of the recovered shape (mm, median / p95 of the
   per-body max over the features) and beta / scale error, for the paper's kernel estimate, the
   refined estimate, and a least-squares baseline (scipy least_squares over (beta, s) from beta=0,
   s=1, inside the same box).
2. Real skeletons from ../shared/data (or $SMPLIK_SHARED_DIR/data): the MakeHuman default skeleton
   and one file per CMU subject (frame 0): head-ankle "stature" and per-bone length errors of the
   SMPL approximation (mm).
3. Real-layout character files written by :mod:`workflows.layout_examples` from one skeleton (the
   built-in body at beta = 0 with 6 % longer legs): Mixamo BVH (per-joint position channels), Rokoko
   BVH, CMU-unit BVH, Blender-style GLB (armature scale 0.01, rotated root node), .gltf + .bin, and
   the same skeleton as plain-metres JSON: units detected, stature in (skeleton as read) and out (the
   SMPL estimate), max feature residual.
4. Joint fit (second stage) on known truth: the held-out bodies' own 24 rest joints (300 of them): rest-joint
   error of the body found (mm, after a rigid alignment), first stage against joint fit; on the real
   skeletons of 2., the bone-length errors with the joint fit (``kernel_joint_fit``).
5. Timings: bank build, estimator build from the cached bank, query per character.

Run: ``python benchmarks/smpl_si.py [--gender neutral] [--samples 1000]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository's packages

import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402
import torch  # noqa: E402

from shape_inversion.bank import BankConfig, sample_bank  # noqa: E402
from shape_inversion.estimator import EstimatorConfig, ShapeEstimator, ShapeInversionError, features_and_jacobian  # noqa: E402
from shape_inversion.skeleton_io import prepare_character, read_bvh  # noqa: E402
from smplik.atomic import write_json_atomic  # noqa: E402
from smplik.body_model import load_body_model  # noqa: E402
from smplik.conventions import JOINT_INDEX, NUM_BETAS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BONES = (("right_hip", "right_knee"), ("right_knee", "right_ankle"), ("left_hip", "left_knee"),
         ("left_knee", "left_ankle"), ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"),
         ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"), ("left_hip", "right_hip"),
         ("left_shoulder", "right_shoulder"), ("head", "right_ankle"), ("head", "right_wrist"))


def least_squares_baseline(estimator: ShapeEstimator, query: np.ndarray) -> np.ndarray:
    """(beta, s) (11,) fitting the six features by bounded least squares from beta = 0, s = 1."""
    T, D = estimator.pair_template, estimator.pair_dirs
    lo = np.append(np.full(NUM_BETAS, -5.0), 0.2)
    hi = np.append(np.full(NUM_BETAS, 5.0), 2.0)
    sol = scipy.optimize.least_squares(
        lambda x: features_and_jacobian(T, D, x[:NUM_BETAS], x[NUM_BETAS])[0] - query,
        np.append(np.zeros(NUM_BETAS), 1.0),
        jac=lambda x: features_and_jacobian(T, D, x[:NUM_BETAS], x[NUM_BETAS])[1], bounds=(lo, hi), method="trf")
    return sol.x


def _stats(values: np.ndarray) -> dict:
    return {"median": float(np.median(values)), "p95": float(np.percentile(values, 95)),
            "mean": float(np.mean(values)), "max": float(np.max(values))}


def synthetic(model, estimators: dict[str, ShapeEstimator], n: int, seed: int) -> dict:
    held = sample_bank(model, BankConfig(num_samples=n, seed=seed))
    base = estimators["kernel"]
    rows: dict[str, dict[str, list]] = {k: {"feat": [], "beta": [], "scale": [], "t": []}
                                        for k in (*estimators, "least_squares")}
    for f, b, s in zip(held.features, held.betas, held.scales, strict=True):
        for name, est in estimators.items():
            t0 = time.perf_counter()
            e = est.estimate(f)
            rows[name]["t"].append(time.perf_counter() - t0)
            rows[name]["feat"].append(e.max_feature_residual_m)
            rows[name]["beta"].append(np.abs(e.betas - b).mean())
            rows[name]["scale"].append(abs(e.scale - s))
        t0 = time.perf_counter()
        x = least_squares_baseline(base, f)
        rows["least_squares"]["t"].append(time.perf_counter() - t0)
        rows["least_squares"]["feat"].append(np.abs(base.features_of(x[:NUM_BETAS], x[NUM_BETAS]) - f).max())
        rows["least_squares"]["beta"].append(np.abs(x[:NUM_BETAS] - b).mean())
        rows["least_squares"]["scale"].append(abs(x[NUM_BETAS] - s))
    return {name: {"max_feature_error_mm": _stats(np.array(r["feat"]) * 1000),
                   "beta_mean_abs_error": _stats(np.array(r["beta"])),
                   "scale_abs_error": _stats(np.array(r["scale"])),
                   "time_ms": _stats(np.array(r["t"]) * 1000)} for name, r in rows.items()}


def joint_fit_held_out(model, estimator: ShapeEstimator, n: int, seed: int) -> dict:
    """Known truth for the joint fit: the held-out bodies' own rest joints (all 24, moved off the origin) given to
    the estimator with their features. Rest-joint error of the body found (mean over the 24 joints after a rigid
    alignment, mm), beta / scale error and time, first stage (kernel mean) against the joint fit."""
    from shape_inversion.joint_fit import MappedRest
    from smplik.conventions import JOINT_NAMES, PARENTS

    held = sample_bank(model, BankConfig(num_samples=n, seed=seed))
    every = {name: j for j, name in enumerate(JOINT_NAMES)}
    rows: dict[str, dict[str, list]] = {k: {"joint": [], "beta": [], "scale": []} for k in ("kernel", "joint_fit")}
    times, kept = [], 0
    for f, b, s in zip(held.features, held.betas, held.scales, strict=True):
        J = s * model.rest_joints(torch.tensor(b)).double().numpy()
        rest = MappedRest.from_skeleton(J + np.array([0.3, -0.2, 0.5]), PARENTS, every)
        t0 = time.perf_counter()
        e = estimator.estimate(f, rest)
        times.append(time.perf_counter() - t0)
        kept += e.joint_fit
        found = {"kernel": (e.kernel_betas, e.kernel_scale), "joint_fit": (e.betas, e.scale)}
        for name, (betas, scale) in found.items():
            x = np.append(betas, scale)
            rows[name]["joint"].append(estimator.rest_joint_residual(x, rest))
            rows[name]["beta"].append(np.abs(betas - b).mean())
            rows[name]["scale"].append(abs(scale - s))
    out = {name: {"rest_joint_error_mm": _stats(np.array(r["joint"]) * 1000),
                  "beta_mean_abs_error": _stats(np.array(r["beta"])),
                  "scale_abs_error": _stats(np.array(r["scale"]))} for name, r in rows.items()}
    return {"num_bodies": n, **out, "joint_fit_kept": kept, "time_ms": _stats(np.array(times) * 1000)}


def edge_refusals(estimator: ShapeEstimator, n: int, seed: int, model) -> int:
    """How many held-out bodies the default edge-of-bank check refuses (scale within 5 % of 0.2 or 2)."""
    held = sample_bank(model, BankConfig(num_samples=n, seed=seed))
    refused = 0
    for f in held.features:
        try:
            estimator.estimate(f)
        except ShapeInversionError:
            refused += 1
    return refused


def real_characters(model, estimators: dict[str, ShapeEstimator], shared: Path) -> dict:
    files: list[tuple[str, Path]] = []
    mh = shared / "data" / "custom-characters" / "mh_default_tpose.bvh"
    if mh.is_file():
        files.append(("makehuman_default", mh))
    seen = set()
    for path in sorted((shared / "data" / "cmu").glob("*.bvh")):
        subject = path.name.split("_")[0]
        if subject not in seen:
            seen.add(subject)
            files.append((f"cmu_{subject} ({path.name})", path))
    out = {}
    for label, path in files:
        char = prepare_character(read_bvh(path))
        entry: dict = {"rig": char.rig.name, "units_m": char.units_m, "up": char.up,
                       "head_ankle_height_m": char.head_ankle_height_m}
        for name, est in estimators.items():
            try:
                t0 = time.perf_counter()
                e = est.estimate(char.features, char.mapped_rest() if name == "kernel_joint_fit" else None)
                dt = time.perf_counter() - t0
            except ShapeInversionError as exc:
                entry[name] = {"error": str(exc)}
                continue
            J = model.rest_joints(torch.tensor(e.betas)).double().numpy() * e.scale
            ankles = [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]]
            smpl_height = J[JOINT_INDEX["head"], 1] - J[ankles, 1].mean()
            bones = {}
            for a, b in BONES:
                if a in char.smpl_joints and b in char.smpl_joints:
                    ref = np.linalg.norm(char.joint(a) - char.joint(b))
                    got = np.linalg.norm(J[JOINT_INDEX[a]] - J[JOINT_INDEX[b]])
                    bones[f"{a}-{b}"] = round(float((got - ref) * 1000), 2)
            entry[name] = {"scale": e.scale, "betas": [round(float(x), 3) for x in e.betas],
                           "stature_head_ankle_error_mm": float((smpl_height - char.head_ankle_height_m) * 1000),
                           "bone_length_error_mm": bones,
                           "bone_mean_abs_error_mm": float(np.mean(np.abs(list(bones.values())))),
                           "max_feature_residual_mm": e.max_feature_residual_m * 1000,
                           "effective_samples": e.effective_samples, "query_ms": dt * 1000}
        out[label] = entry
    return out


def real_layouts(model, estimator: ShapeEstimator, folder: Path) -> dict:
    """One row per real-layout file: units, stature in / out (m), max feature residual (mm), beta/scale."""
    from shape_inversion.skeleton_io import HEAD_ANKLE_PER_STATURE, read_character
    from workflows import layout_examples as lx

    J = lx.smpl_rest()[0].copy()
    for side in ("left", "right"):
        for joint, parent in ((f"{side}_knee", f"{side}_hip"), (f"{side}_ankle", f"{side}_knee")):
            J[JOINT_INDEX[joint]] = J[JOINT_INDEX[parent]] + 1.06 * (J[JOINT_INDEX[joint]] - J[JOINT_INDEX[parent]])
    (folder / "gltf").mkdir(parents=True, exist_ok=True)
    files = {"plain_metres_json": lx.write_plain_json(folder / "plain.json", J),
             "mixamo_bvh": lx.write_mixamo_bvh(folder / "mixamo.bvh", J),
             "rokoko_bvh": lx.write_rokoko_bvh(folder / "rokoko.bvh", J),
             "cmu_units_bvh": lx.write_cmu_bvh(folder / "cmu.bvh", J),
             "blender_glb_scale_0.01": lx.write_mixamo_gltf(folder / "mixamo.glb", J),
             "gltf_external_bin": lx.write_mixamo_gltf(folder / "gltf" / "mixamo.gltf", J, external_bin=True)}
    rows = {}
    for label, path in files.items():
        char = read_character(path)
        e = estimator.estimate(char.features)
        Js = model.rest_joints(torch.tensor(e.betas)).double().numpy() * e.scale
        out_h = Js[JOINT_INDEX["head"], 1] - Js[[JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]], 1].mean()
        rows[label] = {"rig": char.rig.name, "units_m": char.units_m, "units_source": char.units_source,
                       "stature_in_m": char.head_ankle_height_m / HEAD_ANKLE_PER_STATURE,
                       "stature_out_m": float(out_h) / HEAD_ANKLE_PER_STATURE,
                       "max_feature_residual_mm": e.max_feature_residual_m * 1000, "scale": e.scale,
                       "betas": [round(float(b), 4) for b in e.betas]}
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gender", default="neutral")
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=20240611, help="held-out seed (the bank uses 0)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "shape_inversion.json")
    args = parser.parse_args()
    warnings.filterwarnings("ignore", message="beta\\[")  # edge-of-bank betas are counted, not printed
    shared = Path(os.environ.get("SMPLIK_SHARED_DIR", ROOT.parent / "shared"))
    model = load_body_model(args.gender)

    t0 = time.perf_counter()
    sample_bank(model, BankConfig())
    bank_build_s = time.perf_counter() - t0
    ShapeEstimator.build(model)  # make sure the bank is cached
    t0 = time.perf_counter()
    kernel = ShapeEstimator.build(model)
    estimator_from_cache_s = time.perf_counter() - t0
    # the held-out bodies are drawn over the bank's whole range: measure the estimate there with the
    # edge-of-bank check off (edge_fraction=0), and count separately what the default check refuses
    no_edge = EstimatorConfig(edge_fraction=0.0)
    estimators = {"kernel": ShapeEstimator.build(model, config=no_edge),
                  "kernel_refined": ShapeEstimator.build(model, config=EstimatorConfig(refine=True, edge_fraction=0.0))}
    with_joint_fit = {**estimators, "kernel_joint_fit": estimators["kernel"]}  # real skeletons: + their rest joints
    result = {
        "gender": args.gender, "body_model": {"source": model.source, "fingerprint": model.fingerprint},
        "bank": {"num_samples": BankConfig().num_samples, "seed": BankConfig().seed, "bandwidth_m": 0.02,
                 "build_s": bank_build_s, "estimator_build_from_cache_s": estimator_from_cache_s},
        "held_out": {"num_bodies": args.samples, "seed": args.seed,
                     "refused_at_bank_edge_by_default": edge_refusals(kernel, args.samples, args.seed, model),
                     **synthetic(model, estimators, args.samples, args.seed)},
        "joint_fit_held_out": joint_fit_held_out(model, estimators["kernel"], min(args.samples, 300), args.seed),
        "characters": real_characters(model, with_joint_fit, shared) if (shared / "data").is_dir()
        else f"skipped: {shared / 'data'} not found",
    }
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        result["real_layouts"] = real_layouts(model, kernel, Path(tmp))
    write_json_atomic(args.out, result)
    ho = result["held_out"]
    for name in ("kernel", "kernel_refined", "least_squares"):
        r = ho[name]
        print(f"{name:15s} feature err mm median {r['max_feature_error_mm']['median']:.2f} "
              f"p95 {r['max_feature_error_mm']['p95']:.2f} | beta MAE {r['beta_mean_abs_error']['mean']:.3f} "
              f"| scale err {r['scale_abs_error']['mean']:.4f} | {r['time_ms']['median']:.2f} ms")
    jf = result["joint_fit_held_out"]
    err0, err1 = jf["kernel"]["rest_joint_error_mm"], jf["joint_fit"]["rest_joint_error_mm"]
    print(f"joint fit ({jf['num_bodies']} bodies, own rest joints): rest joint error mm median "
          f"{err0['median']:.2f} -> {err1['median']:.2f}, p95 {err0['p95']:.2f} -> {err1['p95']:.2f}"
          f" | beta MAE {jf['kernel']['beta_mean_abs_error']['mean']:.3f} -> "
          f"{jf['joint_fit']['beta_mean_abs_error']['mean']:.3f} | kept {jf['joint_fit_kept']} | "
          f"{jf['time_ms']['median']:.1f} ms")
    print(f"bank build {bank_build_s * 1000:.1f} ms, estimator from cache {estimator_from_cache_s * 1000:.1f} ms")
    if isinstance(result["characters"], dict):
        for label, entry in result["characters"].items():
            k = entry["kernel"]
            if "error" in k:
                print(f"{label:28s} ERROR {k['error'][:100]}")
                continue
            j = entry.get("kernel_joint_fit", {}).get("bone_mean_abs_error_mm", float("nan"))
            print(f"{label:28s} stature err {k['stature_head_ankle_error_mm']:7.1f} mm | bone MAE "
                  f"{k['bone_mean_abs_error_mm']:5.1f} mm (joint fit {j:5.1f})"
                  f" | scale {k['scale']:.3f} | {k['query_ms']:.2f} ms")
    for label, r in result["real_layouts"].items():
        print(f"{label:24s} units {r['units_m']:.4f} ({r['units_source']}) stature in {r['stature_in_m']:.3f} m "
              f"out {r['stature_out_m']:.3f} m | residual {r['max_feature_residual_mm']:.1f} mm | "
              f"scale {r['scale']:.3f}")
    print(f"-> {args.out}")


if __name__ == "__main__":
    main()
