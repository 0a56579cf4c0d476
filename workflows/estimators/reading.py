"""Reading an estimator output: load a file safely, detect its format, dispatch to its reader; folders of
per-frame outputs read as clips. The package docstring (:mod:`workflows.estimators`) says what it returns."""

from __future__ import annotations

import dataclasses
import json
import lzma
import pickle
import re
import struct
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from workflows.estimators import (
    agora,
    aist,
    amass_params,
    easymocap,
    glamr,
    gvhmr,
    humandata,
    hybrik,
    phalp,
    plain,
    pose_array,
    pymafx,
    romp,
    sam3d,
    smplerx,
    smplifyx,
    tram,
    vibe,
    wham,
)
from workflows.estimators.base import (
    M_WORLD_CAMERA,
    MAX_PEOPLE,
    CameraInfo,
    EstimatedPerson,
    EstimateFormatError,
    camera_to_world,
    check_people,
)

FormatName = Literal["auto", "romp", "bev", "hybrik", "phalp", "wham", "pymafx", "vibe", "gvhmr", "glamr", "aist",
                     "amass", "sam3d", "easymocap", "tram", "smplerx", "agora", "humandata", "smplifyx", "plain",
                     "pose_array"]
FORMATS: tuple[str, ...] = ("romp", "bev", "hybrik", "phalp", "wham", "pymafx", "vibe", "gvhmr", "glamr", "aist",
                            "amass", "sam3d", "easymocap", "tram", "smplerx", "agora", "humandata", "smplifyx", "plain",
                            "pose_array")
_MODULES = {"romp": romp, "bev": romp, "hybrik": hybrik, "phalp": phalp, "wham": wham, "pymafx": pymafx, "vibe": vibe,
            "gvhmr": gvhmr, "glamr": glamr, "aist": aist, "amass": amass_params, "sam3d": sam3d, "easymocap": easymocap,
            "tram": tram, "smplerx": smplerx, "agora": agora, "humandata": humandata, "smplifyx": smplifyx,
            "plain": plain, "pose_array": pose_array}
_DETECT_ORDER = (romp, hybrik, gvhmr, glamr, aist, sam3d, humandata, phalp, wham, pymafx, vibe, amass_params, easymocap,
                 tram, agora, smplifyx, smplerx, plain, pose_array)
_PATH_READERS = (amass_params, tram, smplerx, agora)
"""Readers that need the file's path (sibling files: other tracks or people, the camera or meta file)."""
SIGNATURES: dict[str, tuple[str, ...]] = {
    "romp": ("smpl_thetas", "smpl_betas", "cam_trans"), "hybrik": ("pred_thetas", "pred_betas", "transl"),
    "phalp": ("smpl", "camera"), "wham": ("pose", "trans", "betas"), "pymafx": ("pose", "betas", "orig_cam_t"),
    "vibe": ("pose", "betas", "orig_cam", "frame_ids"),
    "gvhmr": ("smpl_params_incam", "smpl_params_global", "K_fullimg"), "glamr": ("person_data", "cam_pose"),
    "aist": ("smpl_poses", "smpl_trans", "smpl_scaling"), "amass": ("poses", "trans", "betas"),
    "sam3d": ("pred_joint_coords", "pred_cam_t"), "easymocap": ("id", "Rh", "Th", "poses", "shapes"),
    "tram": ("pred_rotmat", "pred_trans", "pred_shape", "frame"), "smplerx": smplerx.KEYS,
    "agora": ("params", "pose2rot", "joints"), "humandata": ("smpl", "__data_len__", "image_path"),
    "smplifyx": ("camera_translation", "global_orient", "body_pose", "betas"),
    "plain": ("global_orient", "body_pose", "transl", "betas")}
"""The keys that identify each format (in a person's record for per-person layouts), for the closest-format hint."""
SUFFIXES = (".npz", ".npy", ".json", ".pk", ".pkl", ".pickle", ".joblib", ".pt", ".pth")
MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl")
MESH_HINT = ("a mesh holds no SMPL parameters (CameraHMR's and TokenHMR's demo.py and Multi-HMR's --save_mesh write "
             "only meshes); run the estimator's parameter output instead (TokenHMR: track.py writes a PHALP .pkl, "
             "read as phalp), see docs/estimators.md.")
