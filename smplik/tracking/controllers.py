"""The tracked VR controllers' wrist offsets (numpy only; read by :mod:`smplik.tracking.io` and
:mod:`smplik.tracking.calibrate`)."""

from __future__ import annotations

import numpy as np

CONTROLLERS: dict[str, tuple[float, float, float]] = {
    "vive": (-0.032, -0.085, 0.133),
    "touch": (-0.032, -0.038, 0.101),
    "index": (-0.025, -0.030, 0.150),
    "none": (0.0, 0.0, 0.0),
}
"""The left wrist joint in its controller's tracked frame (OpenVR axes of the device: +x right, +y up, +z back
toward the user; metres); the right wrist mirrors x. ``vive``: HTC Vive wand; ``touch``: Oculus / Meta Touch;
``index``: Valve Index ("knuckles"); ``none``: the controller's position is the wrist. The Vive and Touch values
are the hand-model offsets commonly used in Unity projects (hand root 3 cm to the outer side, 8.5 / 3.8 cm down
and 13.3 / 10.1 cm behind the controller's origin, mirrored to OpenVR's right-handed axes); the Index value puts
the wrist 2 cm behind Monado's Index grip pose (0, -1.5, 13 cm): estimates within a few centimetres, not
measurements of one hand."""


class ControllerError(ValueError):
    """An unknown controller name (one line naming the choices)."""


def controller_offset(controller: str, side: str) -> np.ndarray:
    """(3,) the ``side`` ("left"/"right") wrist in the controller's frame (:data:`CONTROLLERS`)."""
    if controller not in CONTROLLERS:
        raise ControllerError(f"unknown controller {controller!r}; choose from {', '.join(CONTROLLERS)}.")
    off = np.asarray(CONTROLLERS[controller], dtype=np.float64)
    return off if side == "left" else off * np.array([-1.0, 1.0, 1.0])
