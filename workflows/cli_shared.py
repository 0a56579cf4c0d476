"""What the ``smplik`` commands of :mod:`workflows` share (light: no torch at import)."""

from __future__ import annotations

from pathlib import Path

from smplik.cli.errors import user_errors


def _solver(checkpoint: Path | None):
    import torch

    from smplik.solver import IKSolver

    torch.set_num_threads(max(1, min(torch.get_num_threads(), 2)))
    with user_errors():
        return IKSolver.load(checkpoint)