MESH_VERTICES = {6890: "SMPL", 10475: "SMPL-X"}
"""Vertex counts of the body meshes some demos save as bare arrays (Multi-HMR ``demo.py --save_mesh``: SMPL-X)."""
MAX_BYTES = 1 << 30
"""Default cap (1 GiB) on the uncompressed size of an estimator file's data."""

__all__ = ["M_WORLD_CAMERA", "MAX_BYTES", "MAX_PEOPLE", "CameraInfo", "EstimatedPerson", "EstimateFormatError",
           "FORMATS", "camera_to_world", "closest_format", "detect_format", "read_estimate"]


def _check_zip(path: Path, max_bytes: int) -> None:
    """Refuse a zip (npz / torch) whose members declare more than ``max_bytes`` uncompressed."""
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, NotImplementedError) as exc:
        raise EstimateFormatError(f"{path}: not a readable zip archive ({type(exc).__name__}: {exc}).") from None
    if len(infos) > 10_000:
        raise EstimateFormatError(f"{path}: {len(infos)} archive members; refusing more than 10000.")
    total = sum(i.file_size for i in infos)
    if total > max_bytes:
        big = max(infos, key=lambda i: i.file_size)
        raise EstimateFormatError(f"{path}: its arrays would take {total / 2**20:.0f} MiB uncompressed "
                                  f"('{big.filename}' {big.file_size / 2**20:.0f} MiB), over the "
                                  f"{max_bytes / 2**20:.0f} MiB limit (max_bytes / --max-bytes raises it).")


def _to_numpy(value: Any, depth: int = 0) -> Any:
    import torch

    if depth > 20:
        raise EstimateFormatError("nesting deeper than 20 levels.")
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().double().numpy() if value.is_floating_point() else value.cpu().numpy()
    if isinstance(value, dict):
        return {k: _to_numpy(v, depth + 1) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_to_numpy(v, depth + 1) for v in value]
    return value


def _load_torch(path: Path) -> Any:
    from smplik.model_io import read_torch_file

    # the one .pt reader: zip directory checked before torch reads anything, weights_only, and every tensor's
    # logical size (a stride-0 view expands to its full shape; .double() makes every float tensor real) before
    # .numpy(); estimator outputs may hold views, so their layout is not required to be contiguous
    data = read_torch_file(path, what="tensor file", error=EstimateFormatError, layout=False, as_itemsize=8,
                           hint="torch.load with weights_only=True refused it, so nothing in it ran")
    return _to_numpy(data)


def _load_raw(path: Path, trust_pickle: bool, max_bytes: int) -> Any:
    from smplik.safe_pickle import UnsafePickleError, load_pickle, read_npy, read_npz

    suffix = path.suffix.lower()
    if suffix in MESH_SUFFIXES:
        raise EstimateFormatError(f"{path}: {MESH_HINT}")
    if suffix not in SUFFIXES:
        raise EstimateFormatError(f"{path}: unsupported file type {suffix!r} (expected {', '.join(SUFFIXES)}).")
    from smplik.limits import JSON_BYTES, check_input_file, read_bounded

    size = check_input_file(path, "estimator output")  # a pipe or a device is refused; the size read through links
    if suffix in (".npz", ".pt", ".pth"):
        _check_zip(path, max_bytes)
    elif size > max_bytes:
        raise EstimateFormatError(f"{path}: {size / 2**20:.0f} MiB is over the "
                                  f"{max_bytes / 2**20:.0f} MiB limit (max_bytes / --max-bytes raises it).")
    try:
        if suffix == ".npz":
            return read_npz(path)
        if suffix in (".pt", ".pth"):
            return _load_torch(path)
        if suffix == ".npy":  # an object array (a saved dict, e.g. TRAM's) through the restricted unpickler
            return read_npy(path)
        if suffix == ".json":
            try:
                return json.loads(read_bounded(path, JSON_BYTES).decode("utf-8"))
            except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
                raise EstimateFormatError(f"{path}: cannot read JSON ({type(exc).__name__}: "
                                          f"{str(exc)[:200]}).") from None
        return load_pickle(path, trust_pickle=trust_pickle)
    except UnsafePickleError as exc:  # keep the class; one line even when the file's global names hold newlines
        raise UnsafePickleError(" ".join(str(exc).split())) from None
    except EstimateFormatError:
        raise
    except (ValueError, OSError, RecursionError, MemoryError, EOFError, KeyError, IndexError, TypeError,
            AttributeError, OverflowError, NotImplementedError, UnicodeDecodeError, zlib.error, lzma.LZMAError,
            struct.error, zipfile.BadZipFile, pickle.UnpicklingError, SystemError) as exc:
        # a corrupt file: the loaders (zip, numpy, joblib, pickle) fail in many ways, all of them the file's fault
        message = " ".join(str(exc).split())[:300]
        raise EstimateFormatError(message if str(path) in message else f"{path}: {message}") from None


