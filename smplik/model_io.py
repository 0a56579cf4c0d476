"""Model files: exported inference models and training checkpoints, read without running code.

Both kinds are one :func:`torch.save` dict of **plain data only**: tensors, ``int``/``float``/
``bool``/``str``/``None``, lists/tuples and dicts of those (no numpy objects, no classes). Every
``.pt`` smplik opens (these, tracking models, estimator tensor files) goes through :func:`read_torch_file`, the
library's only ``torch.load(..., weights_only=True)``, which refuses anything else before it can run, after the
zip directory's sizes are checked and before any tensor is used (logical sizes, dense contiguous layout).
:func:`write_model_file` checks the same rule before writing (atomically), so what it writes is always loadable.

==================  =============================================  ==================================
key                 exported model (``format: smplik-model``)       checkpoint (``smplik-checkpoint``)
==================  =============================================  ==================================
``format``          ``"smplik-model"``                              ``"smplik-checkpoint"``
``version``         :data:`FORMAT_VERSION` (2; 1 is read too)       same
``network``         :class:`~smplik.network.NetworkConfig` dict     same
``model``           state dict (fp16 weights by default)            state dict (fp32)
``body_fingerprint`` fingerprint of the training body models        same
``metrics``         last validation metrics                         same
``step``            optimizer steps trained                         same
``train_config`` /  the run's ``TrainConfig`` dict                  ``config`` (same dict)
``optimizer``, ``rng``, ``loss_ema``   --                           Adam state; RNG states as tensors
``averaged_from``   inputs of :func:`average_models` (name, step)   --
==================  =============================================  ==================================

A file written some other way is refused with a one-line :class:`CheckpointError` naming the
file. An older smplik file whose metadata holds numpy values (numpy scalars, arrays, a numpy RNG
state) converts once with ``smplik export-model OLD.pt --out NEW.pt --legacy`` (:func:`export_model`
with ``legacy=True``): still ``torch.load(weights_only=True)``, with only numpy's array and scalar
reconstructors added to the allow-list (:func:`legacy_numpy_globals`; rebuilding an array from its
bytes runs nothing from the file). A file that names any other global (a pickled class, a
payload's ``os.system``) is refused by both paths: no smplik load runs code from a file.
"""

from __future__ import annotations

import pickle
import re
import warnings
import zipfile
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from smplik.atomic import atomic_path
from smplik.limits import check_tensors, check_torch_zip
from smplik.network import NetworkConfig, ProtoResIK

__all__ = ["CHECKPOINT_FORMAT", "FORMAT_VERSION", "MODEL_FORMAT", "CheckpointError", "average_models",
           "check_tensor_layout", "export_model", "load_checkpoint", "load_model", "read_model_file", "read_torch_file",
           "write_model_file"]

MODEL_FORMAT = "smplik-model"
CHECKPOINT_FORMAT = "smplik-checkpoint"
FORMAT_VERSION = 2
_KINDS = (MODEL_FORMAT, CHECKPOINT_FORMAT)
_PLAIN_SCALARS = (bool, int, float, str, type(None))
_UNSAFE_GLOBAL = re.compile(r"GLOBAL ([\w.]+)")
_MAX_INFLATED_BYTES = 64 << 20  # members above this size ...
_MAX_INFLATION = 16  # ... may not expand more than this factor


class CheckpointError(ValueError):
    """An smplik model file (exported model or training checkpoint) is unsafe, old, corrupt or malformed."""


def convert_hint(path: str | Path) -> str:
    """The one conversion command for a model file the safe loader refuses."""
    return (f"if it is an older smplik model file (numpy values in its metadata), convert it once with "
            f"`smplik export-model {path} --out NEW.pt --legacy` (restricted loader too: runs no code)")


def _check_plain(obj: Any, where: str) -> None:
    """Raise ``TypeError`` naming the first value that ``torch.load(weights_only=True)`` would refuse."""
    if isinstance(obj, torch.Tensor) or type(obj) in _PLAIN_SCALARS:
        return
    if type(obj) in (list, tuple):
        for i, v in enumerate(obj):
            _check_plain(v, f"{where}[{i}]")
        return
    if isinstance(obj, dict):  # dict and OrderedDict (state dicts)
        for k, v in obj.items():
            if type(k) not in (str, int):
                raise TypeError(f"{where}: key {k!r} of type {type(k).__name__} cannot go into a model file.")
            _check_plain(v, f"{where}[{k!r}]")
        return
    raise TypeError(f"{where}: a {type(obj).__module__}.{type(obj).__name__} cannot go into a model file "
                    "(tensors, numbers, strings, None, lists and dicts only).")


