"""The network (encoder, both decoders and the FK with J(beta, gender)) as ONNX, run by onnxruntime.

>>> export_onnx(solver.model, "smplik_cmu.onnx", meta={"source": solver.source})   # or `smplik export-model --onnx`
>>> net = OnnxNetwork("smplik_cmu.onnx", threads=1)
>>> out = net(eff, betas, gender)            # same call and IKOutput as ProtoResIK.forward
>>> solver = IKSolver.load(runtime="onnx")   # the solver's refinement then runs unchanged

The exported graph is :class:`smplik.network_folded.FoldedProtoResIK`: the network's function with its weights
folded (embeddings through the first layer, forward layers after the masked means, token layers as 2-D
``Gemm``, FK by pointer jumping), tested equal to ``ProtoResIK.forward``; about half the nodes of a trace of
the forward itself (a one-pose call costs roughly 1.5 us per node).

Exporter: torch's TorchScript-based exporter (``torch.onnx.export(..., dynamo=False)``), pinned. With
torch 2.13 both exporters produce a graph that agrees with torch within 2e-6 and runs equally fast;
the TorchScript one needs no ``onnxscript``, exports in ~4 s instead of ~18 s, and works on every
torch the project supports (2.1+). Opset :data:`ONNX_OPSET` = 15, the highest that Unity Sentis
documents support for (onnxruntime, onnxruntime-web and Unreal NNE read it too).

Graph inputs, exactly the tensors :func:`smplik.effectors.pack_effectors` packs
(:class:`~smplik.effectors.EffectorBatch`) plus the body; ``B`` (``batch``) and ``N`` (``effectors``) are dynamic axes:

==========  =========  =======  ==============================================================
name        shape      dtype    meaning
==========  =========  =======  ==============================================================
joint       (B, N)     int64    SMPL joint index 0..23 (:data:`smplik.conventions.JOINT_NAMES`)
type        (B, N)     int64    0 position, 1 rotation, 2 look-at (:class:`~smplik.conventions.EffectorType`)
data        (B, N, 6)  float32  position: ``(x, y, z, 0, 0, 0)`` in metres, world frame;
                                rotation: the first two columns of R_world_joint, ``(R[:,0], R[:,1])``;
                                look-at: ``(target xyz, unit direction in the joint's frame)``;
                                padding: zeros
tolerance   (B, N)     float32  the effector's ``tolerance`` in [0, 1] (0 = exact); 0 for padding
mask        (B, N)     bool     True for a real effector, False for padding (>= 1 True per row)
betas       (B, 10)    float32  SMPL shape
gender      (B,)       int64    0 neutral, 1 male, 2 female (:class:`~smplik.conventions.Gender` order)
==========  =========  =======  ==============================================================

Outputs (world frame, SMPL's 24 joints, smplx conventions): ``R_local`` (B, 24, 3, 3) local rotations
(joint 0: global orientation), ``R_world`` (B, 24, 3, 3), ``p_world`` (B, 24, 3) joint positions,
``draft`` (B, 24, 3) the position decoder's draft, ``transl`` (B, 3) smplx ``transl``
(pelvis = J0(beta) + transl). The rest skeletons J(beta, gender) of the body models used at export
are constants of the graph; the file's metadata (``metadata_props``) names them (``body_fingerprint``)
and the weights (``model_fingerprint``), so a solver uses a file only with the model it came from.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import tempfile
import threading
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor

from smplik.atomic import write_bytes_atomic
from smplik.body_model import grid_bytes
from smplik.effectors import EffectorBatch
from smplik.network import IKOutput, ProtoResIK
from smplik.network_folded import FoldedProtoResIK
from smplik.threads import run_spread

ONNX_OPSET = 15
"""Opset of the exported graph."""
ONNX_FORMAT = "smplik-onnx"
"""``metadata_props["format"]`` of an exported file."""
INPUT_NAMES = ("joint", "type", "data", "tolerance", "mask", "betas", "gender")
OUTPUT_NAMES = ("R_local", "R_world", "p_world", "draft", "transl")
_INPUT_DTYPES = tuple(map(np.dtype, (np.int64, np.int64, np.float32, np.float32, np.bool_, np.float32, np.int64)))
Runtime = Literal["torch", "onnx", "auto"]
RUNTIMES = ("torch", "onnx", "auto")
INSTALL_HINT = 'pip install -e ".[fast]" in the smplik checkout (onnxruntime and onnx)'


class OnnxUnavailableError(ImportError):
    """onnxruntime (or onnx, for exporting) is not installed."""


class OnnxModelError(ValueError):
    """An ONNX file that is not a usable smplik network (unreadable, other format, other model)."""


def onnxruntime_available() -> bool:
    """True when onnxruntime can be imported."""
    return importlib.util.find_spec("onnxruntime") is not None


def _require(module: str, purpose: str) -> Any:
    try:
        return __import__(module)
    except ImportError:
        raise OnnxUnavailableError(f"{purpose} needs the '{module}' package, which is not installed: "
                                   f"{INSTALL_HINT}.") from None


SKELETON_BUFFERS = ("J_template", "J_dirs")
"""The network's buffers copied from the body models in use."""