def _describe(data: Any) -> str:
    if isinstance(data, dict):
        keys = [str(k) for k in list(data)[:20]]
        more = f", ... ({len(data)} keys)" if len(data) > 20 else ""
        return f"top-level keys: {', '.join(keys) or 'none'}{more}"
    if isinstance(data, list):
        return f"a list of {len(data)} items"
    return f"a {type(data).__name__}"


def detect_format(data: Any) -> str:
    """The format whose layout ``data`` (a loaded file) matches, or :class:`EstimateFormatError`."""
    for module in _DETECT_ORDER:
        if module.matches(data):
            return module.FORMAT
    raise EstimateFormatError(f"Cannot detect the estimator format ({_describe(data)}); {closest_format(data)}")


def _record_keys(data: Any) -> set[str]:
    """The keys of the top level, of a list's first record, and of a dict's first value (per-person layouts)."""
    keys: set[str] = set()
    if isinstance(data, dict):
        keys |= {str(k) for k in data}
        first = next(iter(data.values()), None)
        if isinstance(first, dict):
            keys |= {str(k) for k in first}
    elif isinstance(data, list) and data and isinstance(data[0], dict):
        keys |= {str(k) for k in data[0]}
    return keys


def closest_format(data: Any) -> str:
    """One sentence naming the format whose identifying keys (:data:`SIGNATURES`) ``data`` shares most, and
    the keys it lacks; or, sharing none, the formats known."""
    if isinstance(data, np.ndarray) and data.ndim >= 2 and data.shape[-1] == 3 and data.shape[-2] in MESH_VERTICES:
        return (f"an array of shape {data.shape} holds {MESH_VERTICES[data.shape[-2]]} mesh vertices: {MESH_HINT}")
    if isinstance(data, np.ndarray) and data.ndim in (3, 4) and data.shape[-2:] == (22, 3):
        return (f"an array of shape {data.shape} holds joint positions (HumanML3D's 22 SMPL joints): "
                "`smplik scene animate FILE` fits SMPL to them (docs/animation.md).")
    if isinstance(data, np.ndarray) and data.ndim == 2 and data.shape[1] == 263:
        return (f"an array of shape {data.shape} holds HumanML3D features: `smplik scene animate FILE` (with "
                "--mean/--std when normalised) recovers their joints and fits SMPL to them (docs/animation.md).")
    if isinstance(data, np.ndarray):
        return (f"an array of shape {data.shape}: the pose_array format needs (T, 72 | 156 | 165) floats "
                f"(axis-angle, root first).")
    keys = _record_keys(data)
    candidates = dict(SIGNATURES)
    if isinstance(data, dict) and isinstance(data.get("smpl"), dict):  # PHALP's 'smpl' is per-frame lists, not a
        candidates.pop("phalp")  # dict of arrays (mmhuman3d HumanData's)
    scored = [(len(keys & set(sig)), len(keys & set(sig)) / len(sig), name) for name, sig in candidates.items()]
    shared, share, name = max(scored, key=lambda t: (t[0], t[1]))
    if shared == 0:
        return f"no known layout shares its keys (known formats: {', '.join(FORMATS)})."
    lacks = [k for k in SIGNATURES[name] if k not in keys]
    if not lacks:  # every key is there, in a nested record: the reader's own checks name what is wrong
        holder = _holder(data, SIGNATURES[name])
        where = f" (inside {holder!r})" if holder else ""
        return (f"closest: {name}, whose keys {', '.join(repr(k) for k in SIGNATURES[name])} are here{where} but "
                f"not in its layout; try --format {name} to see what its reader needs.")
    return f"closest: {name}, which also needs {', '.join(repr(k) for k in lacks)}."


def _holder(data: Any, signature: tuple[str, ...]) -> str | None:
    """The key of the nested record holding ``signature``'s keys, None when they are at the top level."""
    if isinstance(data, dict) and all(k in data for k in signature):
        return None
    if isinstance(data, dict):
        for k, v in data.items():
            if isinstance(v, dict) and all(s in v for s in signature):
                return str(k)
    return None