def write_model_file(path: str | Path, state: Mapping[str, Any]) -> Path:
    """Write ``state`` (plain data only, see the module docstring) with ``torch.save``, atomically.

    Raises:
        TypeError: ``state`` holds something the safe loader would refuse (named by its key path).
    """
    _check_plain(dict(state), "state")
    with atomic_path(path) as tmp:
        torch.save(dict(state), tmp)
    return Path(path)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else type(exc).__name__


def _check_archive(path: Path, what: str, error: type[ValueError]) -> None:
    """A torch.save zip whose members do not inflate: torch.save stores them uncompressed, so a
    large member packed much smaller than it expands to can only be a decompression bomb."""
    if not zipfile.is_zipfile(path):
        raise error(f"{path}: not a readable {what} (not a torch.save zip file).")
    try:
        with zipfile.ZipFile(path) as zf:
            members = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise error(f"{path}: not a readable {what} ({_first_line(exc)}).") from None
    for m in members:
        if m.file_size > _MAX_INFLATED_BYTES and m.file_size > _MAX_INFLATION * max(m.compress_size, 1):
            raise error(f"{path}: member {m.filename!r} inflates from {m.compress_size} to {m.file_size} "
                        "bytes; torch.save never compresses, so this is not a model file.")


def check_tensor_layout(obj: Any, source: str, error: type[ValueError] = ValueError, *, max_depth: int = 50) -> None:
    """Every tensor in a loaded structure is a plain dense, contiguous tensor (what ``torch.save`` of a state dict
    writes): no sparse or quantized layout, no stride-0 or transposed view (a numba kernel or ``.numpy()`` would
    see the view's strides, not a copy). Raises ``error`` naming ``source`` and the key path."""
    stack: list[tuple[Any, str, int]] = [(obj, "", 0)]
    while stack:
        node, where, depth = stack.pop()
        if depth > max_depth:
            raise error(f"{source}: nested deeper than {max_depth} levels.")
        if isinstance(node, torch.Tensor):
            name = where or "(root)"
            if node.layout != torch.strided or node.is_quantized:
                raise error(f"{source}: tensor {name} has layout {node.layout}; model files hold dense tensors.")
            if not node.is_contiguous():
                raise error(f"{source}: tensor {name} is a view with strides {tuple(node.stride())} for shape "
                            f"{tuple(node.shape)} (stride 0 or not contiguous); model files hold plain tensors.")
            if node.dtype.is_complex:
                raise error(f"{source}: tensor {name} is complex ({node.dtype}); model files hold real numbers.")
        elif isinstance(node, dict):
            stack.extend((v, f"{where}.{k}" if where else str(k), depth + 1) for k, v in node.items())
        elif isinstance(node, (list, tuple)):
            stack.extend((v, f"{where}[{i}]", depth + 1) for i, v in enumerate(node))