def model_fingerprint(model: ProtoResIK) -> str:
    """SHA-256 (first 16 hex digits) of the network config and every float32 weight and buffer,
    rest skeletons included: equal only for the same weights on the same body models. The rest
    skeletons (``J_template``, ``J_dirs``) are hashed on the body fingerprint's grid
    (:func:`smplik.body_model.grid_bytes`), since the built-in body's joints differ between CPUs by
    floating-point noise."""
    h = hashlib.sha256(json.dumps(model.cfg.to_dict(), sort_keys=True).encode())
    for name, value in sorted(model.state_dict().items()):
        h.update(name.encode())
        array = value.detach().cpu().numpy()
        h.update(grid_bytes(array) if name in SKELETON_BUFFERS else np.ascontiguousarray(array).tobytes())
    return h.hexdigest()[:16]


def _example_inputs() -> tuple[Tensor, ...]:
    """B = 2 rows of N = 3 effectors (one of each type, one padded slot) to trace the graph with."""
    joint = torch.tensor([[20, 0, 15], [21, 12, 0]])
    kind = torch.tensor([[0, 1, 2], [0, 2, 0]])
    data = torch.tensor([[[0.5, 1.2, 0.1, 0, 0, 0], [1, 0, 0, 0, 1, 0], [0, 1.5, 2, 0, 0, 1]],
                         [[-0.4, 1.0, 0.2, 0, 0, 0], [0, 1.6, 2, 0, 0, 1], [0, 0, 0, 0, 0, 0]]])
    tolerance = torch.tensor([[0.0, 0.1, 0.0], [0.2, 0.0, 0.0]])
    mask = torch.tensor([[True, True, True], [True, True, False]])
    return joint, kind, data, tolerance, mask, torch.zeros(2, 10), torch.tensor([0, 2])


def export_onnx_bytes(model: ProtoResIK, meta: Mapping[str, Any] | None = None) -> bytes:
    """The serialized ONNX graph of ``model`` (network + FK), with metadata.

    Args:
        model: the network, with the rest skeletons of the body models it will pose (as the solver holds it).
        meta: extra ``metadata_props`` (values turned into strings; dicts as JSON), e.g. ``source``, ``step``.

    Raises:
        OnnxUnavailableError: the ``onnx`` package is missing.
    """
    onnx = _require("onnx", "Exporting to ONNX")
    dynamic = {name: {0: "batch", 1: "effectors"} for name in INPUT_NAMES[:5]}
    dynamic.update({"betas": {0: "batch"}, "gender": {0: "batch"}}, **{n: {0: "batch"} for n in OUTPUT_NAMES})
    graph = FoldedProtoResIK(model)
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        # The legacy-exporter notice and the tracer's notes on the static (24, 3) shape checks.
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        # strided Slice nodes (the batch-last layout) cannot be constant-folded; harmless, said three times
        warnings.filterwarnings("ignore", message="Constant folding - Only steps=1", category=UserWarning)
        path = Path(tmp) / "model.onnx"
        torch.onnx.export(graph, _example_inputs(), str(path), dynamo=False, opset_version=ONNX_OPSET,
                          input_names=list(INPUT_NAMES), output_names=list(OUTPUT_NAMES), dynamic_axes=dynamic,
                          do_constant_folding=True)
        proto = onnx.load(str(path))
    props = {"format": ONNX_FORMAT, "version": "1", "opset": str(ONNX_OPSET),
             "model_fingerprint": model_fingerprint(model), "network": model.cfg.to_dict(),
             "inputs": ", ".join(INPUT_NAMES), "outputs": ", ".join(OUTPUT_NAMES), **(meta or {})}
    for key, value in props.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, json.dumps(value) if isinstance(value, (dict, list)) else str(value)
    proto.producer_name = "smplik"
    onnx.checker.check_model(proto)
    return proto.SerializeToString()


def export_onnx(model: ProtoResIK, out: str | Path, meta: Mapping[str, Any] | None = None) -> Path:
    """Write :func:`export_onnx_bytes` to ``out`` atomically."""
    return write_bytes_atomic(out, export_onnx_bytes(model, meta))


CHUNK_ROWS = 128
"""Batches of at least ``2 * CHUNK_ROWS`` rows run as chunks of this many rows, one session call each."""
SMALL_TOKENS = 16
"""Calls of at most this many effector tokens (rows x effectors: one pose of up to 16 effectors) run in the
network's ``small`` kernel when it has one."""


