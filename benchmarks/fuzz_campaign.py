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

First, once each, the crafted cases of issue #28 (:func:`crafted_cases`): SMPL model files whose sparse
``J_regressor`` holds out-of-range or negative indices (csr, csc, coo), pickle DAGs of shared references
(2**28 objects once expanded), stride-0 ``.pt`` tensors (GVHMR, plain, model file), model configs asking
for 10**9 refinement steps or a 10**9-wide network, npz bombs through ``data build --amass``, benchmark
files and estimator files, mutated benchmark manifests, BVH files declaring 10**7 frames, a 13000 x 13000
``--image``, 300 MB JSON files and ``/dev/zero``, corrupt zips; and the editor (:func:`editor_cases`):
``smplik edit`` with raw WebSocket clients from foreign and null origins and with missing or wrong tokens
(a client that gets in counts as ``payload_run``). Outputs that a run may replace hold a sentinel first:
a failed run must leave it, a successful one must write a complete file (else ``corrupted_output``).
Then the round-3 cases of issue 36 (``benchmarks/fuzz_round3.py``: config values, pose-cache values, WHAM
``frame_ids``, glTF numbers and bufferViews, outputs that are inputs or empty, strict options); an input a
case names in ``keep`` must come out byte-identical (else ``input_overwritten``). ``--round3-only`` runs
just those (``benchmarks/results/fuzz_round3.json``). Then the round-4 budget cases of issue 45
(``benchmarks/fuzz_round4_budgets.py``: rates and resampled frames, tracker and SteamVR JSON types, tracking and IK
model files through the one reader, keyframe effectors, previews); each must be a clean error holding its key or
limit variable (``round4_budgets`` in the report); ``--round4-budgets-only`` runs just those
(``benchmarks/results/fuzz_round4_budgets.json``). Then the round-4 output and reader cases of issue 45
(``benchmarks/fuzz_round4_outputs.py``: outputs inside ``--out`` that are inputs, glTF/VRM limits, budgets).

    PYTHONPATH=. python benchmarks/fuzz_campaign.py --seconds 240 --workers 2

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
OUTCOMES = ("accepted", "clean_error", "unclear_error", "traceback", "hang", "crash", "payload_run",
            "corrupted_output", "input_overwritten")
SENTINEL = b"smplik-fuzz: the previous output, which a failed run must leave in place\n"

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
    output: Path | None = None
    """An output file the run may replace: it holds a sentinel before the run; after a failed run it must
    still hold it, after a successful one it must be a complete file (else ``corrupted_output``)."""
    keep: Path | None = None
    """An input file the run must leave byte-identical (else ``input_overwritten``)."""
    cwd: Path | None = None
    """The run's working folder (default: the repository root)."""


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))
    os.setsid()


def run_case(case: Case, timeout: float, env: dict[str, str]) -> dict[str, Any]:
    """Run the CLI on one case; classify the outcome (module docstring)."""
    if case.output is not None:
        case.output.parent.mkdir(parents=True, exist_ok=True)
        case.output.write_bytes(SENTINEL)
    kept = case.keep.read_bytes() if case.keep is not None else None
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", *case.args], stdout=out, stderr=err,
                                env=env, cwd=case.cwd or ROOT, preexec_fn=_limit)
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
    elif case.keep is not None and (not case.keep.is_file() or case.keep.read_bytes() != kept):
        outcome = "input_overwritten"
    elif case.output is not None and not hung and not _output_intact(case.output, rc == 0):
        outcome = "corrupted_output"
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


