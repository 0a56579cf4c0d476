"""Randomized-effector benchmark (ProtoRes section 3.2 and App. E; SMPL-IK F.2).

The package keeps one concern per module; every public name is re-exported here:

* :mod:`.files`: the benchmark file format (:func:`make_benchmark`, :func:`load_benchmark`,
  :class:`BenchmarkSet`) and each sample's subject (:func:`sample_subjects`).
* :mod:`.evaluate`: metrics of a prediction, per sample and pooled (:func:`evaluate_prediction`,
  :class:`SampleErrors`), on top of :mod:`smplik.metrics`.
* :mod:`.methods`: the SMPL-IK solver as a method (:class:`LearnedMethod`) and the rest pose;
  :mod:`.optimization` (:class:`OptimizationIK`, :class:`PosePrior`) and :mod:`.nearest`
  (:class:`NearestNeighborMethod`): the baselines.
* :mod:`.runner`: :func:`build_methods` by name, :func:`run_benchmark` (per set, the N = 6..12
  mean, and per subject), :func:`save_results`.
* :mod:`.report`: :func:`results_markdown`.
* :mod:`.tolerance`: the tolerance-tracking scenario of ``benchmarks/tolerance_tracking.py``.
"""

from .evaluate import (
    EFFECTOR_KINDS,
    Prediction,
    SampleErrors,
    SetMetrics,
    effector_errors,
    effector_slot_errors,
    evaluate_prediction,
    sample_errors,
)
from .files import (
    BENCHMARK_FORMAT,
    BENCHMARK_VERSION,
    FIXED_SETS,
    LIMB_ZONES,
    LOOKAT_DISTANCE_STD,
    MANIFEST,
    RANDOM_COUNTS,
    ZONES,
    Benchmark,
    BenchmarkSet,
    load_benchmark,
    make_benchmark,
    sample_subjects,
    set_names,
    write_npz_deterministic,
)
from .methods import LearnedMethod, Method, RestPoseMethod
from .nearest import NearestNeighborMethod
from .optimization import OptimizationIK, PosePrior
from .report import results_markdown
from .runner import (
    ALL_METHODS,
    LEARNED_METHODS,
    METHOD_DESCRIPTIONS,
    RESULTS_FORMAT,
    RESULTS_VERSION,
    TRAIN_DATA_METHODS,
    build_methods,
    run_benchmark,
    save_results,
)

__all__ = [
    "ALL_METHODS", "BENCHMARK_FORMAT", "BENCHMARK_VERSION", "EFFECTOR_KINDS", "FIXED_SETS", "LEARNED_METHODS",
    "LIMB_ZONES", "LOOKAT_DISTANCE_STD", "MANIFEST", "METHOD_DESCRIPTIONS", "RANDOM_COUNTS", "RESULTS_FORMAT",
    "RESULTS_VERSION", "TRAIN_DATA_METHODS", "ZONES", "Benchmark", "BenchmarkSet", "LearnedMethod", "Method",
    "NearestNeighborMethod", "OptimizationIK", "PosePrior", "Prediction", "RestPoseMethod", "SampleErrors",
    "SetMetrics", "build_methods", "effector_errors", "effector_slot_errors", "evaluate_prediction",
    "load_benchmark", "make_benchmark", "results_markdown", "run_benchmark", "sample_errors", "sample_subjects",
    "save_results", "set_names", "write_npz_deterministic",
]
