"""Running methods on benchmark files: the method registry and the results document.

:func:`run_benchmark` evaluates each method on every set and, given each sample's subject
(:func:`smplik.benchmark.files.sample_subjects`), also per subject: every metric pooled over one
subject's samples of the random N = 6..12 sets, and their unweighted mean over subjects, so a
subject with many samples cannot hide a subject with few.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from smplik.atomic import write_json_atomic
from smplik.body_model import BodyModelSet
from smplik.ensemble import EnsembleConfig
from smplik.refine import NO_REFINEMENT

from .evaluate import SampleErrors, SetMetrics, sample_errors
from .files import Benchmark
from .methods import LearnedMethod, Method, RestPoseMethod
from .nearest import NearestNeighborMethod
from .optimization import OptimizationIK, PosePrior

RESULTS_FORMAT = "smplik-benchmark-results"
RESULTS_VERSION = 1
METHOD_DESCRIPTIONS = {
    "smplik": "SMPL-IK solver: network + 3 Levenberg-Marquardt refinement steps (batched solve_tensors)",
    "smplik_net": "SMPL-IK network alone (no refinement)",
    "smplik_ens": "SMPL-IK solver with the test-time ensemble (smplik.ensemble), then the refinement",
    "smplik_net_ens": "SMPL-IK network alone with the test-time ensemble (smplik.ensemble)",
    "optim": "Adam IK on SMPL + diagonal Gaussian 6D pose prior (train split)",
    "nn": "nearest neighbour in the train split (scikit-learn)",
    "rest": "rest pose at the effector centroid",
}
ALL_METHODS = tuple(METHOD_DESCRIPTIONS)
"""Method names understood by :func:`build_methods`."""
LEARNED_METHODS = ("smplik", "smplik_net", "smplik_ens", "smplik_net_ens")
DEFAULT_BENCHMARK_ENSEMBLE = EnsembleConfig(yaw=4, mirror=True)
"""The ensemble of the ``*_ens`` methods unless told otherwise."""
TRAIN_DATA_METHODS = ("optim", "nn")
"""Methods that need the train split's poses."""
METRIC_KEYS = ("mpjpe_mm", "pa_mpjpe_mm", "geodesic_rad", "position_residual_mm", "rotation_residual_deg",
               "lookat_error_deg", "time_ms_per_pose")


def build_methods(names: Sequence[str], bodies: BodyModelSet, *, solver: Any = None, train_pose: Tensor | None = None,
                  optim_iterations: int = 200, nn_samples: int = 20_000,
                  ensemble: EnsembleConfig = DEFAULT_BENCHMARK_ENSEMBLE) -> tuple[dict[str, Method], dict[str, Any]]:
    """The named methods and the settings that describe them (for the results document).

    Args:
        names: subset of :data:`ALL_METHODS`, in run order.
        bodies: body models of the benchmark.
        solver: an :class:`smplik.solver.IKSolver`, needed by ``smplik`` and ``smplik_net``.
        train_pose: (M, 24, 3) axis-angle train poses, needed by ``optim`` (prior) and ``nn`` (index).
        optim_iterations: Adam iterations of ``optim``. nn_samples: train poses indexed by ``nn``.
        ensemble: the test-time ensemble of ``smplik_ens`` and ``smplik_net_ens``.

    Raises:
        ValueError: an unknown name, or a method whose solver or train poses are missing.
    """
    unknown = [n for n in names if n not in ALL_METHODS]
    if unknown or not names:
        raise ValueError(f"unknown method(s) {unknown}; choose from {', '.join(ALL_METHODS)}.")
    if solver is None and set(LEARNED_METHODS) & set(names):
        raise ValueError("the smplik methods need a solver (model file).")
    if train_pose is None and set(TRAIN_DATA_METHODS) & set(names):
        raise ValueError("the optim and nn baselines need the train split's poses (--data).")
    methods: dict[str, Method] = {}
    settings: dict[str, Any] = {"methods": list(names)}
    for name in names:
        if name in LEARNED_METHODS:
            methods[name] = LearnedMethod(solver, refine=NO_REFINEMENT if name.startswith("smplik_net") else None,
                                          ensemble=ensemble if name.endswith("_ens") else None)
            settings["checkpoint"] = solver.source
            settings["checkpoint_step"] = solver.meta.get("step")
            if not name.startswith("smplik_net"):
                settings["refine"] = solver.refine.to_dict()
            if name.endswith("_ens"):
                settings["ensemble"] = ensemble.to_dict()
        elif name == "optim":
            optim = OptimizationIK(bodies, PosePrior.fit(train_pose), iterations=optim_iterations)
            methods[name] = optim
            settings["optim"] = {k: v for k, v in vars(optim).items() if isinstance(v, (int, float))}
        elif name == "nn":
            nn = NearestNeighborMethod.from_dataset(train_pose, bodies, max_samples=nn_samples)
            methods[name] = nn
            settings["nn_samples"] = int(nn.R_local.shape[0])
        else:
            methods[name] = RestPoseMethod(bodies)
    return methods, settings