def _output_intact(path: Path, succeeded: bool) -> bool:
    """A failed run left the sentinel in place; a successful one wrote a complete file of its kind."""
    try:
        data = path.read_bytes()
    except OSError:
        return False
    if not succeeded:
        return data == SENTINEL
    try:
        if path.suffix == ".json":
            json.loads(data)
        elif path.suffix == ".npz":
            with np.load(io.BytesIO(data)) as npz:
                [npz[k] for k in npz.files]
        return data != SENTINEL
    except (ValueError, OSError, EOFError):
        return False


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
        return Case("effector_json", ["solve", str(d / "eff.json"), "--out", str(d / "pose.json")], note,
                    output=d / "pose.json")

    def scene_case(rng: random.Random, n: int) -> Case:
        d = new_dir(n)
        doc, note = mutate_json(valid["scene"], rng)
        (d / "scene.json").write_text(json.dumps(doc))
        return Case("scene_json", ["scene", "solve", str(d / "scene.json"), "--out", str(d / "out.json")], note,
                    output=d / "out.json")

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
                                      str(d / "pose.json")], note, marker, output=d / "pose.json")

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


# ----------------------------------------------------------------------------- crafted cases (each run once)


def _dag(depth: int = 28) -> list:
    """Lists sharing references: a few hundred bytes pickled, 2**depth objects once expanded."""
    node: list = []
    for _ in range(depth):
        node = [node, node]
    return node


def _sparse_model(arrays: dict[str, np.ndarray], layout: str, index: int, where: str) -> dict[str, Any]:
    """SMPL arrays whose J_regressor is a ``layout`` sparse matrix with ``index`` written into ``where``."""
    import scipy.sparse

    m = {"csr": scipy.sparse.csr_matrix, "csc": scipy.sparse.csc_matrix, "coo": scipy.sparse.coo_matrix}[layout](
        arrays["J_regressor"])
    state = dict(vars(m))
    if layout == "coo":
        coords = state.pop("coords", None) or (m.row, m.col)
        state["row"], state["col"] = coords[0].astype(np.int64), coords[1].astype(np.int64)
    arr = state[where].astype(np.int64)
    arr[min(3, len(arr) - 1)] = index
    state[where] = arr
    bad = object.__new__(type(m))
    bad.__dict__.update(state)
    return {**arrays, "J_regressor": bad}


def _benchmark_files(work: Path) -> Path:
    """A small valid benchmark folder (``smplik benchmark make`` on AMASS-layout clips), made once."""
    from smplik.benchmark import make_benchmark
    from smplik.data.dataset import build_cache, find_sources

    folder = work / "bench_src"
    if (folder / "files" / "manifest.json").is_file():
        return folder / "files"
    clips = folder / "clips"
    clips.mkdir(parents=True)
    rng = np.random.default_rng(0)
    names = [f"clip{c}" for c in range(4)]
    for name in names:  # AMASS's layout (poses, trans, betas, gender, mocap_framerate), as smplik.data.amass reads
        t = np.linspace(0, 2 * np.pi, 30)[:, None]
        poses = rng.normal(0, 0.25, 72) + rng.normal(0, 0.3, 72) * np.sin(t + rng.uniform(0, 6, 72))
        poses[:, :3] = [np.pi / 2, 0, 0]
        np.savez(clips / f"{name}.npz", poses=poses, trans=np.zeros((30, 3)), betas=rng.normal(0, 1, 10),
                 gender="neutral", mocap_framerate=30.0)
    split = {"train": {"files": [f"{n}.npz" for n in names[:2]]}, "validation": {"files": [f"{names[2]}.npz"]},
             "test": {"files": [f"{names[3]}.npz"]}}
    (clips / "split.json").write_text(json.dumps(split))
    build_cache(find_sources(clips, "amass"), fps=30, split=clips / "split.json", out=folder / "cache.npz")
    make_benchmark(folder / "cache.npz", folder / "files", split="test", seed=0, samples_per_count=3)
    return folder / "files"


MANIFEST_MUTATIONS: dict[str, Callable[[dict], Any]] = {
    "sha256_missing": lambda m: m["sets"][0].pop("sha256"), "name_missing": lambda m: m["sets"][0].pop("name"),
    "file_bool": lambda m: m["sets"][0].__setitem__("file", True),
    "file_list": lambda m: m["sets"][0].__setitem__("file", [1]),
    "file_traversal": lambda m: m["sets"][0].__setitem__("file", "../../x.npz"),
    "sets_int": lambda m: m.__setitem__("sets", 3), "set_str": lambda m: m["sets"].__setitem__(0, "x"),
    "source_missing": lambda m: m.pop("source"), "source_data_int": lambda m: m["source"].__setitem__("data", 1),
    "version_list": lambda m: m.__setitem__("version", [1]), "root_list": lambda m: m.clear(),
}


