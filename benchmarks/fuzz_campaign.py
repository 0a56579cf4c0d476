"""Fuzz campaign: the real ``smplik`` CLI in subprocesses over mutations of valid inputs, for every reader.

Each run gets a wall-clock timeout and a 2 GB address-space cap (``resource.setrlimit(RLIMIT_AS)``); its
outcome is one of: ``accepted`` (exit 0), ``clean_error`` (non-zero exit, stderr exactly one line,
starting ``error:``), ``unclear_error`` (non-zero exit without a traceback but not that one line, e.g. a
usage panel or a message wrapped over several lines), ``traceback``, ``hang`` (timeout), ``crash``
(killed by a signal or MemoryError) and ``payload_run`` (a malicious input's marker file appeared). Peak
resident memory per run comes from ``os.wait4``. Readers: effector JSON (``smplik solve``), scene JSON
(``smplik scene solve``), SMPL model folders, npz and pkl (``smplik body info --model-dir``), ``.pt``
model files (``smplik solve --checkpoint``), estimator files (``smplik scene from-estimate``; valid ones
from :mod:`workflows.examples_gen`), skeletons: BVH, joints JSON and GLB (``smplik invert-shape``), and
output paths (``smplik body export --out``).

    PYTHONPATH=. python benchmarks/fuzz_campaign.py --seconds 300 --workers 2

writes ``benchmarks/results/fuzz_campaign.json`` (counts per reader and examples of each failure).
"""

from __future__ import annotations

import argparse
import copy
import io
import json
import os
import pickle
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "fuzz_campaign.json"
MEMORY_CAP = 2 << 30
OUTCOMES = ("accepted", "clean_error", "unclear_error", "traceback", "hang", "crash", "payload_run")

# ----------------------------------------------------------------------------- mutations

EXTREMES: list[Any] = [1e308, -1e308, 1e-308, 0, -1, 2**63, float("nan"), float("inf"), True, False, None, "",
                       "[/red]", "0.5", [], {}, [[[[[]]]]], [1e308] * 3, [0] * 1000, "x" * 10_000, -0.0, 1.5]


def _json_nodes(node: Any, parent: Any = None, key: Any = None) -> list[tuple[Any, Any]]:
    """Every (parent, key) of a JSON document (the root as (None, None)); at most 50 items per list."""
    out = [(parent, key)]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _json_nodes(v, node, k)
    elif isinstance(node, list):
        for i, v in enumerate(node[:50]):
            out += _json_nodes(v, node, i)
    return out


def mutate_json(doc: Any, rng: random.Random) -> tuple[Any, str]:
    """One to three structural/value mutations of a JSON document; returns it and a description."""
    doc = copy.deepcopy(doc)
    notes = []
    for _ in range(rng.randint(1, 3)):
        parent, key = rng.choice(_json_nodes(doc))
        if parent is None:
            op = rng.choice(["wrap", "deep", "list"])
            doc = {"wrap": lambda d: {"x": d}, "deep": lambda d: json.loads("[" * 5000 + "]" * 5000),
                   "list": lambda d: [d] * 3}[op](doc)
            notes.append(f"root:{op}")
            continue
        op = rng.choice(["extreme", "extreme", "delete", "add_key", "duplicate", "scale", "type_swap"])
        if op == "extreme":
            parent[key] = copy.deepcopy(rng.choice(EXTREMES))
        elif op == "delete":
            del parent[key]
        elif op == "add_key" and isinstance(parent, dict):
            parent[f"unknown_{rng.randint(0, 9)}"] = 1
        elif op == "duplicate" and isinstance(parent, list):
            parent.extend([copy.deepcopy(parent[key])] * rng.choice([1, 10, 1000]))
        elif op == "scale" and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
            parent[key] = parent[key] * rng.choice([1e6, -1e6, 1e-9, 1e300])
        else:
            parent[key] = str(parent[key])[:20] if not isinstance(parent[key], str) else 3
        notes.append(f"{key}:{op}")
    return doc, ",".join(notes)