def read_estimate(path: str | Path, *, format: FormatName = "auto", trust_pickle: bool = False,
                  frame: int = 0, max_people: int = MAX_PEOPLE, max_bytes: int = MAX_BYTES,
                  space: Literal["camera", "world"] | None = None, solver: Any = None) -> list[EstimatedPerson]:
    """Read the people of one frame of an estimator output file, placed on our body in the y-up world.

    Args:
        path: the results file (.npz, .json, .pk/.pkl/.joblib, .pt/.pth), or a folder of per-frame outputs
            (:func:`scan_folder`: SMPLer-X's output folder, one file per frame of any reader).
        format: one of :data:`FORMATS` or ``"auto"`` (detect from the content).
        trust_pickle: load pickles with plain joblib/pickle (runs code from the file).
        frame: which video frame (default 0); single-image formats accept only 0. People are keyed
            by the estimator's track id (``person_id``).
        max_people: refuse more people than this in the frame.
        max_bytes: refuse files whose (uncompressed) data is larger.
        space: for WHAM, GVHMR, GLAMR and TRAM, ``"camera"`` or ``"world"`` output (default: WHAM and GLAMR world,
            GVHMR and TRAM camera).
        solver: for SAM-3D-Body (not SMPL), the :class:`smplik.solver.IKSolver` that fits the SMPL pose
            (default: the shipped model).

    Raises:
        EstimateFormatError: unknown format, a layout mismatch (naming the key), a limit exceeded.
        smplik.safe_pickle.UnsafePickleError: a pickle names a refused global.
    """
    path = Path(path)
    if not path.is_file() and not path.is_dir():
        raise EstimateFormatError(f"Estimator output not found: {path}")
    if format != "auto" and format not in _MODULES:
        raise EstimateFormatError(f"Unknown format {format!r}; expected auto or one of {', '.join(FORMATS)}.")
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or frame < 0:
        raise EstimateFormatError(f"--frame must be a non-negative integer, got {frame!r}.")
    if max_people < 1:
        raise EstimateFormatError(f"--max-people must be >= 1, got {max_people}.")
    if path.is_dir():  # per-frame outputs (scan_folder, below): frame N of the folder's clip
        import warnings

        folder = scan_folder(path, format=format, trust_pickle=trust_pickle, max_bytes=max_bytes)
        people = read_folder_frame(folder, frame, trust_pickle=trust_pickle, max_people=max_people,
                                   max_bytes=max_bytes, space=space, solver=solver)
        if not people:
            raise EstimateFormatError(f"{folder.describe(frame)}: no people in this frame (choose another --frame).")
        warnings.warn(folder.describe(frame), pose_array.EstimateNote, stacklevel=2)
        return people
    data = _load_raw(path, trust_pickle, max_bytes)
    return people_from_data(data, source=str(path), format=format, frame=frame, max_people=max_people, space=space,
                            path=path, solver=solver)


def people_from_data(data: Any, *, source: str, format: FormatName = "auto", frame: int = 0,
                     max_people: int = MAX_PEOPLE, space: Literal["camera", "world"] | None = None,
                     path: Path | None = None, solver: Any = None) -> list[EstimatedPerson]:
    """:func:`read_estimate` on already loaded data (``path`` is needed for the AMASS reader only)."""
    name = detect_format(data) if format == "auto" else format
    module = _MODULES[name]
    kwargs: dict[str, Any] = {"frame": int(frame), "max_people": max_people}
    if space is not None and module in (wham, gvhmr, glamr, tram):
        kwargs["space"] = space
    if solver is not None and module is sam3d:
        kwargs["solver"] = solver
    try:
        if module in _PATH_READERS:
            if path is None:
                raise EstimateFormatError(f"{source}: the {name} reader reads files only.")
            people = module.read(path, data, **kwargs)
        else:
            people = module.from_data(data, source=source, **kwargs)
    except EstimateFormatError:
        raise
    except (TypeError, ValueError, IndexError, KeyError, AttributeError, OverflowError, RecursionError) as exc:
        # A layout the reader's own checks did not anticipate: still one clear line, never a traceback.
        message = " ".join(str(exc).split())[:200]
        raise EstimateFormatError(f"{source}: does not have the {name} layout ({type(exc).__name__}: "
                                  f"{message}).") from None
    if not people:
        raise EstimateFormatError(f"{source}: no people found.")
    check_people(people, source)
    return people


