"""Markdown tables of a benchmark results document (:func:`smplik.benchmark.runner.run_benchmark`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

_COLUMNS = [("mpjpe_mm", "MPJPE (mm)", 1), ("pa_mpjpe_mm", "PA-MPJPE (mm)", 1), ("geodesic_rad", "geodesic (rad)", 4),
            ("position_residual_mm", "pos. residual (mm)", 1), ("rotation_residual_deg", "rot. residual (°)", 2),
            ("lookat_error_deg", "look-at (°)", 2), ("time_ms_per_pose", "time / pose (ms, batched)", 3)]


def _fmt(value: float | None, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"] + ["| " + " | ".join(r) + " |" for r in rows]


def _mpjpe_geo(m: Mapping[str, Any]) -> str:
    return f"{_fmt(m['mpjpe_mm'], 1)} / {_fmt(m['geodesic_rad'], 3)}"


def results_markdown(results: Mapping[str, Any]) -> str:
    """Markdown tables: the N = 6..12 average per method, the fixed 5-/6-point sets, then (when the
    results hold them) the per-subject MPJPE / geodesic error and their mean over subjects."""
    bench = results["benchmark"]
    methods = results["methods"]
    lines = [f"Random effectors, mean over N = 6..12 ({bench['samples_per_count']} poses per N, "
             f"{bench['source']['split']} split, seed {bench['seed']}):", ""]
    lines += _table(["method"] + [c[1] for c in _COLUMNS],
                    [[name] + [_fmt(res["random_mean"][k], d) for k, _, d in _COLUMNS]
                     for name, res in methods.items() if res.get("random_mean")])
    fixed = [s for s in next(iter(methods.values()))["sets"] if s.startswith("fixed_")]
    if fixed:
        lines += ["", "Fixed sparse sets (positions only): MPJPE / PA-MPJPE (mm) / geodesic (rad):", ""]
        lines += _table(["method"] + fixed, [
            [name] + [f"{_fmt(res['sets'][s]['mpjpe_mm'], 1)} / {_fmt(res['sets'][s]['pa_mpjpe_mm'], 1)} / "
                      f"{_fmt(res['sets'][s]['geodesic_rad'], 3)}" for s in fixed] for name, res in methods.items()])
    subjects = results.get("subjects")
    with_subjects = [name for name, res in methods.items() if res.get("subjects")]
    if subjects and with_subjects:
        lines += ["", f"Per subject ({len(subjects)} subjects of the {bench['source']['split']} split, random "
                  "N = 6..12 sets pooled): MPJPE (mm) / geodesic (rad):", ""]
        rows = [["**mean over subjects**", ""] + [_mpjpe_geo(methods[n]["subject_mean"]) for n in with_subjects]]
        rows += [[s, str(count)] + [_mpjpe_geo(methods[n]["subjects"][s]) for n in with_subjects]
                 for s, count in subjects.items()]
        lines += _table(["subject", "samples"] + with_subjects, rows)
    return "\n".join(lines) + "\n"