def mutate_bytes(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    b = bytearray(data)
    op = rng.choice(["flip", "flip", "truncate", "insert", "zero_run", "duplicate"])
    if op == "flip":
        for _ in range(rng.randint(1, 20)):
            i = rng.randrange(len(b))
            b[i] = rng.randrange(256)
    elif op == "truncate":
        b = b[: rng.randrange(max(1, len(b)))]
    elif op == "insert":
        i = rng.randrange(len(b) + 1)
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
    elif op == "zero_run":
        i = rng.randrange(len(b))
        b[i:i + 64] = bytes(min(64, len(b) - i))
    else:
        i, j = sorted(rng.randrange(len(b)) for _ in range(2))
        b[j:j] = b[i:j][:4096]
    return bytes(b), f"bytes:{op}"


def mutate_text(text: str, rng: random.Random) -> tuple[str, str]:
    lines = text.splitlines()
    op = rng.choice(["numbers", "numbers", "delete_line", "duplicate_line", "channels", "swap", "bytes"])
    if op == "numbers":
        for _ in range(rng.randint(1, 10)):
            i = rng.randrange(len(lines))
            parts = lines[i].split()
            nums = [k for k, p in enumerate(parts) if p.replace(".", "").replace("-", "").isdigit()]
            if nums:
                parts[rng.choice(nums)] = rng.choice(["nan", "inf", "1e308", "-1e308", "1e-308", "0", "-0.033", "x"])
                lines[i] = " ".join(parts)
    elif op == "delete_line":
        del lines[rng.randrange(len(lines))]
    elif op == "duplicate_line":
        i = rng.randrange(len(lines))
        lines[i:i] = [lines[i]] * rng.choice([1, 5, 500])
    elif op == "channels":
        idx = [i for i, line in enumerate(lines) if "CHANNELS" in line or "Frame Time" in line or "Frames" in line]
        if idx:
            i = rng.choice(idx)
            parts = lines[i].split()
            parts[-1 if "Frame" in lines[i] else 1] = rng.choice(["2", "0", "-1", "100000", "1e-308", "nan"])
            lines[i] = " ".join(parts)
    elif op == "swap":
        i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    else:
        return mutate_bytes(text.encode(), rng)[0].decode("latin1"), "text:bytes"
    return "\n".join(lines) + "\n", f"text:{op}"


def mutate_npz(arrays: dict[str, np.ndarray], rng: random.Random) -> tuple[dict[str, np.ndarray], str]:
    arrays = {k: np.array(v) for k, v in arrays.items()}
    key = rng.choice(sorted(arrays))
    a = arrays[key]
    op = rng.choice(["nan", "shape", "zero", "huge", "drop", "dtype", "transpose"])
    if op == "nan" and a.dtype.kind == "f" and a.size:
        a.flat[rng.randrange(a.size)] = rng.choice([np.nan, np.inf])
    elif op == "shape" and a.ndim:
        arrays[key] = a[: max(0, a.shape[0] - rng.randint(1, 3))]
    elif op == "zero":
        arrays[key] = np.zeros_like(a)
    elif op == "huge" and a.dtype.kind in "fi" and a.size:
        arrays[key] = a * (1e30 if a.dtype.kind == "f" else 1000)
    elif op == "drop":
        del arrays[key]
    elif op == "dtype":
        arrays[key] = a.astype(rng.choice(["<U3", "bool", "int8", "complex64"]))
    elif a.ndim >= 2:
        arrays[key] = a.T
    return arrays, f"npz:{key}:{op}"


# ----------------------------------------------------------------------------- valid inputs and payloads


class _Payload:
    """Pickles to ``os.system(cmd)``: runs the command if a reader unpickles it unrestricted."""

    def __init__(self, cmd: str) -> None:
        self.cmd = cmd

    def __reduce__(self):
        return os.system, (self.cmd,)


def make_valid_inputs(work: Path) -> dict[str, Any]:
    """Valid material for every reader (generated, nothing downloaded)."""
    import torch

    from smplik.atomic import write_npz_deterministic
    from smplik.body_model import load_body_model
    from smplik.solver import IKSolver, packaged_model_path
    from workflows.examples_gen import example_poses, write_mixamo_character, write_romp_example
    from workflows.scene import Scene, SceneCharacter, save_scene

    work.mkdir(parents=True, exist_ok=True)
    effectors = {"format": "smplik-effectors", "version": 1, "betas": [0.5] + [0.0] * 9, "gender": "female",
                 "effectors": [{"joint": "left_wrist", "type": "position", "value": [0.4, 1.1, 0.2], "tolerance": 0},
                               {"joint": "pelvis", "type": "rotation", "value": np.eye(3).tolist()},
                               {"joint": "head", "type": "look_at", "target": [0.0, 1.6, 2.0],
                                "direction": [0, 0, 1], "tolerance": 0.2}]}
    solver = IKSolver.load()
    from smplik.effectors import Effector

    chars = []
    for i, person in enumerate(example_poses()):
        p = person.pose
        eff = (Effector.position("left_wrist", p.joints[20] if p.joints is not None else [0.3, 1.0, 0.1]),
               Effector.position("pelvis", [0.0, 0.9, 0.0]))
        pose = solver.solve(list(eff), betas=p.betas, gender=p.gender)
        chars.append(SceneCharacter(f"person_{i}", p.gender, p.betas, 1.0, None, eff, pose))
    scene = json.loads(save_scene(Scene(tuple(chars)), work / "scene.json").read_text())
    model = load_body_model("neutral")
    smpl_arrays = {k: np.asarray(v) for k, v in model.export_arrays().items() if k != "gender"}
    romp = write_romp_example(work / "romp.npz")
    bvh = write_mixamo_character(work / "mixamo.bvh")
    J = model.rest_joints(torch.zeros(10)).double().numpy()
    from smplik.conventions import JOINT_NAMES, PARENTS

    joints_json = {"units": "m", "up": "y", "joints": {n: J[k].tolist() for k, n in enumerate(JOINT_NAMES)}}
    glb = _write_glb(work / "char.glb", list(JOINT_NAMES), list(PARENTS), J)
    smpl_npz = write_npz_deterministic(work / "smpl_valid" / "SMPL_NEUTRAL.npz", smpl_arrays)
    return {"smpl_npz": smpl_npz, "effectors": effectors, "scene": scene, "smpl_arrays": smpl_arrays,
            "pt": packaged_model_path(), "romp": romp, "bvh": bvh.read_text(), "joints_json": joints_json,
            "glb": glb.read_bytes()}


def _write_glb(path: Path, names: list[str], parents: list[int], positions: np.ndarray) -> Path:
    """A minimal skinned GLB (joint nodes with parent-relative translations, inverse bind matrices)."""
    import pygltflib

    n = len(names)
    ibm = np.stack([np.eye(4) for _ in range(n)]).astype(np.float32)
    ibm[:, 3, :3] = -positions  # column-major storage of a translation by -p
    blob = ibm.tobytes()
    nodes = [pygltflib.Node(name=names[k], translation=(positions[k] - (positions[parents[k]] if parents[k] >= 0
                                                                         else 0)).tolist(),
                            children=[c for c in range(n) if parents[c] == k] or None) for k in range(n)]
    gltf = pygltflib.GLTF2(scenes=[pygltflib.Scene(nodes=[0])], scene=0, nodes=nodes,
                           skins=[pygltflib.Skin(joints=list(range(n)), inverseBindMatrices=0)],
                           accessors=[pygltflib.Accessor(bufferView=0, componentType=pygltflib.FLOAT, count=n,
                                                         type="MAT4")],
                           bufferViews=[pygltflib.BufferView(buffer=0, byteOffset=0, byteLength=len(blob))],
                           buffers=[pygltflib.Buffer(byteLength=len(blob))])
    gltf.set_binary_blob(blob)
    gltf.save_binary(str(path))
    return path


def _zip_bomb(path: Path, rows: int = 100_000_000) -> Path:
    """An SMPL npz whose ``v_template`` member inflates to ``rows * 24`` bytes (2.4 GB) from a few MB (made once)."""
    import zipfile

    if path.is_file():
        return path
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (rows, 3)})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf, zf.open("v_template.npy", "w", force_zip64=True) as fh:
        fh.write(header.getvalue())
        chunk = bytes(1 << 24)
        for _ in range(rows * 24 // len(chunk)):
            fh.write(chunk)
    return path


# ----------------------------------------------------------------------------- running one case


@dataclass
class Case:
    reader: str
    args: list[str]
    note: str
    marker: Path | None = None


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))
    os.setsid()


