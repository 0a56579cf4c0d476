"""The edit benchmark, in one place: single-limb edits from real motion, every method side by side.

* :mod:`workflows.edit_benchmark.pairs`: edit pairs (frames ``t0 -> t1`` where one wrist or ankle moved) and the
  metrics per pair;
* :mod:`workflows.edit_benchmark.run`: the runner (recover ``t0``'s scene, drag, solve with each method, compare);
* the command ``smplik benchmark edits`` (:mod:`workflows.benchmark_cli`) and the script
  ``benchmarks/edit_benchmark.py`` that writes ``benchmarks/results/edit_benchmark.json``.
"""