# ----------------------------------------------------------------------------- folders of per-frame outputs
# A folder of per-frame estimator outputs, read as a clip: ``scene animate DIR``, ``scene from-estimate DIR
# --frame N``.
#
# Layouts (:func:`scan_folder`):
#
# * **SMPLer-X** (github.com/caizhongang/SMPLer-X, ``main/inference.py`` ``main``): ``--output_folder`` holds
#   ``smplx/{frame:05}_{bbox_id}.npz`` (``np.savez(npz_path, **smplx_pred)``, one person of one frame) and
#   ``meta/{frame:05}_{bbox_id}.json`` (the person's crop camera), for ``frame`` in ``range(start, end)`` over the
#   images ``{img_path}/{frame:06d}.jpg`` (``--start`` default 1), plus ``img/{frame:06d}.jpg``, the rendered
#   image of **every** processed frame (a frame where nobody was detected has an image and no npz). ``bbox_id``
#   numbers the detections of one frame (it is not a track id). DIR is that output folder or its ``smplx``
#   folder; each frame is read by :mod:`workflows.estimators.smplerx`.
# * **Any reader whose files hold one frame each** (plain SMPL npz/JSON, ROMP/BEV image npz, HybrIK, ...): the
#   files of one format in DIR. Names ``<frame>`` or ``<frame>_<person>`` (digits) give the frame number; else
#   the files are frames in name order.
#
# Frame numbers: clip frame 0 is the first frame number (SMPLer-X: the lowest of ``img/`` when present, so that
# leading frames without people still count, and clip frame k is the k-th source image), clip frame k is frame
# number first + k; a number without files is a frame without people.
#
# Tracks (:func:`match_tracks`): per-frame outputs carry no track ids, so people are linked across consecutive
# frames by their pelvis positions (one-to-one, nearest first: :func:`scipy.optimize.linear_sum_assignment`);
# a person further than :data:`MAX_STEP_M` from every person of the previous frame starts a new track. For people in
# a camera frame the distance counts the step along the line of sight at :data:`DEPTH_WEIGHT` (:func:`step_m`): a
# monocular depth jumps with the detection box (SMPLer-X's crop camera scales with the box, so a box 12 % taller
# moves a person 5 m away by 0.6 m in depth while it stays on the same pixels). Every frame
# is moved into the clip's camera (the first person's of the first frame) when the frames' cameras differ
# (SMPLer-X's crop cameras): the pelvis keeps its pixel and apparent size (:func:`workflows.estimators.smplerx.
# move_to_camera`).

MAX_STEP_M = 0.5
"""Farthest (metres) a person's pelvis may move between consecutive frames and stay the same track."""
DEPTH_WEIGHT = 0.25
"""Weight of the step along the camera's line of sight in :func:`step_m` (monocular depth is about four times
noisier than the image axes)."""
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


def step_m(a: EstimatedPerson, pa: np.ndarray, pb: np.ndarray) -> float:
    """How far a pelvis moved from ``pa`` to ``pb`` (3,) for track linking: in a camera frame (``a.camera`` set; the
    camera at the origin) the step along ``pa``'s line of sight counts at :data:`DEPTH_WEIGHT`; else the distance."""
    d = pb - pa
    if a.camera is None or not np.linalg.norm(pa) > 1e-9:
        return float(np.linalg.norm(d))
    ray = pa / np.linalg.norm(pa)
    along = float(d @ ray)
    return float(np.hypot(np.linalg.norm(d - along * ray), DEPTH_WEIGHT * along))


def match_tracks(frames: list[tuple[int, list[EstimatedPerson]]], max_step_m: float = MAX_STEP_M
                 ) -> dict[str, list[tuple[int, EstimatedPerson]]]:
    """Link per-frame people (frames in order) into tracks by nearest pelvis (module docstring); track ids
    ``"0"``, ``"1"``, ... in order of appearance."""
    from scipy.optimize import linear_sum_assignment

    tracks: dict[str, list[tuple[int, EstimatedPerson]]] = {}
    last: dict[str, tuple[int, np.ndarray]] = {}  # track -> (frame, pelvis) of its latest person
    person: dict[str, EstimatedPerson] = {}
    for f, people in frames:
        pelvis = [pelvis_of(p) for p in people]
        live = [t for t, (g, _) in last.items() if g == f - 1]
        taken: dict[int, str] = {}
        if live and people:
            cost = np.array([[step_m(person[t], last[t][1], q) for q in pelvis] for t in live])
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
            person[tid] = p
    return tracks