def _mean_metrics(items: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Unweighted mean of each metric over ``items`` (None where no item has it); summed sample counts."""
    out: dict[str, Any] = {}
    for key in METRIC_KEYS:
        vals = [m[key] for m in items if m.get(key) is not None]
        out[key] = float(np.mean(vals)) if vals else None
    out["samples"] = int(sum(m["samples"] for m in items))
    return out


def _per_subject(errors: SampleErrors, subjects: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Metrics pooled over each subject's samples, subjects sorted by name."""
    labels = np.asarray(subjects)
    return {s: errors.select(torch.from_numpy(labels == s)).summary() for s in sorted(set(subjects))}


def run_benchmark(bench: Benchmark, methods: Mapping[str, Method], bodies: BodyModelSet, *,
                  settings: Mapping[str, Any] | None = None, subjects: Mapping[str, Sequence[str]] | None = None,
                  progress: Callable[[str, str, SetMetrics], None] | None = None) -> dict[str, Any]:
    """Evaluate each method on every set; returns the results document (JSON-ready).

    ``results["methods"][name]["sets"][set_name]`` holds :class:`SetMetrics` fields and
    ``results["methods"][name]["random_mean"]`` their mean over the random N = 6..12 sets.

    With ``subjects`` (set name -> each sample's subject, :func:`sample_subjects`),
    ``results["methods"][name]["subjects"][subject]`` holds the metrics (no time) pooled over that
    subject's samples of the random sets, ``results["methods"][name]["subject_mean"]`` their
    unweighted mean over subjects, and ``results["subjects"]`` each subject's sample count.
    """
    if bench.manifest.get("body_fingerprint") not in (None, bodies.fingerprint):
        raise ValueError(f"{bench.folder}: the benchmark was made with body models "
                         f"{bench.manifest['body_fingerprint']}, the models in use are {bodies.fingerprint}; "
                         "re-create the files or pass the same --model-dir.")
    randoms = [s for s in bench.sets if s.kind == "random"]
    results: dict[str, Any] = {
        "format": RESULTS_FORMAT,
        "version": RESULTS_VERSION,
        "benchmark": {"files": bench.folder, "seed": bench.manifest["seed"], "version": bench.manifest["version"],
                      "source": bench.manifest["source"], "samples_per_count": bench.manifest["samples_per_count"]},
        "settings": dict(settings or {}) | {"torch_threads": torch.get_num_threads()},
        "methods": {},
    }
    random_subjects: list[str] = []
    if subjects is not None:
        for bset in randoms:
            if len(subjects[bset.name]) != len(bset):
                raise ValueError(f"{bench.folder}: {len(subjects[bset.name])} subject labels for the "
                                 f"{len(bset)} samples of set {bset.name}.")
            random_subjects += subjects[bset.name]
        results["subjects"] = {s: random_subjects.count(s) for s in sorted(set(random_subjects))}
    for name, method in methods.items():
        per_set: dict[str, Any] = {}
        random_errors: list[SampleErrors] = []
        for bset in bench.sets:
            t0 = time.perf_counter()
            pred = method(bset)
            seconds = time.perf_counter() - t0
            errors = sample_errors(bset, pred, bodies)
            m = SetMetrics(**errors.summary(), time_ms_per_pose=seconds * 1000.0 / max(len(bset), 1))
            per_set[bset.name] = m.to_dict()
            if bset.kind == "random":
                random_errors.append(errors)
            if progress is not None:
                progress(name, bset.name, m)
        entry: dict[str, Any] = {"description": METHOD_DESCRIPTIONS.get(name, name), "sets": per_set,
                                 "random_mean": _mean_metrics([per_set[s.name] for s in randoms]) if randoms else None}
        if subjects is not None and random_errors:
            by_subject = _per_subject(SampleErrors.concat(random_errors), random_subjects)
            entry["subjects"] = by_subject
            entry["subject_mean"] = _mean_metrics(list(by_subject.values()))
        results["methods"][name] = entry
    return results


def save_results(path: str | Path, results: Mapping[str, Any]) -> Path:
    """Write the results document as JSON (atomic)."""
    return write_json_atomic(path, results)
