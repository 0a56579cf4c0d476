"""Issue 36's "memory and time not bounded" cases, rebuilt from their recipes and run through the CLI under a 3 GiB
address-space cap: exit status, the error line, peak RSS and wall time of each (each must be one ``error:`` line,
exit 1, < 2 GiB, < 150 s).

    python benchmarks/limits_round3.py            # writes benchmarks/results/limits_round3.json

The recipes are the ones of ``tests/test_resource_limits.py`` (which asserts the same outcomes in CI).
"""

from __future__ import annotations

import gzip
import json
import os
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from limit_recipes import bvh_text, gltf_rig, run_capped, str_of_list_dag  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "limits_round3.json"


def cases(work: Path) -> dict[str, list[str]]:
    """name -> smplik arguments, each input written under ``work``."""
    import torch

    from smplik.model_io import read_model_file
    from smplik.solver import packaged_model_path

    out: dict[str, list[str]] = {}

    def folder(name: str) -> Path:
        d = work / name
        d.mkdir()
        return d

    d = folder("str_dag")
    (d / "results.pkl").write_bytes(str_of_list_dag())
    out["pickle: builtins.str of a 27-level list DAG"] = ["scene", "from-estimate", str(d / "results.pkl"), "--out",
                                                           str(d / "o"), "--no-previews"]
    d = folder("gzip")
    (d / "results.pkl").write_bytes(gzip.compress(b"\x80\x04\x8e" + (4 << 30).to_bytes(8, "little") + bytes(4 << 20),
                                                  compresslevel=1))
    out["gzip .pkl declaring 4 GiB"] = ["scene", "from-estimate", str(d / "results.pkl"), "--out", str(d / "o"),
                                        "--no-previews"]
    d = folder("stride0")
    torch.save({"smpl_params_global": {"body_pose": torch.zeros(1).expand(199_000_000),  # 4 bytes stored each
                                       "betas": torch.zeros(1).expand(199_000_000)}}, d / "hmr4d_results.pt")
    out["two stride-0 .pt tensors of 199M elements (float64 conversion)"] = [
        "scene", "from-estimate", str(d / "hmr4d_results.pt"), "--out", str(d / "o"), "--no-previews"]
    d = folder("compressed_pt")
    torch.save({"x": torch.zeros(4)}, d / "plain.pt")
    with zipfile.ZipFile(d / "plain.pt") as src, zipfile.ZipFile(d / "hmr4d_results.pt", "w") as dst:
        for info in src.infolist():
            if "/data/" in info.filename:
                dst.writestr(info.filename, bytes(800 << 20), compress_type=zipfile.ZIP_DEFLATED, compresslevel=1)
            else:
                dst.writestr(info, src.read(info))
    out[".pt with a compressed 800 MB storage member"] = ["scene", "from-estimate", str(d / "hmr4d_results.pt"),
                                                          "--out", str(d / "o"), "--no-previews"]
    d = folder("wide")
    state = read_model_file(packaged_model_path())
    state["network"] = {**state["network"], "width": 8192}
    torch.save(state, d / "wide.pt")
    (d / "e.json").write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [
        {"joint": "pelvis", "type": "position", "value": [0.0, 0.9, 0.0]}]}))
    out["checkpoint with network.width 8192"] = ["solve", str(d / "e.json"), "--checkpoint", str(d / "wide.pt"),
                                                 "--out", str(d / "p.json")]
    d = folder("train")
    (d / "c.json").write_text(json.dumps({"network": {"encoder_blocks": 32, "decoder_blocks": 32,
                                                      "layers_per_block": 16}}))
    out["train --config with the most blocks and layers"] = ["train", "--config", str(d / "c.json"), "--data",
                                                             str(d / "cache.npz"), "--out", str(d / "run")]
    d = folder("render")
    out["body render 8192 x 8192"] = ["body", "render", "--out", str(d / "b.png"), "--width", "8192", "--height",
                                      "8192"]
    d = folder("zero")
    (d / "z.glb").symlink_to("/dev/zero")
    out["z.glb -> /dev/zero"] = ["invert-shape", str(d / "z.glb"), "--out", str(d / "s.json")]
    d = folder("fifo")
    os.mkfifo(d / "pipe.bin")
    gltf_rig(d, [{"uri": "pipe.bin", "byteLength": 128}],
          [{"bufferView": 0, "componentType": 5126, "count": 2, "type": "MAT4"}])
    out["glTF buffer on a named pipe"] = ["invert-shape", str(d / "rig.gltf"), "--out", str(d / "s.json")]
    d = folder("skin")
    gltf_rig(d, [], [{"componentType": 5126, "count": 50_000_000, "type": "MAT4"}])
    out["skin accessor claiming 5e7 matrices"] = ["invert-shape", str(d / "rig.gltf"), "--out", str(d / "s.json")]
    d = folder("json")
    with open(d / "plain.json", "wb") as fh:
        fh.truncate(300 << 20)
    out["300 MB estimator JSON"] = ["scene", "from-estimate", str(d / "plain.json"), "--out", str(d / "o"),
                                    "--no-previews"]
    d = folder("bvh")
    (d / "long.bvh").write_text(bvh_text(31, 900_000, 2))
    out["BVH declaring 900,000 frames of 31 joints (data preview)"] = ["data", "preview", str(d / "long.bvh"),
                                                                       "--out", str(d / "p.png")]
    d = folder("bench")
    out["benchmark make --samples-per-count 1e9"] = ["benchmark", "make", "--data", str(d / "cache.npz"), "--out",
                                                     str(d / "b"), "--samples-per-count", "1000000000"]
    return out


def main() -> None:
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, args in cases(Path(tmp)).items():
            start = time.monotonic()
            rc, lines, peak = run_capped(*args)
            wall = time.monotonic() - start
            ok = rc == 1 and len(lines) == 1 and lines[0].startswith("error: ") and peak < 2 << 30 and wall < 150
            results.append({"case": name, "rc": rc, "stderr_lines": len(lines), "peak_mb": round(peak / 2**20, 1),
                            "wall_s": round(wall, 1), "ok": ok, "error": lines[0][:300] if lines else ""})
            print(f"{'ok ' if ok else 'BAD'} rc={rc} peak={peak / 2**20:7.1f} MB wall={wall:5.1f} s  {name}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"cases": results, "all_ok": all(r["ok"] for r in results)}, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
