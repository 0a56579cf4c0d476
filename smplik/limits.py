"""Size limits of the readers that the command line also shows as option defaults (no heavy imports:
``--help`` reads them)."""

from __future__ import annotations

DEFAULT_MAX_JOINTS = 10_000
"""Joint cap of the skeleton readers (:func:`smplik.data.bvh.read_bvh`, glTF and joints JSON; real rigs
have < 500; raise it with ``max_joints`` / ``--max-joints``)."""