def crafted_cases(valid: dict[str, Any], work: Path) -> list[Case]:
    """The external campaign's findings as inputs: sparse-index model files, pickle DAGs, stride-0 tensors, every
    bomb (npz, BVH frames, image pixels, JSON size, /dev/zero), corrupt zips, mutated benchmark files."""
    import torch


    root = work / "crafted"
    root.mkdir()
    cases: list[Case] = []
    effectors_file = work / "valid_effectors.json"
    n = iter(range(10**6))

    def folder() -> Path:
        d = root / f"c{next(n):03d}"
        d.mkdir()
        return d

    # SMPL model files: sparse J_regressor index arrays out of range (a SIGSEGV before)
    for layout, where in (("csr", "indices"), ("csc", "indices"), ("csr", "indptr"), ("coo", "row"), ("coo", "col")):
        for index in (10**9, -5):
            d = folder()
            arrays = _sparse_model(valid["smpl_arrays"], layout, index, where)
            (d / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps(arrays, protocol=2))
            cases.append(Case("sparse_model_file", ["body", "info", "--model-dir", str(d)],
                              f"{layout}.{where}={index}"))
    d = folder()
    (d / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps(_sparse_model(valid["smpl_arrays"], "csr", 10**9, "indices")))
    cases.append(Case("sparse_model_file", ["solve", str(effectors_file), "--model-dir", str(d), "--out",
                                            str(d / "pose.json")], "solve:csr.indices=1e9", output=d / "pose.json"))
    # pickle DAGs (2**28 objects once expanded)
    d = folder()
    (d / "results.pkl").write_bytes(pickle.dumps({"pred_thetas": _dag(), "pred_betas": _dag()}))
    cases.append(Case("pickle_dag", ["scene", "from-estimate", str(d / "results.pkl"), "--out", str(d / "out"),
                                     "--no-previews"], "estimator:dag28"))
    d = folder()
    (d / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps({**valid["smpl_arrays"], "v_template": _dag()}))
    cases.append(Case("pickle_dag", ["body", "info", "--model-dir", str(d)], "smpl_pkl:dag28"))
    d = folder()
    np.savez(d / "results.npz", results=_object_array(_dag()))
    cases.append(Case("pickle_dag", ["scene", "from-estimate", str(d / "results.npz"), "--out", str(d / "out"),
                                     "--no-previews"], "npz_object:dag28"))
    # stride-0 tensors (8 GB once made contiguous)
    view = torch.zeros(1).expand(10**9, 8)
    d = folder()
    incam = {"body_pose": view, "global_orient": torch.zeros(1, 3), "transl": torch.zeros(1, 3),
             "betas": torch.zeros(1, 10)}
    torch.save({"smpl_params_incam": incam, "smpl_params_global": {"body_pose": view}, "K_fullimg": torch.eye(3)[None]},
               d / "hmr4d_results.pt")
    cases.append(Case("stride0_tensor", ["scene", "from-estimate", str(d / "hmr4d_results.pt"), "--out", str(d / "o"),
                                         "--no-previews"], "gvhmr.pt"))
    d = folder()
    torch.save({"global_orient": view, "body_pose": torch.zeros(1, 69)}, d / "params.pt")
    cases.append(Case("stride0_tensor", ["scene", "from-estimate", str(d / "params.pt"), "--out", str(d / "o"),
                                         "--no-previews"], "plain.pt"))
    from smplik.model_io import read_model_file

    d = folder()
    state = read_model_file(valid["pt"])
    torch.save({**state, "metrics": {"x": view}}, d / "model.pt")
    cases.append(Case("stride0_tensor", ["solve", str(effectors_file), "--checkpoint", str(d / "model.pt"), "--out",
                                         str(d / "pose.json")], "model.pt", output=d / "pose.json"))
    d = folder()
    torch.save({**state, "refine": {"iterations": 10**9}}, d / "model.pt")
    cases.append(Case("model_config", ["solve", str(effectors_file), "--checkpoint", str(d / "model.pt"), "--out",
                                       str(d / "pose.json")], "refine.iterations=1e9", output=d / "pose.json"))
    d = folder()
    torch.save({**state, "network": {**state["network"], "width": 10**9}}, d / "model.pt")
    cases.append(Case("model_config", ["solve", str(effectors_file), "--checkpoint", str(d / "model.pt"), "--out",
                                       str(d / "pose.json")], "network.width=1e9", output=d / "pose.json"))
    # npz bombs: a member inflating to 2.4 GB from a few MB, through every npz reader
    bomb = _zip_bomb(work / "bomb.npz")
    d = folder()
    (d / "amass").mkdir()
    shutil.copy(bomb, d / "amass" / "clip_poses.npz")
    cases.append(Case("npz_bomb", ["data", "build", "--amass", str(d / "amass"), "--split-by-subject", "0", "--out",
                                   str(d / "cache.npz")], "data build --amass", output=d / "cache.npz"))
    bench = _benchmark_files(work)
    d = folder()
    shutil.copytree(bench, d / "files")
    manifest = json.loads((d / "files" / "manifest.json").read_text())
    shutil.copy(bomb, d / "files" / manifest["sets"][0]["file"])
    import hashlib

    manifest["sets"][0]["sha256"] = hashlib.sha256(bomb.read_bytes()).hexdigest()  # past the SHA check
    (d / "files" / "manifest.json").write_text(json.dumps(manifest))
    cases.append(Case("npz_bomb", ["benchmark", "run", "--files", str(d / "files"), "--methods", "rest", "--out",
                                   str(d / "r.json")], "benchmark set file", output=d / "r.json"))
    d = folder()
    shutil.copy(bomb, d / "results.npz")
    cases.append(Case("npz_bomb", ["scene", "from-estimate", str(d / "results.npz"), "--out", str(d / "o"),
                                   "--no-previews"], "estimator npz"))
    # mutated benchmark files (KeyError 'sha256', PosixPath / bool, unhashable, not subscriptable ... before)
    for name, mutate in MANIFEST_MUTATIONS.items():
        d = folder()
        shutil.copytree(bench, d / "files")
        m = json.loads((d / "files" / "manifest.json").read_text())
        mutate(m)
        (d / "files" / "manifest.json").write_text(json.dumps(m))
        cases.append(Case("benchmark_files", ["benchmark", "run", "--files", str(d / "files"), "--methods", "rest",
                                              "--out", str(d / "r.json")], f"manifest:{name}", output=d / "r.json"))
    # BVH declaring 10**7 frames: with the frame lines (60 MB) and with the header alone
    head = ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n"
            "End Site\n{\nOFFSET 0 1 0\n}\n}\n")
    d = folder()
    with open(d / "big.bvh", "w") as fh:
        fh.write(head + "MOTION\nFrames: 10000000\nFrame Time: 0.0083333\n")
        line = "0 0 0\n" * 10_000
        for _ in range(1000):
            fh.write(line)
    cases.append(Case("bvh_bomb", ["invert-shape", str(d / "big.bvh"), "--out", str(d / "s.json")], "10^7 frames",
                      output=d / "s.json"))
    d = folder()
    (d / "head.bvh").write_text(head + "MOTION\nFrames: 10000000\nFrame Time: 0.0083333\n0 0 0\n")
    cases.append(Case("bvh_bomb", ["invert-shape", str(d / "head.bvh"), "--out", str(d / "s.json")],
                      "10^7 frames declared", output=d / "s.json"))
    # a 13000 x 13000 image (164 KB as PNG, 1.9 GiB decoded as floats)
    from PIL import Image

    d = folder()
    Image.new("L", (13000, 13000)).save(d / "huge.png")
    # with a camera, so that render draws the image behind the characters
    camera = {"focal_px": None, "image_size": None, "default_fov_deg": 60.0, "principal_px": None, "focal_rule": "fov"}
    (d / "scene.json").write_text(json.dumps({**valid["scene"], "camera": camera}))
    cases.append(Case("image_bomb", ["scene", "render", str(d / "scene.json"), "--image", str(d / "huge.png"),
                                     "--out", str(d / "r.png")], "scene render --image 13000^2", output=d / "r.png"))
    cases.append(Case("image_bomb", ["scene", "from-estimate", str(valid["romp"]), "--image", str(d / "huge.png"),
                                     "--out", str(d / "fe")], "from-estimate --image 13000^2"))
    # JSON of 300 MB (effectors, joints) and /dev/zero
    d = folder()
    big = json.dumps(valid["effectors"])[:-1] + ', "pad": [' + "0," * (150 << 20) + "0]}"
    (d / "eff.json").write_text(big)
    cases.append(Case("json_bomb", ["solve", str(d / "eff.json"), "--out", str(d / "pose.json")], "effectors 300 MB",
                      output=d / "pose.json"))
    joints = json.dumps(valid["joints_json"])[:-1] + ', "pad": [' + "0," * (150 << 20) + "0]}"
    (d / "joints.json").write_text(joints)
    cases.append(Case("json_bomb", ["invert-shape", str(d / "joints.json"), "--out", str(d / "s.json")],
                      "joints 300 MB", output=d / "s.json"))
    for args in (["solve", "/dev/zero"], ["scene", "solve", "/dev/zero"]):
        d = folder()
        cases.append(Case("json_bomb", [*args, "--out", str(d / "o.json")], " ".join(args), output=d / "o.json"))
    # corrupt zips: a deflated model file with damaged data, a truncated estimator npz
    import zipfile

    d = folder()
    with zipfile.ZipFile(valid["pt"]) as src, zipfile.ZipFile(d / "deflated.pt", "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            dst.writestr(info.filename, src.read(info.filename))
    data = bytearray((d / "deflated.pt").read_bytes())
    data[len(data) // 2: len(data) // 2 + 256] = bytes(range(256))
    (d / "corrupt.pt").write_bytes(data)
    cases.append(Case("corrupt_zip", ["solve", str(effectors_file), "--checkpoint", str(d / "corrupt.pt"), "--out",
                                      str(d / "pose.json")], "deflated model, damaged", output=d / "pose.json"))
    romp = bytearray(Path(valid["romp"]).read_bytes())
    romp[len(romp) // 3: len(romp) // 3 + 64] = bytes(64)
    (d / "results.npz").write_bytes(romp)
    cases.append(Case("corrupt_zip", ["scene", "from-estimate", str(d / "results.npz"), "--out", str(d / "o"),
                                      "--no-previews"], "romp npz, damaged"))
    return cases


def _object_array(obj: Any) -> np.ndarray:
    out = np.empty((), dtype=object)
    out[()] = obj
    return out


# ----------------------------------------------------------------------------- the editor from foreign origins


EDITOR_ATTEMPTS = {  # name: (origin, token?) -- {own} is the editor's own origin
    "origin_evil": ("http://evil.example.com", True), "origin_null": ("null", True), "origin_missing": (None, True),
    "origin_other_port": ("http://127.0.0.1:{other}", True), "origin_https": ("https://127.0.0.1:{port}", True),
    "token_missing": ("{own}", False), "token_wrong": ("{own}", "wrong"), "own_page_with_token": ("{own}", True),
}


def editor_cases(valid: dict[str, Any], work: Path, timeout: float, env: dict[str, str]) -> list[dict[str, Any]]:
    """``smplik edit`` on a scene, then raw WebSocket clients (what any page or local program can send) with
    foreign and null origins and missing/wrong tokens: each must be refused (a foreign client that gets in
    is a ``payload_run``: it could press Save); the editor's own origin with the token must get in; the scene
    file must be unchanged afterwards (``corrupted_output`` otherwise)."""
    import asyncio
    import re

    import viser
    import websockets.asyncio.client as ws_client
    from websockets.exceptions import InvalidStatus

    d = work / "editor"
    d.mkdir()
    scene = d / "scene.json"
    scene.write_text(json.dumps(valid["scene"]))
    before = scene.read_bytes()
    proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", "edit", str(scene), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT,
                            preexec_fn=_limit)
    results = []
    url = None
    deadline = time.monotonic() + timeout
    lines: list[str] = []
    while url is None and time.monotonic() < deadline and proc.poll() is None:
        line = proc.stdout.readline()
        lines.append(line)
        m = re.search(r"smplik editor: (http://127\.0\.0\.1:(\d+)/\?token=([\w-]+))", line)
        if m:
            url, port, token = m.group(1), int(m.group(2)), m.group(3)
    try:
        if url is None:
            outcome = "hang" if proc.poll() is None else "crash"
            return [{"reader": "editor_origin", "outcome": outcome, "rc": proc.returncode, "peak_mb": 0.0,
                     "note": "start", "last_line": "".join(lines)[-300:]}]

        async def attempt(origin: str | None, token_value: Any) -> str:
            query = f"?token={token if token_value is True else token_value}" if token_value else ""
            headers = {} if origin is None else {"Origin": origin.format(own=f"http://127.0.0.1:{port}", port=port,
                                                                         other=port + 1)}
            try:
                async with ws_client.connect(f"ws://127.0.0.1:{port}/{query}", additional_headers=headers,
                                             subprotocols=[f"viser-v{viser.__version__}"], origin=None,
                                             open_timeout=30) as ws:
                    await asyncio.wait_for(ws.recv(), 30)
                    return "open"
            except InvalidStatus as exc:
                return f"refused {exc.response.status_code}"

        for name, (origin, token_value) in EDITOR_ATTEMPTS.items():
            got = asyncio.run(attempt(origin, token_value))
            own = name == "own_page_with_token"
            if own:
                outcome = "accepted" if got == "open" else "unclear_error"
            else:
                outcome = "payload_run" if got == "open" else "clean_error" if got == "refused 403" else "unclear_error"
            results.append({"reader": "editor_origin", "outcome": outcome, "rc": 0, "peak_mb": 0.0, "note": name,
                            "last_line": got})
    finally:
        proc.terminate()
        try:
            _, status, rusage = os.wait4(proc.pid, 0)
        except ChildProcessError:
            rusage = None
        peak = rusage.ru_maxrss / 1024 if rusage else 0.0
        for r in results:
            r["peak_mb"] = round(peak, 1)
    if scene.read_bytes() != before:
        results.append({"reader": "editor_origin", "outcome": "corrupted_output", "rc": 0, "peak_mb": 0.0,
                        "note": "scene file changed", "last_line": ""})
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=240.0,
                        help="Wall-clock budget of the random mutations (default 240), after the crafted cases.")
    parser.add_argument("--timeout", type=float, default=120.0, help="Per-run timeout in seconds (hang).")
    parser.add_argument("--workers", type=int, default=2, help="Parallel CLI runs.")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--readers", default="", help="Comma-separated subset of random readers (default: all).")
    parser.add_argument("--no-crafted", action="store_true", help="Skip the crafted cases and the editor.")
    parser.add_argument("--round3-only", action="store_true", help="Run only the round-3 cases of issue 36 "
                        "(benchmarks/fuzz_round3.py); results default to benchmarks/results/fuzz_round3.json.")
    # --- round 4, budgets (issue 45): benchmarks/fuzz_round4_budgets.py ---
    parser.add_argument("--round4-budgets-only", action="store_true", help="Run only the round-4 budget cases of "
                        "issue 45 (benchmarks/fuzz_round4_budgets.py); results default to "
                        "benchmarks/results/fuzz_round4_budgets.json.")
    args = parser.parse_args()
    if args.round3_only and args.out == RESULTS:
        args.out = RESULTS.with_name("fuzz_round3.json")
    if args.round4_budgets_only and args.out == RESULTS:
        args.out = RESULTS.with_name("fuzz_round4_budgets.json")
    only = args.round3_only or args.round4_budgets_only

    work = Path(tempfile.mkdtemp(prefix="smplik-fuzz-"))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYOPENGL_PLATFORM": "egl", "OMP_NUM_THREADS": "1",
           "PYTHONWARNINGS": "ignore", "COLUMNS": "80",
           "SMPLIK_CACHE_DIR": os.environ.get("SMPLIK_CACHE_DIR", str(work / "cache"))}
    env.pop("SMPLIK_MODEL_DIR", None)
    os.environ["SMPLIK_CACHE_DIR"] = env["SMPLIK_CACHE_DIR"]
    start = time.monotonic()
    results: list[dict[str, Any]] = []
    lock = threading.Lock()

    def record(res: dict[str, Any]) -> None:
        with lock:
            results.append(res)
            print(f"[{time.monotonic() - start:6.0f}s] {res['reader']:<22} {res['outcome']:<13} "
                  f"{res['note'][:40]:<40} {res['last_line'][:90]}", flush=True)

    try:
        if args.round3_only:
            from fuzz_round3 import round3_cases

            with ThreadPoolExecutor(args.workers) as pool:
                for res in pool.map(lambda c: run_case(c, args.timeout, env), round3_cases(work / "round3")):
                    record(res)
            args.seconds = 0.0
        # --- round 4, budgets (issue 45): each case a clean error holding its key or limit variable ---
        if args.round4_budgets_only or not (args.no_crafted or args.round3_only):
            from fuzz_round4_budgets import run_round4_budgets

            for res in run_round4_budgets(work / "round4_budgets", args.timeout, env, args.workers):
                record(res)
            if args.round4_budgets_only:
                args.seconds = 0.0
        valid = make_valid_inputs(work / "valid") if not only else {}
        makers = case_makers(valid, work) if not only else {}
        if not args.no_crafted and not only:
            for res in editor_cases(valid, work, args.timeout, env):
                record(res)
            crafted = crafted_cases(valid, work)
            from fuzz_round3 import round3_cases  # issue 36: each case must be a clean error

            crafted += round3_cases(work / "round3")
            # --- issue 45, outputs and glTF/VRM readers (benchmarks/fuzz_round4_outputs.py) ---
            from fuzz_round4_outputs import round4_output_cases

            crafted += round4_output_cases(work / "round4_outputs")
            # --- end of issue 45, outputs ---
            with ThreadPoolExecutor(args.workers) as pool:
                for res in pool.map(lambda c: run_case(c, args.timeout, env), crafted):
                    record(res)
        if args.readers:
            makers = {k: v for k, v in makers.items() if k in args.readers.split(",")}
        rng = random.Random(args.seed)
        random_start = time.monotonic()
        counter = iter(range(10**9))
        order = sorted(makers)

        def worker(slot: int) -> None:
            while time.monotonic() - random_start < args.seconds:
                with lock:
                    n = next(counter)
                    reader = order[n % len(order)]
                    seed = rng.random()
                try:
                    case = makers[reader](random.Random(seed), n)
                except Exception as exc:  # noqa: BLE001 - a mutation the generator itself cannot write
                    print(f"skipped a {reader} case: {type(exc).__name__}: {exc}", flush=True)
                    continue
                record(run_case(case, args.timeout, env))

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
    peak = max((s["peak_mb"] for s in summary.values()), default=0.0)
    report = {"seconds": args.seconds, "timeout_s": args.timeout, "memory_cap_bytes": MEMORY_CAP, "seed": args.seed,
              "wall_s": round(time.monotonic() - start, 1), "totals": totals, "peak_mb": peak,
              "peak_rss_within_2gb": peak <= 2048, "readers": summary}
    round4 = [r for r in results if "as_expected" in r]  # round 4, budgets (issue 45)
    if round4:
        report["round4_budgets"] = {"cases": len(round4), "as_expected": sum(r["as_expected"] for r in round4),
                                    "max_peak_mb": max(r["peak_mb"] for r in round4),
                                    "cases_detail": [{k: r[k] for k in ("reader", "note", "outcome", "peak_mb",
                                                                        "expected", "as_expected", "last_line")}
                                                     for r in round4]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(totals), f"peak RSS {peak:.0f} MB")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