def read_torch_file(path: str | Path, *, what: str = "smplik model", error: type[ValueError] = CheckpointError,
                    legacy: bool = False, layout: bool = True, as_itemsize: int | None = None,
                    hint: str | None = None) -> Any:
    """THE reader of every ``.pt`` file smplik opens (IK models and checkpoints, tracking models, estimator
    tensor files): nothing in it runs and nothing it declares is allocated before it is checked.

    1. a regular file (:func:`smplik.limits.check_input_file`: no pipe, no device);
    2. a ``torch.save`` zip whose directory declares no member inflating past 64 MiB from a smaller packed size
       and whose storages fit :func:`smplik.limits.check_torch_zip` (no compressed storage over
       ``TORCH_COMPRESSED_MEMBER_BYTES``, each within ``SMPLIK_MAX_ARRAY_BYTES``, all within
       ``SMPLIK_MAX_INPUT_BYTES``), from the directory, before anything is inflated;
    3. ``torch.load(weights_only=True)`` (``legacy`` adds numpy's reconstructors, :func:`legacy_numpy_globals`);
    4. every tensor's logical size (:func:`smplik.limits.check_tensors`; ``as_itemsize``: the float conversion
       the caller will make, counted against ``SMPLIK_MAX_MEMORY_BYTES``) and, with ``layout``, its layout
       (:func:`check_tensor_layout`: dense, contiguous, no stride 0).

    Config values are the caller's: each file kind checks its own keys' types and ranges after this.

    Args:
        what: the kind of file, for messages ("tracking model"). error: the one-line error class raised.
        hint: appended to the refusal of a file that holds other Python objects (a conversion command).

    Raises:
        FileNotFoundError: no such file. LimitError: a declared size over a limit. ``error``: unsafe (never
        executed), unreadable or badly laid out content; one line naming the file.
    """
    from smplik.limits import check_input_file

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"Model file not found: {path}" if error is CheckpointError
                                else f"{path}: {what} not found.")
    check_input_file(path, what)
    check_torch_zip(path)  # declared member sizes within the input limits, before torch reads anything
    _check_archive(path, what, error)  # a zip at all, and no member inflating 16-fold past 64 MiB
    extra = legacy_numpy_globals() if legacy else []
    try:
        with warnings.catch_warnings(), torch.serialization.safe_globals(extra):
            warnings.simplefilter("ignore")  # the safe unpickler warns about pickle protocols
            state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = _UNSAFE_GLOBAL.search(str(exc))
        named = f" (it names {found.group(1)})" if found else ""
        if legacy:
            raise error(f"{path}: refused even as a legacy file: it holds Python objects other than "
                        f"tensors, numbers, strings, containers and numpy values{named}, which could "
                        "run code when loaded; smplik never loads such a file.") from None
        raise error(f"{path}: refused: the file holds Python objects other than tensors, numbers, "
                    f"strings, lists and dicts{named}, which could run code when loaded"
                    f"{'; ' + hint if hint else ''}.") from None
    except Exception as exc:  # torch raises RuntimeError, EOFError, ... for corrupt files
        raise error(f"{path}: not a readable {what} ({type(exc).__name__}: {_first_line(exc)}).") from None
    check_tensors(state, str(path), as_itemsize=as_itemsize)  # a stride-0 view expands to its full shape in any use
    if layout:
        check_tensor_layout(state, str(path), error)
    return state


def read_model_file(path: str | Path, kinds: Collection[str] = _KINDS) -> dict[str, Any]:
    """Read an smplik model file with ``torch.load(weights_only=True)`` and check its header.

    Args:
        path: the ``.pt`` file.
        kinds: accepted ``format`` values (:data:`MODEL_FORMAT`, :data:`CHECKPOINT_FORMAT`).

    Raises:
        FileNotFoundError: no such file.
        CheckpointError: not a torch file, unsafe content (never executed), another format or a
            newer version; the one-line message names the file.
    """
    path = Path(path)
    state = _safe_load(path, legacy=False)
    if not isinstance(state, dict) or state.get("format") not in _KINDS:
        raise CheckpointError(f"{path}: not an smplik model or checkpoint (missing 'format').")
    if state["format"] not in kinds:
        raise CheckpointError(f"{path}: is an {state['format']} file; expected {' or '.join(kinds)}.")
    version = state.get("version")
    if type(version) is not int or not 1 <= version <= FORMAT_VERSION:
        raise CheckpointError(f"{path}: {state['format']} version {version!r}; this smplik reads versions "
                              f"1..{FORMAT_VERSION} (a newer file needs a newer smplik).")
    for key, typ in (("network", dict), ("model", dict)):
        if not isinstance(state.get(key), typ):
            raise CheckpointError(f"{path}: key '{key}' is missing or not a {typ.__name__}.")
    return state


def _network_config(state: Mapping[str, Any], path: Path) -> NetworkConfig:
    """The file's network config, its implied memory (weights + activations at the inference batch) checked
    against ``SMPLIK_MAX_MEMORY_BYTES`` before any layer is allocated."""
    from smplik.configs import check_network_memory
    from smplik.limits import LimitError

    try:
        cfg = NetworkConfig(**state["network"])
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: key 'network' is not a network config ({exc}).") from None
    try:
        check_network_memory(cfg, f"{path}: key 'network'")
    except LimitError as exc:
        raise CheckpointError(str(exc)) from None
    return cfg


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """A training checkpoint (``RUN_DIR/checkpoint.pt``) as a dict, read safely (see :func:`read_model_file`)."""
    path = Path(path)
    state = read_model_file(path, kinds=(CHECKPOINT_FORMAT,))
    _network_config(state, path)
    if type(state.get("step")) is not int or state["step"] < 0:
        raise CheckpointError(f"{path}: key 'step' is missing or not a non-negative integer.")
    return state


