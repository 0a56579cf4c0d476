"""Recipes of the resource-limit tests (no tests here), also used by ``benchmarks/limits_round3.py``: the CLI
run under an address-space cap, and small files that declare or imply a lot of work."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CAP = 3 << 30

_WRAPPER = """
import json, resource, subprocess, sys
resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[1]), int(sys.argv[1])))
proc = subprocess.run(sys.argv[2:], capture_output=True, text=True, timeout=600)
peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(json.dumps({"rc": proc.returncode, "stderr": proc.stderr, "peak_kib": peak_kib}))
"""


def run_capped(*args: str, env: dict[str, str] | None = None) -> tuple[int, list[str], int]:
    """``smplik ARGS`` under a 3 GiB address-space cap: (exit status, non-empty stderr lines, peak RSS in bytes)."""
    full_env = {**os.environ, **(env or {})}
    proc = subprocess.run([sys.executable, "-c", _WRAPPER, str(CAP), sys.executable, "-m", "smplik.cli", *args],
                          capture_output=True, text=True, cwd=ROOT, env=full_env, timeout=900)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    lines = [ln for ln in out["stderr"].splitlines() if ln.strip()]
    return out["rc"], lines, out["peak_kib"] * 1024


def str_of_list_dag(levels: int = 27) -> bytes:
    """A pickle applying ``builtins.str`` to a list DAG of ``levels`` levels (a few hundred bytes; str() of it
    would format 2**levels lists)."""
    node: list = []
    for _ in range(levels):
        node = [node, node]

    class Call:
        def __reduce__(self):
            return str, (node,)

    return pickle.dumps({"pred_thetas": Call()}, protocol=4)


def gltf_rig(tmp_path: Path, buffers: list[dict], accessors: list[dict]) -> Path:
    """A two-joint skinned glTF file with these buffers and accessors (``rig.gltf`` under ``tmp_path``)."""
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"name": "hips", "children": [1]}, {"name": "spine", "translation": [0, 0.2, 0]}],
           "skins": [{"joints": [0, 1], "inverseBindMatrices": 0}], "buffers": buffers, "accessors": accessors,
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 128}] if buffers else []}
    path = tmp_path / "rig.gltf"
    path.write_text(json.dumps(doc))
    return path


def bvh_text(joints: int, frames: int, lines: int) -> str:
    """A chain of ``joints`` joints (3 rotation channels each) declaring ``frames`` frames over ``lines`` lines."""
    text = "HIERARCHY\nROOT j0\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation " \
           "Yrotation\n"
    for j in range(1, joints):
        text += f"JOINT j{j}\n{{\nOFFSET 0 1 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"
    text += "End Site\n{\nOFFSET 0 1 0\n}\n" + "}\n" * joints
    row = " ".join(["0"] * (3 * joints + 3)) + "\n"
    return text + f"MOTION\nFrames: {frames}\nFrame Time: 0.008333\n" + row * lines
