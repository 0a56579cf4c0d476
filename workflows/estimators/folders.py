"""A folder of per-frame estimator outputs, read as a clip: ``scene animate DIR``, ``scene from-estimate DIR
--frame N``.

Layouts (:func:`scan_folder`):

* **SMPLer-X** (github.com/caizhongang/SMPLer-X, ``main/inference.py`` ``main``): ``--output_folder`` holds
  ``smplx/{frame:05}_{bbox_id}.npz`` (``np.savez(npz_path, **smplx_pred)``, one person of one frame) and
  ``meta/{frame:05}_{bbox_id}.json`` (the person's crop camera), for ``frame`` in ``range(start, end)`` over the
  images ``{img_path}/{frame:06d}.jpg`` (``--start`` default 1), plus ``img/{frame:06d}.jpg``, the rendered
  image of **every** processed frame (a frame where nobody was detected has an image and no npz). ``bbox_id``
  numbers the detections of one frame (it is not a track id). DIR is that output folder or its ``smplx``
  folder; each frame is read by :mod:`workflows.estimators.smplerx`.
* **Any reader whose files hold one frame each** (plain SMPL npz/JSON, ROMP/BEV image npz, HybrIK, ...): the
  files of one format in DIR. Names ``<frame>`` or ``<frame>_<person>`` (digits) give the frame number; else
  the files are frames in name order.

Frame numbers: clip frame 0 is the first frame number (SMPLer-X: the lowest of ``img/`` when present, so that
leading frames without people still count, and clip frame k is the k-th source image), clip frame k is frame
number first + k; a number without files is a frame without people.

Tracks (:func:`match_tracks`): per-frame outputs carry no track ids, so people are linked across consecutive
frames by their pelvis positions (one-to-one, nearest first: :func:`scipy.optimize.linear_sum_assignment`);
a person further than :data:`MAX_STEP_M` from every person of the previous frame starts a new track. Every frame
is moved into the clip's camera (the first person's of the first frame) when the frames' cameras differ
(SMPLer-X's crop cameras): the pelvis keeps its pixel and apparent size (:func:`workflows.estimators.smplerx.
move_to_camera`).
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from workflows.estimators.base import M_WORLD_CAMERA, EstimatedPerson, EstimateFormatError

MAX_STEP_M = 0.5
"""Farthest (metres) a person's pelvis may move between consecutive frames and stay the same track."""
MAX_FILES = 1_000_000
"""Most files listed in one folder."""
_NUMBERED = re.compile(r"^(\d+)(?:_(\d+))?$")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


@dataclass(frozen=True)
class FrameFolder:
    """A scanned folder: per clip frame (0..length-1), its files (empty: nobody), and the format."""

    path: Path
    format: str
    first: int
    """The producer's frame number of clip frame 0."""
    files: dict[int, tuple[Path, ...]]
    """Clip frame -> its files (people of that frame), frames without files absent."""
    length: int

    def describe(self, frame: int) -> str:
        names = ", ".join(p.name for p in self.files.get(frame, ())) or "no files (nobody)"
        return (f"{self.path}: a folder of {self.length} per-frame {self.format} outputs (frames 0..{self.length - 1}"
                f"{'' if self.first == 0 else f' = its frame numbers {self.first}..{self.first + self.length - 1}'}"
                f"); frame {frame}: {names}")


def _files_dir(path: Path) -> tuple[Path, bool]:
    """The folder holding the per-frame files, and whether it is SMPLer-X's ``smplx`` folder."""
    if (path / "smplx").is_dir() and any((path / "smplx").glob("*.npz")):
        return path / "smplx", True
    if path.name == "smplx" and (path.parent / "meta").is_dir():
        return path, True
    return path, False


def scan_folder(path: str | Path, *, format: str = "auto", trust_pickle: bool = False,
                max_bytes: int | None = None) -> FrameFolder:
    """The frames of a folder of per-frame outputs (module docstring), the format detected from its first file."""
    from workflows.estimators import MAX_BYTES, SUFFIXES, _load_raw, detect_format

    path = Path(path)
    if not path.is_dir():
        raise EstimateFormatError(f"Estimator output not found: {path}")
    where, smplerx = _files_dir(path)
    listed = []
    for k, p in enumerate(where.iterdir()):
        if k >= MAX_FILES:
            raise EstimateFormatError(f"{where}: more than {MAX_FILES} files; refusing to list more.")
        if p.is_file() and p.suffix.lower() in SUFFIXES and not p.name.startswith("."):
            listed.append(p)
    if smplerx:
        listed = [p for p in listed if p.suffix.lower() == ".npz"]
    if not listed:
        raise EstimateFormatError(f"{path}: no estimator files ({', '.join(SUFFIXES)}) in the folder"
                                  f"{' (smplx/)' if smplerx else ''}.")
    listed.sort(key=lambda p: p.name)
    if smplerx:
        fmt = "smplerx"
    elif format != "auto":
        fmt = format
    else:
        fmt = detect_format(_load_raw(listed[0], trust_pickle, MAX_BYTES if max_bytes is None else max_bytes))
    if fmt in ("gvhmr", "wham", "phalp", "tram", "glamr", "vibe", "aist", "amass") and len(listed) == 1:
        raise EstimateFormatError(f"{path}: a folder with one {fmt} file; pass the file itself ({listed[0]}).")
    named = [_NUMBERED.match(p.stem) for p in listed]
    if all(named):
        numbers = [int(m.group(1)) for m in named if m]
        first = min(numbers)
        if smplerx and (where.parent / "img").is_dir():  # every processed frame has an image, people or not
            shown = [int(m.group(1)) for q in (where.parent / "img").iterdir()
                     if q.suffix.lower() in IMAGE_SUFFIXES and (m := _NUMBERED.match(q.stem))]
            first = min([first, *shown])
        files: dict[int, list[Path]] = {}
        for n, p in zip(numbers, listed, strict=True):
            files.setdefault(n - first, []).append(p)
    else:
        first = 0
        files = {k: [p] for k, p in enumerate(listed)}
    out = {k: tuple(sorted(v, key=lambda p: (int(m.group(2) or 0) if (m := _NUMBERED.match(p.stem)) else 0, p.name)))
           for k, v in files.items()}
    return FrameFolder(path, fmt, first, out, max(out) + 1)


