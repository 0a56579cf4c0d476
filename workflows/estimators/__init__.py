"""Readers for image-to-SMPL estimator outputs, one module per format (see each module's docstring).

:func:`read_estimate` loads the file (never running code from it), picks the reader by ``format``
or detects it from the content, and returns the people of one frame (``frame``, default 0: the one
frame-selection rule of every reader) in smplik's y-up world, placed on our body model
(:mod:`workflows.estimators.base`).

Safety limits: ``.npz`` and ``.pt`` members are checked against ``max_bytes`` (their uncompressed
sizes, read from the zip directory) before anything is decompressed; other files by their size; at
most ``max_people`` people per frame. Every problem raises :class:`EstimateFormatError` (one line,
naming the file and the key) or :class:`smplik.safe_pickle.UnsafePickleError`.
"""

from workflows.estimators.base import CameraInfo, EstimatedPerson, EstimateFormatError
from workflows.estimators.reading import (
    FORMATS,
    MAX_BYTES,
    MAX_PEOPLE,
    MAX_STEP_M,
    SUFFIXES,
    FormatName,
    FrameFolder,
    _load_raw,
    closest_format,
    detect_format,
    match_tracks,
    pelvis_of,
    people_from_data,
    read_estimate,
    read_folder_frame,
    scan_folder,
    to_camera,
)

__all__ = ["FORMATS", "MAX_BYTES", "MAX_PEOPLE", "MAX_STEP_M", "SUFFIXES", "CameraInfo", "EstimateFormatError",
           "EstimatedPerson", "FormatName", "FrameFolder", "_load_raw", "closest_format", "detect_format",
           "match_tracks", "pelvis_of", "people_from_data", "read_estimate", "read_folder_frame", "scan_folder",
           "to_camera"]
