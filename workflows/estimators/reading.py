"""Readers for image-to-SMPL estimator outputs, one module per format (see each module's docstring).

:func:`read_estimate` loads the file (never running code from it), picks the reader by ``format``
or detects it from the content, and returns the people of one frame (``frame``, default 0: the one
frame-selection rule of every reader) in smplik's y-up world, placed on our body model
(:mod:`workflows.estimators.base`).

Safety limits: ``.npz`` and ``.pt`` members are checked against ``max_bytes`` (their uncompressed
sizes, read from the zip directory) before anything is decompressed; other files by their size; at
most ``max_people`` people per frame. Every problem raises :class:`EstimateFormatError` (one line,
naming the file and the key) or :class:`workflows.safe_pickle.UnsafePickleError`.
"""

from __future__ import annotations

import json
import lzma
import pickle
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any, Literal

import numpy as np

from workflows.estimators import (
    aist,
    amass_params,
    easymocap,
    glamr,
    gvhmr,
    hybrik,
    phalp,
    plain,
    pose_array,
    pymafx,
    romp,
    sam3d,
    smplerx,
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
                     "amass", "sam3d", "easymocap", "tram", "smplerx", "plain", "pose_array"]
FORMATS: tuple[str, ...] = ("romp", "bev", "hybrik", "phalp", "wham", "pymafx", "vibe", "gvhmr", "glamr", "aist",
                            "amass", "sam3d", "easymocap", "tram", "smplerx", "plain", "pose_array")
_MODULES = {"romp": romp, "bev": romp, "hybrik": hybrik, "phalp": phalp, "wham": wham, "pymafx": pymafx, "vibe": vibe,
            "gvhmr": gvhmr, "glamr": glamr, "aist": aist, "amass": amass_params, "sam3d": sam3d, "easymocap": easymocap,
            "tram": tram, "smplerx": smplerx, "plain": plain, "pose_array": pose_array}
_DETECT_ORDER = (romp, hybrik, gvhmr, glamr, aist, sam3d, phalp, wham, pymafx, vibe, amass_params, easymocap, tram,
                 smplerx, plain, pose_array)
_PATH_READERS = (amass_params, tram, smplerx)
"""Readers that need the file's path (sibling files: other tracks or people, the camera or meta file)."""
SIGNATURES: dict[str, tuple[str, ...]] = {
    "romp": ("smpl_thetas", "smpl_betas", "cam_trans"), "hybrik": ("pred_thetas", "pred_betas", "transl"),
    "phalp": ("smpl", "camera"), "wham": ("pose", "trans", "betas"), "pymafx": ("pose", "betas", "orig_cam_t"),
    "vibe": ("pose", "betas", "orig_cam", "frame_ids"),
    "gvhmr": ("smpl_params_incam", "smpl_params_global", "K_fullimg"), "glamr": ("person_data", "cam_pose"),
    "aist": ("smpl_poses", "smpl_trans", "smpl_scaling"), "amass": ("poses", "trans", "betas"),
    "sam3d": ("pred_joint_coords", "pred_cam_t"), "easymocap": ("id", "Rh", "Th", "poses", "shapes"),
    "tram": ("pred_rotmat", "pred_trans", "pred_shape", "frame"), "smplerx": smplerx.KEYS,
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
    import torch

    from smplik.limits import check_torch_zip

    check_torch_zip(path)  # declared sizes and no compressed storage, before torch reads anything
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError, ValueError, TypeError, AttributeError,
            zipfile.BadZipFile) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EstimateFormatError(f"{path}: not a readable tensor file (torch.load with weights_only=True: "
                                  f"{first[:200]}).") from None
    from smplik.limits import check_tensors

    # before .numpy(): a stride-0 view expands to its full shape, and .double() makes every float tensor real
    check_tensors(data, str(path), as_itemsize=8)
    return _to_numpy(data)


def _load_raw(path: Path, trust_pickle: bool, max_bytes: int) -> Any:
    from workflows.safe_pickle import UnsafePickleError, load_npz, load_pickle, read_npy

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
            return load_npz(path)
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
    if isinstance(data, np.ndarray):
        return (f"an array of shape {data.shape}: the pose_array format needs (T, 72 | 156 | 165) floats "
                f"(axis-angle, root first).")
    keys = _record_keys(data)
    scored = [(len(keys & set(sig)) / len(sig), name) for name, sig in SIGNATURES.items()]
    share, name = max(scored, key=lambda t: t[0])
    if share == 0:
        return f"no known layout shares its keys (known formats: {', '.join(FORMATS)})."
    lacks = [k for k in SIGNATURES[name] if k not in keys]
    return f"closest: {name}, which also needs {', '.join(repr(k) for k in lacks)}."


def read_estimate(path: str | Path, *, format: FormatName = "auto", trust_pickle: bool = False,
                  frame: int = 0, max_people: int = MAX_PEOPLE, max_bytes: int = MAX_BYTES,
                  space: Literal["camera", "world"] | None = None, solver: Any = None) -> list[EstimatedPerson]:
    """Read the people of one frame of an estimator output file, placed on our body in the y-up world.

    Args:
        path: the results file (.npz, .json, .pk/.pkl/.joblib, .pt/.pth), or a folder of per-frame outputs
            (:mod:`workflows.estimators.folders`: SMPLer-X's output folder, one file per frame of any reader).
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
        workflows.safe_pickle.UnsafePickleError: a pickle names a refused global.
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
    if path.is_dir():  # per-frame outputs (workflows.estimators.folders): frame N of the folder's clip
        import warnings

        from workflows.estimators.folders import read_folder_frame, scan_folder

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
