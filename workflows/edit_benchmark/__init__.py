"""The edit benchmark, in one place: single-limb edits from real motion, every method side by side.

* :mod:`workflows.edit_benchmark.pairs`: edit pairs (frames ``t0 -> t1`` where one wrist or ankle moved) and the
  metrics per pair;
* :mod:`workflows.edit_benchmark.run`: the runner (recover ``t0``'s scene, drag, solve with each method, compare);
* the command ``smplik benchmark edits`` (:mod:`workflows.benchmark_cli`) and the script
  ``benchmarks/edit_benchmark.py`` that writes ``benchmarks/results/edit_benchmark.json``.
"""

from workflows.edit_benchmark.pairs import (
    LIMB_ENDS,
    LIMB_OF_END,
    LIMB_ROOT,
    RANGE_MARGIN_DEG,
    STILL_JOINTS,
    TORSO_JOINTS,
    TORSO_TURN_DEG,
    EditMetrics,
    EditPair,
    EditPairConfig,
    JointRanges,
    align_to_pelvis,
    edit_metrics,
    find_edit_pairs,
    limb_mask,
    pelvis_relative,
    summarize,
)
from workflows.edit_benchmark.run import (
    EDIT_FPS,
    METHOD_DESCRIPTIONS,
    METHODS,
    RESULTS_FORMAT,
    RESULTS_VERSION,
    EditBenchmarkConfig,
    EditClip,
    EditProblems,
    clip_fk,
    clips_from_dataset,
    clips_from_folder,
    edit_benchmark,
    evaluate_method,
    make_problems,
    run_edit_benchmark,
    save_figure,
    select_pairs,
    solve_method,
)

__all__ = [
    "EDIT_FPS", "LIMB_ENDS", "LIMB_OF_END", "LIMB_ROOT", "METHODS", "METHOD_DESCRIPTIONS", "RANGE_MARGIN_DEG",
    "RESULTS_FORMAT", "RESULTS_VERSION", "STILL_JOINTS", "TORSO_JOINTS", "TORSO_TURN_DEG", "EditBenchmarkConfig",
    "EditClip", "EditMetrics", "EditPair", "EditPairConfig", "EditProblems", "JointRanges", "align_to_pelvis",
    "clip_fk", "clips_from_dataset", "clips_from_folder", "edit_benchmark", "edit_metrics", "evaluate_method",
    "find_edit_pairs", "limb_mask", "make_problems", "pelvis_relative", "run_edit_benchmark", "save_figure",
    "select_pairs", "solve_method", "summarize",
]