def read_folder_frame(folder: FrameFolder, frame: int, *, trust_pickle: bool = False, max_people: int | None = None,
                      max_bytes: int | None = None, space: str | None = None, solver: Any = None
                      ) -> list[EstimatedPerson]:
    """The people of clip frame ``frame`` (ids ``"0"``, ``"1"``, ... in file order; [] for a frame without files)."""
    from workflows.estimators import MAX_BYTES, MAX_PEOPLE, read_estimate

    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < folder.length:
        raise EstimateFormatError(f"{folder.path}: frame {frame} out of range (0..{folder.length - 1}).")
    files = folder.files.get(int(frame), ())
    if folder.format == "smplerx":
        files = files[:1]  # the SMPLer-X reader reads every person of the frame from the first file's siblings
    people: list[EstimatedPerson] = []
    for f in files:
        people += read_estimate(f, format=folder.format, trust_pickle=trust_pickle, frame=0,  # type: ignore[arg-type]
                                max_people=MAX_PEOPLE if max_people is None else max_people,
                                max_bytes=MAX_BYTES if max_bytes is None else max_bytes, space=space,  # type: ignore[arg-type]
                                solver=solver)
    return [dataclasses.replace(p, person_id=str(i), frame=str(frame)) for i, p in enumerate(people)]


def pelvis_of(person: EstimatedPerson) -> np.ndarray:
    """(3,) the person's posed pelvis in the world (smplx ``transl`` plus our rest pelvis)."""
    from workflows.estimators.base import rest_pelvis

    return person.transl + rest_pelvis(person.betas[None], person.gender)[0]


def to_camera(person: EstimatedPerson, camera) -> EstimatedPerson:  # noqa: ANN001 - CameraInfo
    """``person`` moved into ``camera`` (same pelvis pixel and apparent size) when both cameras have a focal length
    and a principal point and differ; else unchanged."""
    from workflows.estimators.smplerx import move_to_camera

    own = person.camera
    if (own is None or camera is None or own == camera or own.focal_px is None or camera.focal_px is None
            or own.principal_px is None or camera.principal_px is None):
        return person
    pelvis = pelvis_of(person)
    moved = move_to_camera(M_WORLD_CAMERA @ pelvis, (np.full(2, own.focal_px), np.asarray(own.principal_px)),
                           (np.full(2, camera.focal_px), np.asarray(camera.principal_px)))
    return dataclasses.replace(person, transl=person.transl + M_WORLD_CAMERA @ moved - pelvis, camera=camera)


def match_tracks(frames: list[tuple[int, list[EstimatedPerson]]], max_step_m: float = MAX_STEP_M
                 ) -> dict[str, list[tuple[int, EstimatedPerson]]]:
    """Link per-frame people (frames in order) into tracks by nearest pelvis (module docstring); track ids
    ``"0"``, ``"1"``, ... in order of appearance."""
    from scipy.optimize import linear_sum_assignment

    tracks: dict[str, list[tuple[int, EstimatedPerson]]] = {}
    last: dict[str, tuple[int, np.ndarray]] = {}  # track -> (frame, pelvis) of its latest person
    for f, people in frames:
        pelvis = [pelvis_of(p) for p in people]
        live = [t for t, (g, _) in last.items() if g == f - 1]
        taken: dict[int, str] = {}
        if live and people:
            cost = np.array([[np.linalg.norm(last[t][1] - q) for q in pelvis] for t in live])
            for r, c in zip(*linear_sum_assignment(cost), strict=True):
                if cost[r, c] <= max_step_m:
                    taken[int(c)] = live[int(r)]
        for i, p in enumerate(people):
            tid = taken.get(i)
            if tid is None:
                tid = str(len(tracks))
                tracks[tid] = []
            tracks[tid].append((f, dataclasses.replace(p, person_id=tid)))
            last[tid] = (f, pelvis[i])
    return tracks