def run_case(case: Case, timeout: float, env: dict[str, str]) -> dict[str, Any]:
    """Run the CLI on one case; classify the outcome (module docstring)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", *case.args], stdout=out, stderr=err,
                                env=env, cwd=ROOT, preexec_fn=_limit)
        deadline = time.monotonic() + timeout
        status, rusage, hung = 0, None, False
        while True:
            pid, status, rusage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                hung = True
                os.killpg(proc.pid, signal.SIGKILL)
                _, status, rusage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        stderr = err.read().decode("utf-8", "replace")
    rc = proc.returncode
    peak_mb = rusage.ru_maxrss / 1024 if rusage else 0.0
    if case.marker is not None and case.marker.exists():
        outcome = "payload_run"
    elif hung:
        outcome = "hang"
    elif "Traceback (most recent call last)" in stderr:
        outcome = "crash" if "MemoryError" in stderr.splitlines()[-1:][0] else "traceback"
    elif rc < 0:
        outcome = "crash"
    elif rc == 0:
        outcome = "accepted"
    else:
        lines = [line for line in stderr.splitlines() if line.strip()]
        outcome = "clean_error" if len(lines) == 1 and lines[0].startswith("error:") else "unclear_error"
    lines = [line for line in stderr.splitlines() if line.strip()]
    return {"reader": case.reader, "outcome": outcome, "rc": rc, "peak_mb": round(peak_mb, 1), "note": case.note,
            "last_line": lines[-1][:300] if lines else ""}


# ----------------------------------------------------------------------------- case generators per reader


def case_makers(valid: dict[str, Any], work: Path) -> dict[str, Callable[[random.Random, int], Case]]:
    import torch

    from smplik.atomic import write_npz_deterministic

    effectors_file = work / "valid_effectors.json"
    effectors_file.write_text(json.dumps(valid["effectors"]))

    def new_dir(n: int) -> Path:
        d = work / f"case{n:05d}"
        d.mkdir()
        return d

    def effector_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        doc, note = mutate_json(valid["effectors"], rng)
        (d / "eff.json").write_text(json.dumps(doc))
        return Case("effector_json", ["solve", str(d / "eff.json"), "--out", str(d / "pose.json")], note)

    def scene_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        doc, note = mutate_json(valid["scene"], rng)
        (d / "scene.json").write_text(json.dumps(doc))
        return Case("scene_json", ["scene", "solve", str(d / "scene.json"), "--out", str(d / "out.json")], note)

    def smpl_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        kind = rng.choice(["npz", "npz", "npz_bytes", "pkl", "pkl_payload", "npz_bomb"])
        marker = d / "PAYLOAD_RAN"
        if kind == "npz":
            arrays, note = mutate_npz(valid["smpl_arrays"], rng)
            write_npz_deterministic(d / "SMPL_NEUTRAL.npz", arrays)
        elif kind == "npz_bytes":
            data, note = mutate_bytes(Path(valid["smpl_npz"]).read_bytes(), rng)
            (d / "SMPL_NEUTRAL.npz").write_bytes(data)
        elif kind == "npz_bomb":
            shutil.copy(_zip_bomb(work / "bomb.npz"), d / "SMPL_NEUTRAL.npz")
            note = "npz:zip_bomb_2.4GB"
        elif kind == "pkl":
            arrays, note = mutate_npz(valid["smpl_arrays"], rng)
            (d / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps(arrays, protocol=rng.choice([0, 2, 4])))
        else:
            (d / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps({"v_template": _Payload(f"touch {marker}")}))
            note = "pkl:payload"
        return Case("smpl_model_folder", ["body", "info", "--model-dir", str(d)], note, marker)

    pt_bytes = Path(valid["pt"]).read_bytes()

    def pt_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        marker = d / "PAYLOAD_RAN"
        if rng.random() < 0.25:
            torch.save({"model": _Payload(f"touch {marker}")}, d / "model.pt")
            note = "pt:payload"
        else:
            data, note = mutate_bytes(pt_bytes, rng)
            (d / "model.pt").write_bytes(data)
        return Case("pt_model_file", ["solve", str(effectors_file), "--checkpoint", str(d / "model.pt"), "--out",
                                      str(d / "pose.json")], note, marker)

    def estimator_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        marker = d / "PAYLOAD_RAN"
        kind = rng.choice(["romp_arrays", "romp_bytes", "payload_npz", "payload_pk"])
        from smplik.safe_pickle import read_npz

        if kind == "romp_arrays":
            results = read_npz(valid["romp"])["results"]
            results, note = mutate_npz(results, rng)
            np.savez(d / "results.npz", results=results)
            path = d / "results.npz"
        elif kind == "romp_bytes":
            data, note = mutate_bytes(Path(valid["romp"]).read_bytes(), rng)
            path = d / "results.npz"
            path.write_bytes(data)
        elif kind == "payload_npz":
            obj = np.empty((), dtype=object)
            obj[()] = _Payload(f"touch {marker}")
            np.savez(d / "results.npz", results=obj)
            path, note = d / "results.npz", "npz:payload"
        else:
            path = d / "results.pk"
            path.write_bytes(pickle.dumps({"pred_thetas": _Payload(f"touch {marker}")}))
            note = "pk:payload"
        return Case("estimator_file", ["scene", "from-estimate", str(path), "--out", str(d / "out"), "--no-previews"],
                    note, marker)

    def skeleton_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        kind = rng.choice(["bvh", "joints_json", "glb"])
        if kind == "bvh":
            text, note = mutate_text(valid["bvh"], rng)
            path = d / "char.bvh"
            path.write_text(text, encoding="latin1")
        elif kind == "joints_json":
            doc, note = mutate_json(valid["joints_json"], rng)
            path = d / "char.json"
            path.write_text(json.dumps(doc))
        else:
            data, note = mutate_bytes(valid["glb"], rng)
            path = d / "char.glb"
            path.write_bytes(data)
        return Case(f"skeleton_{kind}", ["invert-shape", str(path), "--out", str(d / "shape.json"),
                                         "--bank-samples", "2000"], note)

    def output_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        (d / "a_file").write_text("x")
        (d / "a_folder.npz").mkdir()
        ro = d / "read_only"
        ro.mkdir()
        ro.chmod(0o500)
        choices = {"folder": d / "a_folder.npz", "under_a_file": d / "a_file" / "x.npz",
                   "markup": d / "[red]x[/red].npz", "long_name": d / ("x" * 300 + ".npz"),
                   "deep_new": d / "a" / "b" / "c" / "x.npz", "read_only": ro / "x.npz", "fifo": d / "fifo.npz",
                   "proc": Path("/proc/smplik_x.npz"), "root_folder": Path("/"), "empty_suffix": d / "x.",
                   "newline": d / "x\ny.npz", "wrong_suffix": d / "x.txt"}
        os.mkfifo(d / "fifo.npz")
        kind = rng.choice(sorted(choices))
        return Case("output_path", ["body", "export", "--out", str(choices[kind])], f"out:{kind}")

    return {"effector_json": effector_case, "scene_json": scene_case, "smpl_model_folder": smpl_case,
            "pt_model_file": pt_case, "estimator_file": estimator_case, "skeleton": skeleton_case,
            "output_path": output_case}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=300.0, help="Campaign wall-clock budget (default 300).")
    parser.add_argument("--timeout", type=float, default=60.0, help="Per-run timeout in seconds (hang).")
    parser.add_argument("--workers", type=int, default=2, help="Parallel CLI runs.")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--readers", default="", help="Comma-separated subset of readers (default: all).")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="smplik-fuzz-"))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYOPENGL_PLATFORM": "egl", "OMP_NUM_THREADS": "1",
           "PYTHONWARNINGS": "ignore", "COLUMNS": "80",
           "SMPLIK_CACHE_DIR": os.environ.get("SMPLIK_CACHE_DIR", str(work / "cache"))}
    env.pop("SMPLIK_MODEL_DIR", None)
    os.environ["SMPLIK_CACHE_DIR"] = env["SMPLIK_CACHE_DIR"]
    try:
        valid = make_valid_inputs(work / "valid")
        makers = case_makers(valid, work)
        if args.readers:
            makers = {k: v for k, v in makers.items() if k in args.readers.split(",")}
        rng = random.Random(args.seed)
        start = time.monotonic()
        lock = threading.Lock()
        counter = iter(range(10**9))
        order = sorted(makers)
        results: list[dict[str, Any]] = []

        def worker(slot: int) -> None:
            while time.monotonic() - start < args.seconds:
                with lock:
                    n = next(counter)
                    reader = order[n % len(order)]
                    seed = rng.random()
                try:
                    case = makers[reader](random.Random(seed), n)
                except Exception as exc:  # noqa: BLE001 - a mutation the generator itself cannot write
                    print(f"skipped a {reader} case: {type(exc).__name__}: {exc}", flush=True)
                    continue
                res = run_case(case, args.timeout, env)
                with lock:
                    results.append(res)
                    print(f"[{time.monotonic() - start:6.0f}s] {res['reader']:<22} {res['outcome']:<13} "
                          f"{res['note'][:40]:<40} {res['last_line'][:90]}", flush=True)

        with ThreadPoolExecutor(args.workers) as pool:
            list(pool.map(worker, range(args.workers)))
    finally:
        for ro in work.glob("case*/read_only"):
            ro.chmod(0o700)
        shutil.rmtree(work, ignore_errors=True)

    summary: dict[str, Any] = {}
    for res in results:
        reader = res["reader"]
        s = summary.setdefault(reader, {"runs": 0, **{o: 0 for o in OUTCOMES}, "peak_mb": 0.0, "examples": {}})
        s["runs"] += 1
        s[res["outcome"]] += 1
        s["peak_mb"] = max(s["peak_mb"], res["peak_mb"])
        if res["outcome"] not in ("accepted", "clean_error"):
            ex = s["examples"].setdefault(res["outcome"], [])
            if len(ex) < 5:
                ex.append({"note": res["note"], "last_line": res["last_line"]})
    totals = {o: sum(s[o] for s in summary.values()) for o in ("runs", *OUTCOMES)}
    report = {"seconds": args.seconds, "timeout_s": args.timeout, "memory_cap_bytes": MEMORY_CAP, "seed": args.seed,
              "totals": totals, "peak_mb": max((s["peak_mb"] for s in summary.values()), default=0.0),
              "readers": summary}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(totals))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
