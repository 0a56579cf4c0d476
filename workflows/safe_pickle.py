"""Pickle and ``.npz`` loading for estimator outputs: the project's one restricted unpickler lives in
:mod:`smplik.safe_pickle` (shared with SMPL ``.pkl`` model files); this module re-exports it for the
estimator readers."""

from __future__ import annotations

from smplik.safe_pickle import (
    TRUST_HINT,
    RestrictedUnpickler,
    UnsafePickleError,
    allowed_global,
    load_pickle,
    read_npy,
    read_npz,
)

__all__ = ["TRUST_HINT", "RestrictedUnpickler", "UnsafePickleError", "allowed_global", "load_npz", "load_pickle",
           "read_npy"]

load_npz = read_npz
"""Every array of an estimator ``.npz``; object arrays through the restricted unpickler."""
