"""The README's benchmark table agrees with ``benchmarks/results/*.json``: each row's figures are read from the
README by a pattern and compared with the value the benchmark script wrote, to the digits the README prints.

The map below names, per row, the pattern of its figures and where each figure comes from. A row whose text no
longer matches its pattern fails too (update the pattern with the row). The IK row's times are not checked: the
README and docs/benchmarks.md give times measured on an idle machine, the JSON's come from a busy one (said there).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"


def _json(name: str) -> dict:
    return json.loads((RESULTS / name).read_text())


def _ik(method: str, key: str) -> float:
    return _json("ik_benchmark.json")["methods"][method]["random_mean"][key]


def _truth_rows() -> list[dict]:
    return _json("animation_truth.json")["rows"]


def _truth_mean(method: str, key: str) -> float:
    return float(np.mean([row[method][key] for row in _truth_rows()]))


def _tracking(method: str, key: str) -> float:
    return _json("tracking.json")["summary"]["exact"][method][key]


def _real_speed() -> list[dict]:
    return _json("animation_real_speed.json")["rows"]


def _fresh(row: dict) -> float:
    """frames per CPU second of a fresh ``scene animate`` command (fast backends) on one real file."""
    return next(c["frames_per_cpu_s"] for c in row["command"] if c["fast_backends"])


# README row (a phrase of its first cell) -> (pattern of its figures, one source per captured figure)
ROWS: dict[str, tuple[str, list[Callable[[], float]]]] = {
    "IK accuracy, CMU test split": (
        r"solver \*\*([\d.]+) mm / ([\d.]+) rad .*; network alone ([\d.]+) mm / ([\d.]+) rad .*; "
        r"optimization IK ([\d.]+) mm / ([\d.]+) rad",
        [lambda: _ik("smplik", "mpjpe_mm"), lambda: _ik("smplik", "geodesic_rad"),
         lambda: _ik("smplik_net", "mpjpe_mm"), lambda: _ik("smplik_net", "geodesic_rad"),
         lambda: _ik("optim", "mpjpe_mm"), lambda: _ik("optim", "geodesic_rad")]),
    "effector residual of the solver": (
        r"\| ([\d.]+) mm / ([\d.]+)° \|",
        [lambda: _ik("smplik", "position_residual_mm"), lambda: _ik("smplik", "rotation_residual_deg")]),
    "one `solve()`": (
        r"\| ([\d.]+) ms \|",
        [lambda: _json("speed.json")["summary"]["onnx_solve_single_p50_ms_1thread"]]),
    "throughput, batch 1024": (
        r"([\d,]+) / ([\d,]+) poses/s",
        [lambda: _json("speed.json")["summary"]["onnx_network_b1024_poses_per_s_2threads"],
         lambda: _json("speed.json")["summary"]["onnx_refined_b1024_poses_per_s_2threads"]]),
    "video estimates → animation": (
        r"PA-MPJPE ([\d.]+) mm \(Savitzky-Golay ([\d.]+), raw ([\d.]+);.*acceleration error ([\d.]+) mm/frame² "
        r"\(([\d.]+), ([\d.]+)\), foot skating on the truth's contacts ([\d.]+) mm/frame \(truth ([\d.]+), "
        r"raw ([\d.]+)\), ≤ ([\d.]+) % clean frames repaired, (\d+)/(\d+) glitches repaired; (\d+) of (\d+) clips "
        r"still miss .*; (\d+)-(\d+) frames per CPU second on real",
        [lambda: _truth_mean("default", "pa_mpjpe_mm"), lambda: _truth_mean("savgol", "pa_mpjpe_mm"),
         lambda: _truth_mean("raw", "pa_mpjpe_mm"),
         lambda: _truth_mean("default", "accel_error_mm"), lambda: _truth_mean("savgol", "accel_error_mm"),
         lambda: _truth_mean("raw", "accel_error_mm"),
         lambda: _truth_mean("default", "skating_mm_per_frame"), lambda: _truth_mean("truth", "skating_mm_per_frame"),
         lambda: _truth_mean("raw", "skating_mm_per_frame"),
         lambda: max(row["default"]["false_repairs_pct"] for row in _truth_rows()),
         lambda: sum(row["glitches_injected"] - row["default"].get("glitches_left", 0) for row in _truth_rows()),
         lambda: sum(row["glitches_injected"] for row in _truth_rows()),
         lambda: sum(not all(row["checks"].values()) for row in _truth_rows()),
         lambda: len(_truth_rows()),
         lambda: min(row["warm"]["frames_per_cpu_s"] for row in _real_speed()),
         lambda: max(row["warm"]["frames_per_cpu_s"] for row in _real_speed())]),
    "full body from 4 exact VR trackers": (
        r"\*\*([\d.]+) mm / (\d+) cm/s² / ([\d.]+) mm/frame\*\* \(per-frame IK solver ([\d.]+) / (\d+) / ([\d.]+)\); "
        r"([\d.]+) ms per frame",
        [lambda: _tracking("ours", "mpjpe_mm"), lambda: _tracking("ours", "mpjae_cm_s2"),
         lambda: _tracking("ours", "skating_mm_per_frame"), lambda: _tracking("ik", "mpjpe_mm"),
         lambda: _tracking("ik", "mpjae_cm_s2"), lambda: _tracking("ik", "skating_mm_per_frame"),
         lambda: _json("tracking.json")["per_frame_cost_ms"]["deterministic"]["p50_ms"]]),
}


def _benchmark_rows() -> dict[str, str]:
    """The README's benchmark table: first cell -> the whole row."""
    text = (REPO / "README.md").read_text()
    table = text[text.index("| what | result |"):].split("\n\n")[0]
    return {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines()[2:]}