class OnnxNetwork:
    """An onnxruntime session of an exported network, called like ``ProtoResIK.forward``.

    The session itself runs single-threaded. A batch of at least ``2 *`` :data:`CHUNK_ROWS` rows is cut
    into chunks of :data:`CHUNK_ROWS` rows, and ``threads`` Python threads run the chunks through the
    session at once (onnxruntime releases the GIL and its sessions may be run concurrently). On these
    graphs that is faster than onnxruntime's own intra-op threads, whose thread pool splits every small
    ``Gemm`` (2 threads, batch 1024: about 1.5x), and at one thread the chunks alone are faster than one
    large call (their activations stay in cache). Rows are independent, so the answer does not depend
    on ``threads`` (tested bit for bit).

    Calls of at most :data:`SMALL_TOKENS` effector tokens (B N) run in ``small``, when given
    (:func:`select_network` gives :class:`smplik.network_numba.NumbaNetwork` of the same weights when numba
    is installed): one compiled kernel instead of ~170 graph operators, about half the time of a one-pose
    session call.

    Args:
        model: an ``.onnx`` file from :func:`export_onnx` or its bytes.
        threads: threads a large batch is spread over (1: everything in the caller's thread).
        small: the network for calls of at most :data:`SMALL_TOKENS` tokens (None: the session runs every call).

    Raises:
        OnnxUnavailableError: onnxruntime is missing.
        OnnxModelError: not a readable smplik ONNX network.
    """

    def __init__(self, model: str | Path | bytes, *, threads: int = 1, small: Any = None):
        ort = _require("onnxruntime", "The onnx runtime")
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}.")
        self.source = "<in memory>" if isinstance(model, bytes) else str(model)
        self._model = model if isinstance(model, bytes) else Path(model).read_bytes()
        self.threads = threads
        self.small = small
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(self._model, options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidProtobuf/... types
            raise OnnxModelError(f"{self.source}: not a readable ONNX model ({type(exc).__name__}).") from None
        self._local = threading.local()  # per thread: the input buffers bound to the session
        self.meta: dict[str, str] = dict(self.session.get_modelmeta().custom_metadata_map)
        names = tuple(i.name for i in self.session.get_inputs())
        if self.meta.get("format") != ONNX_FORMAT or names != INPUT_NAMES:
            raise OnnxModelError(f"{self.source}: not an smplik network (format {self.meta.get('format')!r}, "
                                 f"inputs {', '.join(names)}); export one with `smplik export-model --onnx`.")

    @property
    def model_bytes(self) -> bytes:
        """The serialized graph this session runs."""
        return self._model

    @property
    def fingerprint(self) -> str | None:
        """The ``model_fingerprint`` of the weights it was exported from."""
        return self.meta.get("model_fingerprint")

    def with_threads(self, threads: int) -> OnnxNetwork:
        """A new session of the same graph with another thread count."""
        return OnnxNetwork(self._model if self.source == "<in memory>" else self.source, threads=threads,
                           small=self.small)

    def __call__(self, eff: EffectorBatch, betas: Tensor, gender: Tensor) -> IKOutput:
        """eff: B rows of N effectors; betas (B, 10); gender (B,) long -> :class:`IKOutput` (float32, CPU).

        The inputs are copied (cast where needed) into numpy buffers bound to the session once per thread and
        input shape (``io_binding``): for one pose that costs a fraction of what ``session.run`` spends turning
        seven fresh arrays into onnxruntime values. Each call returns new output tensors (copies).
        """
        tensors = (eff.joint, eff.type, eff.data, eff.tolerance, eff.mask, betas, gender)
        arrays = [(t.detach() if t.requires_grad else t).cpu().numpy() for t in tensors]
        return IKOutput(*map(torch.from_numpy, self.run_arrays(*arrays)))

    def run_arrays(self, *arrays: np.ndarray) -> list[np.ndarray]:
        """The graph on numpy inputs in :data:`INPUT_NAMES` order (any numeric dtype: cast into the bound
        buffers) -> the outputs in :data:`OUTPUT_NAMES` order, new float32 arrays."""
        B = arrays[0].shape[0] if arrays and arrays[0].ndim else 0
        if self.small is not None and B * (arrays[0].shape[1] if arrays[0].ndim > 1 else 1) <= SMALL_TOKENS:
            return self.small.run_arrays(*arrays)
        if B < 2 * CHUNK_ROWS:
            return self._run_chunk(arrays)
        bounds = [*range(0, B, CHUNK_ROWS), B]
        outs = [np.empty((B, *shape), np.float32) for shape in self._output_shapes]

        def run(lo: int, hi: int) -> None:
            self._run_chunk([a[lo:hi] for a in arrays], [o[lo:hi] for o in outs])

        run_spread(run, bounds, self.threads)
        return outs

    def _run_chunk(self, arrays: Sequence[np.ndarray], into: Sequence[np.ndarray] | None = None
                   ) -> list[np.ndarray]:
        """One session call, through this thread's input buffers bound for these shapes; the outputs are
        written into ``into`` (C-contiguous float32 arrays of the output shapes) when given, else new arrays."""
        shapes = tuple(a.shape for a in arrays)
        bound = getattr(self._local, "bound", None)
        if bound is None:
            self._local.bound = bound = {}
        key = (shapes, into is not None)
        if key not in bound:
            if len(bound) >= 4:  # a chunk, a remainder and a few small calls
                bound.clear()
            buffers = [np.empty(tuple(shape), dtype) for shape, dtype in zip(shapes, _INPUT_DTYPES, strict=True)]
            binding = self.session.io_binding()
            for name, buffer in zip(INPUT_NAMES, buffers, strict=True):
                binding.bind_cpu_input(name, buffer)
            for name in OUTPUT_NAMES:
                binding.bind_output(name, "cpu")
            bound[key] = (buffers, binding)
        buffers, binding = bound[key]
        for buffer, a in zip(buffers, arrays, strict=True):
            np.copyto(buffer, a, casting="unsafe")
        if into is None:
            self.session.run_with_iobinding(binding)
            return binding.copy_outputs_to_cpu()  # copies: the buffers are reused
        for name, out in zip(OUTPUT_NAMES, into, strict=True):
            binding.bind_output(name, "cpu", 0, np.float32, list(out.shape), out.ctypes.data)
        self.session.run_with_iobinding(binding)
        return list(into)

    @property
    def _output_shapes(self) -> list[tuple[int, ...]]:
        """Each output's shape after the batch axis (static in an exported graph)."""
        return [tuple(int(d) for d in o.shape[1:]) for o in self.session.get_outputs()]


def select_network(runtime: str, model: ProtoResIK, model_path: str | Path, onnx_file: str | Path | None = None, *,
                   threads: int = 1, meta: Mapping[str, Any] | None = None, small_batches: bool = True
                   ) -> OnnxNetwork | None:
    """The network backend a solver runs: None for the torch model, else an :class:`OnnxNetwork`.

    ``small_batches``: with numba installed, calls of at most :data:`SMALL_TOKENS` effector tokens run in
    :class:`smplik.network_numba.NumbaNetwork` (same weights; tested equal within 1e-5) instead of the session.

    ``"torch"``: None. ``"onnx"``: ``onnx_file``, else ``model_path`` with the suffix ``.onnx`` if it exists,
    else the model exported in memory (a few seconds); the file must come from ``model`` (same
    :func:`model_fingerprint`). ``"auto"``: onnxruntime when it is installed and such a matching file is given
    or found next to the model, else None (a warning says why a file found was not used).

    Raises:
        ValueError: unknown runtime. OnnxUnavailableError: ``"onnx"`` without onnxruntime.
        FileNotFoundError: ``onnx_file`` missing. OnnxModelError: (``"onnx"``) a file of another model.
    """
    if runtime not in RUNTIMES:
        raise ValueError(f"Unknown runtime {runtime!r}; expected one of: {', '.join(RUNTIMES)}.")
    if runtime == "torch" or (runtime == "auto" and not onnxruntime_available()):
        return None
    if onnx_file is not None and not Path(onnx_file).is_file():
        raise FileNotFoundError(f"ONNX file not found: {onnx_file}")
    candidate = Path(onnx_file) if onnx_file is not None else Path(model_path).with_suffix(".onnx")
    if candidate.is_file():
        try:
            net = OnnxNetwork(candidate, threads=threads)
            if net.fingerprint != model_fingerprint(model):
                raise OnnxModelError(
                    f"{candidate} was exported from other weights or body models than {model_path} (model "
                    f"fingerprint {net.fingerprint} vs {model_fingerprint(model)}); re-export it with "
                    f"`smplik export-model {model_path} --onnx {candidate}`.")
            net.small = small_batch_network(model) if small_batches else None
            return net
        except OnnxModelError as exc:
            if runtime == "onnx":
                raise
            warnings.warn(f"{exc} Using the torch network.", stacklevel=3)
            return None
    if runtime == "auto":
        return None
    return OnnxNetwork(export_onnx_bytes(model, meta), threads=threads,
                       small=small_batch_network(model) if small_batches else None)


def small_batch_network(model: ProtoResIK) -> Any:
    """:class:`smplik.network_numba.NumbaNetwork` of ``model`` for small calls, or None without numba (or for
    a network that kernel does not run)."""
    if importlib.util.find_spec("numba") is None:
        return None
    from smplik.network_numba import NumbaNetwork

    try:
        return NumbaNetwork(model)
    except ValueError:
        return None
