"""IK accuracy benchmark: make the files (if absent) and run all methods; results in benchmarks/results.

``python benchmarks/ik_benchmark.py [--data CACHE] [--files DIR] [--checkpoint FILE]`` is the same
as ``smplik benchmark make`` followed by ``smplik benchmark run --methods smplik,optim,nn,rest``,
plus the per-subject results of the split (each subject's samples of the random N = 6..12 sets,
and the mean over subjects). It writes ``<results>/<name>.json`` and ``<name>.md`` (``--results``, default
``benchmarks/results``; ``--name``, default ``ik_benchmark``: the README table).

Defaults (:mod:`smplik.paths`): ``--data`` is ``$SMPLIK_POSE_CACHE``, else ``<cache>/cmu30.npz``
(``$SMPLIK_CACHE_DIR``, else ``~/.cache/smplik``); ``--files`` is
``<cache>/benchmark/<split>-seed<seed>-n<samples>``. ``--max-samples`` evaluates only the first
samples of every set (a reduced run that shows the report quickly).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS, machine  # noqa: E402

from smplik.atomic import write_text_atomic  # noqa: E402
from smplik.benchmark import (  # noqa: E402
    LEARNED_METHODS,
    MANIFEST,
    Benchmark,
    build_methods,
    load_benchmark,
    make_benchmark,
    results_markdown,
    run_benchmark,
    sample_subjects,
    save_results,
)
from smplik.body_model import BodyModelSet  # noqa: E402
from smplik.data.dataset import load_cache  # noqa: E402
from smplik.paths import POSE_CACHE_ENV, benchmark_files_dir, pose_cache  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402

METHODS = ("smplik", "smplik_net", "smplik_ens", "smplik_net_ens", "optim", "nn", "rest")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="Pose cache (test split + train split).")
    parser.add_argument("--files", type=Path, default=None, help="Benchmark folder (made if absent).")
    parser.add_argument("--checkpoint", default=None, help="Model file (default: the packaged model).")
    parser.add_argument("--split", default="test", help="Split the files are made from.")
    parser.add_argument("--samples-per-count", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--methods", default=",".join(METHODS), help="Comma-separated methods.")
    parser.add_argument("--optim-iterations", type=int, default=200)
    parser.add_argument("--max-samples", type=int, default=None, help="Evaluate the first N samples of each set.")
    parser.add_argument("--name", default="ik_benchmark", help="Result file name (without suffix).")
    parser.add_argument("--results", type=Path, default=RESULTS, help="Result folder (default benchmarks/results).")
    args = parser.parse_args(argv)

    data = args.data or pose_cache()
    if not data.is_file():
        print(f"error: no pose cache at {data}: build one with `smplik data build` (README) and pass --data "
              f"or set ${POSE_CACHE_ENV}.", file=sys.stderr)
        return 1
    files = args.files or benchmark_files_dir(args.split, args.seed, args.samples_per_count)
    torch.set_num_threads(args.threads)
    bodies = BodyModelSet.load()
    stale = args.files is None and (files / MANIFEST).is_file() and json.loads(
        (files / MANIFEST).read_text(encoding="utf-8")).get("body_fingerprint") != bodies.fingerprint
    if stale or not (files / MANIFEST).is_file():  # the default cache folder is remade for other body models
        make_benchmark(data, files, split=args.split, seed=args.seed, samples_per_count=args.samples_per_count)
    bench = load_benchmark(files)
    if args.max_samples is not None:
        bench = Benchmark(bench.manifest, tuple(s.head(args.max_samples) for s in bench.sets), bench.folder)
    dataset = load_cache(data)
    names = [m.strip() for m in args.methods.split(",") if m.strip()]
    solver = IKSolver.load(args.checkpoint) if set(LEARNED_METHODS) & set(names) else None
    methods, settings = build_methods(names, bodies, solver=solver, train_pose=dataset.subset("train").pose,
                                      optim_iterations=args.optim_iterations)
    settings |= {"machine": machine(), "train_data": str(data), "max_samples": args.max_samples}
    results = run_benchmark(bench, methods, bodies, settings=settings, subjects=sample_subjects(bench, dataset),
                            progress=lambda m, s, r: print(f"{m:7s} {s:10s} {r.mpjpe_mm:7.1f} mm", flush=True))
    save_results(args.results / f"{args.name}.json", results)
    table = results_markdown(results)
    write_text_atomic(args.results / f"{args.name}.md", table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