def _row(phrase: str) -> str:
    found = [line for what, line in _benchmark_rows().items() if phrase in what]
    assert len(found) == 1, f"README's benchmark table has {len(found)} rows naming {phrase!r}"
    return found[0]


def _agrees(printed: str, value: float) -> bool:
    """``printed`` (as the README writes it: 12.2, 27,559, 0.20) is ``value`` rounded to its digits."""
    digits = len(printed.split(".")[1]) if "." in printed else 0
    return abs(float(printed.replace(",", "")) - value) <= 0.5 * 10.0 ** -digits + 1e-9


@pytest.mark.parametrize("phrase", list(ROWS))
def test_readme_benchmark_row_agrees_with_its_results_file(phrase):
    pattern, sources = ROWS[phrase]
    match = re.search(pattern, _row(phrase))
    assert match, f"README row {phrase!r} no longer matches its pattern in {Path(__file__).name}: update both"
    assert len(match.groups()) == len(sources)
    wrong = [(printed, round(source(), 4)) for printed, source in zip(match.groups(), sources, strict=True)
             if not _agrees(printed, source())]
    assert not wrong, f"README row {phrase!r}: (README figure, benchmarks/results value) disagree: {wrong}"


def test_readme_fresh_command_speeds_agree_with_the_real_files():
    """'a fresh `scene animate` command: A-B on C-D frames, E-F on G-H': every real file of
    ``animation_real_speed.json`` is in one frame range, its fresh command's frames per CPU second in that range."""
    match = re.search(r"fresh `scene animate` command: (\d+)-(\d+) on (\d+)-(\d+) frames, (\d+)-(\d+) on (\d+)-(\d+)",
                      _row("video estimates → animation"))
    assert match, "README's animation row no longer gives the fresh command's speeds as 'A-B on C-D frames, ...'"
    a, b, c, d, e, f, g, h = match.groups()
    for row in _real_speed():
        speed_range, _ = ((a, b), (c, d)) if int(c) <= row["frames"] <= int(d) else ((e, f), (g, h))
        assert int(c) <= row["frames"] <= int(d) or int(g) <= row["frames"] <= int(h), row["file"]
        lo, hi = speed_range
        assert float(lo) - 0.5 <= _fresh(row) <= float(hi) + 0.5, (row["file"], _fresh(row), speed_range)
    frames = sorted(row["frames"] for row in _real_speed())
    assert {int(c), int(d), int(g), int(h)} <= set(frames), "the README's frame ranges end on real files' lengths"


def test_the_figure_comparison_rounds_as_printed():
    assert _agrees("12.2", 12.221) and _agrees("27,559", 27559.48) and _agrees("0.20", 0.2005)
    assert not _agrees("12.3", 12.221) and not _agrees("0.77", 0.749) and not _agrees("83", 73.0)