def load_model(path: str | Path) -> tuple[ProtoResIK, dict[str, Any]]:
    """Load a model from an exported model file or a training checkpoint (float32, eval mode).

    Returns:
        ``(model, meta)``: meta is the file's dict without ``model``, ``optimizer`` and ``rng``.

    Raises:
        FileNotFoundError: no such file. CheckpointError: see :func:`read_model_file`; weights that
            do not fit the file's network config.
    """
    path = Path(path)
    state = read_model_file(path)
    cfg = _network_config(state, path)
    weights = state["model"]
    if not all(isinstance(v, torch.Tensor) for v in weights.values()):
        raise CheckpointError(f"{path}: key 'model' must map names to tensors.")
    weights = {k: v.float() if v.is_floating_point() else v for k, v in weights.items()}
    if "J_template" not in weights or "J_dirs" not in weights:
        raise CheckpointError(f"{path}: key 'model' lacks the J_template / J_dirs buffers.")
    try:
        model = ProtoResIK(cfg, weights["J_template"], weights["J_dirs"])
        model.load_state_dict(weights)
    except (RuntimeError, ValueError, TypeError, IndexError) as exc:
        raise CheckpointError(f"{path}: weights do not fit its network config ({_first_line(exc)}).") from None
    model.eval()
    return model, {k: v for k, v in state.items() if k not in {"model", "optimizer", "rng"}}


