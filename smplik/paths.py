"""Where smplik looks for data and writes generated files: every default path and its environment variable.

* ``SMPLIK_SHARED_DIR``: the shared folder (``data/cmu``, ``data/custom-characters``); default
  ``<repo>/../shared`` when it is a folder.
* ``SMPLIK_CMU_DIR``: CMU BVH clips and their ``split.json``; default ``<shared>/data/cmu`` when it is a folder.
* ``SMPLIK_CACHE_DIR``: generated files (built-in body model, SMPL-SI sample banks, the benchmark
  scripts' pose cache and benchmark files); default ``$XDG_CACHE_HOME/smplik``, else ``~/.cache/smplik``.
* ``SMPLIK_POSE_CACHE``: the pose cache the benchmark scripts read; default ``<cache>/cmu30.npz``.
* ``SMPLIK_REAL_ESTIMATORS`` / ``SMPLIK_RIG_CORPUS``: third-party files whose licences keep them out of the
  repository (real estimator outputs; real rigs), read by the benchmark scripts when present; default
  ``<cache>/real/estimators`` and ``<cache>/real/rigs``.

(``SMPLIK_MODEL_DIR``, real SMPL files, is read by :func:`smplik.body_model.resolve_model_dir`.)
An empty variable counts as unset. Nothing here creates a folder; no default is an absolute path
of one machine: ``<repo>`` is the folder holding the ``smplik`` package.
"""

from __future__ import annotations

import os
from pathlib import Path

SHARED_DIR_ENV = "SMPLIK_SHARED_DIR"
CMU_DIR_ENV = "SMPLIK_CMU_DIR"
CACHE_DIR_ENV = "SMPLIK_CACHE_DIR"
POSE_CACHE_ENV = "SMPLIK_POSE_CACHE"
REAL_ESTIMATORS_ENV = "SMPLIK_REAL_ESTIMATORS"
RIG_CORPUS_ENV = "SMPLIK_RIG_CORPUS"
POSE_CACHE_NAME = "cmu30.npz"
"""File name of the default pose cache (the README's ``smplik data build`` recipe, 30 fps CMU)."""


def _env(name: str) -> Path | None:
    value = os.environ.get(name, "")
    return Path(value).expanduser() if value else None


def repo_root() -> Path:
    """The folder holding the ``smplik`` package (the repository root for a source checkout)."""
    return Path(__file__).resolve().parents[1]


def shared_dir() -> Path | None:
    """``$SMPLIK_SHARED_DIR`` (returned even when missing, so errors can name it), else ``<repo>/../shared``
    when it is a folder, else None."""
    env = _env(SHARED_DIR_ENV)
    if env is not None:
        return env
    default = repo_root().parent / "shared"
    return default if default.is_dir() else None


def cmu_dir() -> Path | None:
    """``$SMPLIK_CMU_DIR`` (returned even when missing), else ``<shared>/data/cmu`` when it is a folder, else None."""
    env = _env(CMU_DIR_ENV)
    if env is not None:
        return env
    shared = shared_dir()
    default = shared / "data" / "cmu" if shared is not None else None
    return default if default is not None and default.is_dir() else None


def cache_dir(override: str | Path | None = None) -> Path:
    """``override``, else ``$SMPLIK_CACHE_DIR``, else ``$XDG_CACHE_HOME/smplik``, else ``~/.cache/smplik``."""
    if override is not None and str(override) != "":
        return Path(override).expanduser()
    env = _env(CACHE_DIR_ENV)
    if env is not None:
        return env
    xdg = _env("XDG_CACHE_HOME")
    return (xdg if xdg is not None else Path.home() / ".cache") / "smplik"


def pose_cache() -> Path:
    """``$SMPLIK_POSE_CACHE``, else ``<cache_dir()>/cmu30.npz``."""
    return _env(POSE_CACHE_ENV) or cache_dir() / POSE_CACHE_NAME


def real_estimators_dir() -> Path:
    """``$SMPLIK_REAL_ESTIMATORS``, else ``<cache_dir()>/real/estimators`` (real estimator outputs kept locally)."""
    return _env(REAL_ESTIMATORS_ENV) or cache_dir() / "real" / "estimators"


def rig_corpus_dir() -> Path:
    """``$SMPLIK_RIG_CORPUS``, else ``<cache_dir()>/real/rigs`` (real rigs kept locally)."""
    return _env(RIG_CORPUS_ENV) or cache_dir() / "real" / "rigs"


def benchmark_files_dir(split: str, seed: int, samples_per_count: int) -> Path:
    """Default folder of the scripts' benchmark files: ``<cache_dir()>/benchmark/<split>-seed<seed>-n<S>``."""
    return cache_dir() / "benchmark" / f"{split}-seed{seed}-n{samples_per_count}"


def missing_cmu_reason() -> str:
    """One line saying why no CMU folder is available and how to provide one."""
    where = cmu_dir()
    if where is not None:
        return f"CMU BVH folder {where} not found (${CMU_DIR_ENV})."
    return (f"no CMU BVH folder: set ${CMU_DIR_ENV} or place the shared folder at {repo_root().parent / 'shared'} "
            f"(or set ${SHARED_DIR_ENV}).")