def _to_plain(obj: Any) -> Any:
    """numpy arrays -> tensors, numpy scalars -> Python numbers, recursively (for converting old files)."""
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(obj)) if obj.dtype != object else [_to_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        return {k: _to_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_to_plain(v) for v in obj]
    return obj


def legacy_numpy_globals() -> list[Any]:
    """The allow-list additions of the legacy reader: numpy's array/scalar reconstructors and dtypes.

    They rebuild an ``ndarray`` or a numpy scalar from the bytes stored in the file (numpy checks the
    byte count against the shape), so they allocate nothing beyond the file's own data and run no
    code of the file. Old pickles name them under ``numpy.core`` (numpy 1), new ones under ``numpy._core``.
    """
    try:
        from numpy._core import multiarray
    except ImportError:  # numpy < 2
        from numpy.core import multiarray
    dtypes = sorted({type(np.dtype(c)) for c in "?bhilqBHILQefdgFDGUS"}, key=str)
    names = [(multiarray._reconstruct, f"{root}.multiarray._reconstruct") for root in ("numpy.core", "numpy._core")]
    names += [(multiarray.scalar, f"{root}.multiarray.scalar") for root in ("numpy.core", "numpy._core")]
    return [np.ndarray, np.dtype, *dtypes, *names]


def _safe_load(path: Path, *, legacy: bool) -> Any:
    """:func:`read_torch_file` of an smplik IK model file (its messages and conversion hint)."""
    return read_torch_file(path, legacy=legacy, hint=convert_hint(path))


def _read_legacy(path: Path) -> dict[str, Any]:
    """An older smplik file: :func:`_safe_load` with numpy values allowed, converted to plain values."""
    state = _safe_load(path, legacy=True)
    if not isinstance(state, dict) or state.get("format") not in _KINDS:
        raise CheckpointError(f"{path}: not an smplik model or checkpoint (missing 'format').")
    return _to_plain(state)


def export_model(checkpoint: str | Path, out: str | Path, *, half: bool = True, legacy: bool = False) -> Path:
    """Write a compact inference model file (config + weights, fp16 by default).

    Args:
        checkpoint: a training checkpoint or an exported model (re-export / conversion).
        out: the model file to write (atomically; may equal ``checkpoint``).
        half: store floating-point weights (not the skeleton buffers) as fp16.
        legacy: read ``checkpoint`` as an older smplik file whose metadata holds numpy values
            (:func:`_read_legacy`; still the restricted loader).
    """
    checkpoint = Path(checkpoint)
    state = _read_legacy(checkpoint) if legacy else read_model_file(checkpoint)
    for key in ("network", "model"):
        if not isinstance(state.get(key), dict):
            raise CheckpointError(f"{checkpoint}: key '{key}' is missing or not a dict.")
    if not all(isinstance(v, torch.Tensor) for v in state["model"].values()):
        raise CheckpointError(f"{checkpoint}: key 'model' must map names to tensors.")
    weights = {k: (v.half() if half and _is_weight(k, v) else v) for k, v in state["model"].items()}
    slim = _slim_state(state, weights)
    if "averaged_from" in state:
        slim["averaged_from"] = state["averaged_from"]
    for key in ("refine", "refine_calibration"):  # a calibrated model keeps its refinement settings
        if state.get(key) is not None:
            slim[key] = state[key]
    try:
        return write_model_file(out, slim)
    except TypeError as exc:
        raise CheckpointError(f"{checkpoint}: {exc}") from None


def _slim_state(state: Mapping[str, Any], weights: Mapping[str, torch.Tensor]) -> dict[str, Any]:
    """The exported-model dict of ``state`` (a checkpoint or model file) with ``weights`` as its state dict."""
    return {"format": MODEL_FORMAT, "version": FORMAT_VERSION, "network": state["network"], "model": dict(weights),
            "body_fingerprint": state.get("body_fingerprint"), "metrics": state.get("metrics", {}),
            "step": state.get("step", 0), "train_config": state.get("train_config", state.get("config", {}))}


def _is_weight(key: str, value: torch.Tensor) -> bool:
    """A trained floating-point weight (not the rest-skeleton buffers ``J_*`` / ``identity*``)."""
    return value.is_floating_point() and not key.startswith(("J_", "identity"))


def average_models(paths: Sequence[str | Path], out: str | Path, *, half: bool = True) -> Path:
    """Uniform weight average of models fine-tuned from one start (a "model soup", Wortsman et al. 2022).

    Every input (model file or checkpoint) must have the same network config, body fingerprint, weight names and
    shapes, and identical rest-skeleton buffers. The weights are averaged in float32 and written like
    :func:`export_model` (fp16 unless ``half=False``), with ``averaged_from`` (file names and steps). Refinement
    settings are not carried over: calibrate the average anew (``smplik benchmark calibrate``).

    Raises:
        ValueError: fewer than two inputs. CheckpointError: an unreadable input or one that does not match the first
            (named by file and key).
    """
    if len(paths) < 2:
        raise ValueError(f"averaging needs at least two model files, got {len(paths)}.")
    paths = [Path(p) for p in paths]
    states = [read_model_file(p) for p in paths]
    first, ref = paths[0], states[0]
    for path, state in zip(paths, states, strict=True):
        for key in ("network", "model"):
            if not isinstance(state.get(key), dict):
                raise CheckpointError(f"{path}: key '{key}' is missing or not a dict.")
        _network_config(state, path)
        if state["network"] != ref["network"]:
            raise CheckpointError(f"{path}: key 'network' differs from {first}'s; only models of one architecture "
                                  "can be averaged.")
        if state.get("body_fingerprint") != ref.get("body_fingerprint"):
            raise CheckpointError(f"{path}: key 'body_fingerprint' differs from {first}'s (other body models).")
        if state["model"].keys() != ref["model"].keys():
            extra = sorted(set(state["model"]) ^ set(ref["model"]))
            raise CheckpointError(f"{path}: weight names differ from {first}'s (e.g. 'model.{extra[0]}').")
        for key, value in state["model"].items():
            base = ref["model"][key]
            if not isinstance(value, torch.Tensor) or value.shape != base.shape:
                raise CheckpointError(f"{path}: key 'model.{key}' is not a tensor of shape {tuple(base.shape)}.")
            if not _is_weight(key, value) and not torch.equal(value.to(base.dtype), base):
                raise CheckpointError(f"{path}: buffer 'model.{key}' differs from {first}'s (other body models).")
    weights = {}
    for key, base in ref["model"].items():
        if _is_weight(key, base):
            mean = torch.stack([s["model"][key].float() for s in states]).mean(0)
            weights[key] = mean.half() if half else mean
        else:
            weights[key] = base
    slim = _slim_state(ref, weights)
    slim["step"] = max(int(s.get("step", 0) or 0) for s in states)
    slim["metrics"] = {}
    slim["averaged_from"] = [{"file": p.name, "step": int(s.get("step", 0) or 0)} for p, s in zip(paths, states,
                                                                                               strict=True)]
    return write_model_file(out, slim)


def write_calibrated_model(source: str | Path, out: str | Path, refine: Mapping[str, Any],
                           calibration: Mapping[str, Any] | None = None) -> Path:
    """Copy a model file with refinement settings (``refine``: ``RefineConfig.to_dict()``) that its solver
    then uses by default, and how they were found (``refine_calibration``); written atomically."""
    state = dict(read_model_file(source))
    state["refine"] = dict(refine)
    if calibration is not None:
        state["refine_calibration"] = dict(calibration)
    return write_model_file(out, state)
