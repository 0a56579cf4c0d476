"""The project's one restricted unpickler, and bounded ``.npz`` reading.

A pickle names Python callables that the loader calls (``os.system`` is one line away), so every
pickle a user opens -- SMPL ``.pkl`` model files (chumpy pickles), estimator outputs (HybrIK ``.pk``,
4D-Humans/PHALP, WHAM and PyMAF-X joblib ``.pkl``) and object arrays inside ``.npz`` files (ROMP's
``results`` dict) -- is read by :class:`RestrictedUnpickler`, which resolves only:

* numpy arrays, dtypes and scalars (``numpy[._core].multiarray._reconstruct``/``scalar``,
  ``numpy.ndarray``, ``numpy.dtype``, numpy 2's ``numpy.dtypes.*DType`` classes, ``_frombuffer``);
* builtin containers and values (dict, list, tuple, set, frozenset, bytes, bytearray, complex, slice,
  int, float, str, bool, ``collections.OrderedDict``/``defaultdict``, ``_codecs.encode`` of latin-1
  text for protocol-2 bytes, ``copyreg._reconstructor`` of plain objects);
* chumpy objects (any ``chumpy.*`` global) as :class:`ChumpyStub`, whose ``x`` array is kept, and
  ``scipy.sparse`` csc/csr/coo matrices (SMPL's ``J_regressor``);
* joblib's ``NumpyArrayWrapper`` (joblib writes each array's raw bytes after the pickle stream); object
  arrays in it (a nested pickle) go through this same unpickler. Compressed joblib files (zlib, gzip,
  bz2, lzma, xz, lz4) are decompressed by joblib's file-object helper.

**No allowed global allocates from a number in the file.** The Python unpickler's call opcodes are
checked before they run: ``REDUCE``/``INST``/``OBJ`` may call only dtypes, scalars, ``_frombuffer``
(whose size is its buffer's), ``_reconstruct`` with numpy's own ``(0,)`` shape, containers of objects
already in the file, ``int``/``float``/``str``/``complex``/``slice``/``bool`` and latin-1 ``encode``;
``bytes``/``bytearray`` only of an existing buffer, never of a count; ``NEWOBJ`` only without arguments;
an array's ``BUILD`` state must carry exactly as much data as its declared shape needs; a sparse
matrix's dense size is checked before it is expanded. So ``builtins.bytearray(2e9)``,
``numpy.ndarray((10**9,))`` or an object array of declared shape (10**9,) are refused before any memory
is taken. Any other global raises :class:`UnsafePickleError` naming it.

**Every call's cost is bounded by its arguments and counted before it runs.** ``str``/``int``/``float``/
``complex``/``bool``/``slice`` take only numbers, text and bytes (``str(list_dag)`` would format 2**27 lists:
refused by name); the items container constructors copy and the bytes calls and array states materialise are
added to a per-stream budget (:data:`smplik.limits.PICKLE_OBJECTS`, :data:`smplik.limits.MEMORY_BYTES`) before
the call; a dict key or set member whose hash would walk more than :data:`MAX_KEY_OBJECTS` objects (a tuple DAG)
is refused before it is hashed (SETITEM(S), DICT, ADDITEMS, FROZENSET and ``dict``/``set`` calls). The whole
object graph is checked once more after loading (:func:`check_object_graph`). Files are read as a stream
capped at :data:`smplik.limits.PICKLE_BYTES` (:class:`smplik.limits.CappedReader`): a compressed pickle is
inflated only as far as the unpickler reads, never whole.

Opt-in for files you produced yourself: ``trust_pickle=True`` (CLI ``--trust-pickle``) loads estimator
pickles with plain :func:`joblib.load`, i.e. runs whatever the file says.
"""

from __future__ import annotations

import collections
import io
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

TRUST_HINT = ("Only if you trust the file's source, pass --trust-pickle (trust_pickle=True) to load it with "
              "plain joblib/pickle, which can run arbitrary code.")


class UnsafePickleError(pickle.UnpicklingError, ValueError):
    """The pickle asks for a global or a call outside the allowed set (the message names it)."""


MAX_DEPTH = 200
"""Deepest nesting of containers a pickle may hold (real files nest a few levels)."""


def check_object_graph(obj: Any, source: str = "pickle") -> None:
    """Refuse an unpickled object whose containers expand to more than :data:`smplik.limits.PICKLE_OBJECTS`
    objects, counting a shared reference each time it is reachable (a DAG of shared lists, a few KB on disk,
    counts as the tree that ``repr``, ``np.asarray`` or a JSON dump would walk), nest deeper than
    :data:`MAX_DEPTH`, or hold a reference cycle. Runs in time linear in the distinct objects (sizes are
    memoised), never expanding anything.

    Raises:
        UnsafePickleError: naming ``source`` and the limit (and its environment variable).
    """
    from smplik.limits import PICKLE_OBJECTS

    limit = PICKLE_OBJECTS.value
    size: dict[int, int] = {}
    keep: list[Any] = []  # ids stay valid while the objects are referenced
    stack: list[tuple[Any, bool, int]] = [(obj, False, 0)]
    on_path: set[int] = set()
    while stack:
        node, done, depth = stack.pop()
        key = id(node)
        children = _children(node)
        if children is None:
            continue
        if done:
            on_path.discard(key)
            total = 1 + sum(size.get(id(c), 1) for c in children)
            size[key] = total
            if total > limit:
                raise UnsafePickleError(f"{source}: its objects expand to more than {limit} (shared references "
                                        f"counted each time; set {PICKLE_OBJECTS.env} to raise the limit if the file "
                                        "is genuine).")
            continue
        if key in size:
            continue
        if key in on_path:
            raise UnsafePickleError(f"{source}: its objects form a reference cycle.")
        if depth > MAX_DEPTH:
            raise UnsafePickleError(f"{source}: containers nested deeper than {MAX_DEPTH} levels.")
        on_path.add(key)
        keep.append(node)
        stack.append((node, True, depth))
        stack.extend((c, False, depth + 1) for c in children if id(c) not in size)


def _children(node: Any) -> list[Any] | None:
    """The objects a container refers to (None for a leaf: numbers, strings, numeric arrays)."""
    if isinstance(node, dict):
        return [*node.keys(), *node.values()]
    if isinstance(node, (list, tuple, set, frozenset)):
        return list(node)
    if isinstance(node, np.ndarray):
        return list(node.ravel()) if node.dtype.hasobject else None
    if isinstance(node, ChumpyStub) or (hasattr(node, "__dict__") and not isinstance(node, type)):
        return list(vars(node).values())
    return None


def sparse_to_dense(matrix: Any, source: str) -> np.ndarray:
    """A ``scipy.sparse`` csr/csc/coo matrix read from a pickle, as a dense float64 array.

    A pickle sets the matrix's index arrays directly (scipy checks nothing), and scipy's C code reads
    memory at whatever index they hold: an index of 1e9 or -5 crashes the process or corrupts memory.
    So every array is checked here first (1-D integers, ``indptr`` starting at 0, non-decreasing, ending
    at ``nnz``; every index within the shape; finite data) and the dense matrix is built with numpy,
    its size checked by :func:`smplik.limits.check_array`.

    Raises:
        ValueError: naming ``source`` and the array at fault.
    """
    from smplik.limits import check_array

    kind = type(matrix).__name__[:3]
    state = vars(matrix)
    shape = state.get("_shape", state.get("shape"))
    if not (isinstance(shape, tuple) and len(shape) == 2 and all(type(n) is int and n >= 0 for n in shape)):
        raise ValueError(f"{source}: a sparse matrix with shape {shape!r:.60}.")
    check_array(shape, 8, source)
    rows, cols = shape

    def array(name: str, integer: bool) -> np.ndarray:
        value = state.get(name)
        kinds, noun = ("iu", "integers") if integer else ("iufb", "numbers")
        if not isinstance(value, np.ndarray) or value.ndim != 1 or value.dtype.kind not in kinds:
            raise ValueError(f"{source}: sparse '{name}' must be a 1-D array of {noun}.")
        return value

    data = array("data", False).astype(np.float64)
    if not np.isfinite(data).all():
        raise ValueError(f"{source}: sparse 'data' contains NaN or inf.")
    if kind in ("csr", "csc"):
        indices, indptr = array("indices", True).astype(np.int64), array("indptr", True).astype(np.int64)
        major, minor = (rows, cols) if kind == "csr" else (cols, rows)
        if len(indptr) != major + 1 or indptr[0] != 0 or (np.diff(indptr) < 0).any():
            raise ValueError(f"{source}: sparse 'indptr' is not {major + 1} non-decreasing offsets from 0.")
        if indptr[-1] != len(indices) or len(indices) != len(data):
            raise ValueError(f"{source}: sparse 'indptr' ends at {indptr[-1]} but there are {len(indices)} indices "
                             f"and {len(data)} values.")
        if len(indices) and (indices.min() < 0 or indices.max() >= minor):
            raise ValueError(f"{source}: sparse 'indices' outside [0, {minor - 1}].")
        major_index = np.repeat(np.arange(major), np.diff(indptr))
        r, c = (major_index, indices) if kind == "csr" else (indices, major_index)
    elif kind == "coo":
        coords = state.get("coords")
        if isinstance(coords, tuple) and len(coords) == 2:
            state = {**state, "row": coords[0], "col": coords[1]}
        r, c = (array(n, True).astype(np.int64) for n in ("row", "col")) if "row" in state else (None, None)
        if r is None or len(r) != len(data) or len(c) != len(data):
            raise ValueError(f"{source}: sparse 'row'/'col' do not match its {len(data)} values.")
        if len(data) and (r.min() < 0 or r.max() >= rows or c.min() < 0 or c.max() >= cols):
            raise ValueError(f"{source}: sparse row/column indices outside its shape {shape}.")
    else:
        raise ValueError(f"{source}: unsupported sparse matrix type {type(matrix).__name__}.")
    dense = np.zeros(shape, np.float64)
    np.add.at(dense, (r, c), data)
    return dense


class ChumpyStub:
    """Stands in for any chumpy object while unpickling; only its ``x`` array is kept."""

    def __setstate__(self, state: Any) -> None:
        self.state = state

    def to_array(self) -> np.ndarray | None:
        """The plain array held by the chumpy object, or None when it holds none."""
        state = getattr(self, "state", None)
        if isinstance(state, dict):
            for key in ("x", "a", "_x"):
                if key in state:
                    value = state[key]
                    return value.to_array() if isinstance(value, ChumpyStub) else np.asarray(value)
        return None


def _encode_latin1(text: Any, encoding: str = "utf-8", errors: str = "strict") -> bytes:
    """``_codecs.encode`` as protocol-2 pickles of bytes use it (latin-1 text only)."""
    if not isinstance(text, str) or encoding.replace("_", "-").lower() not in ("latin1", "latin-1", "iso-8859-1"):
        raise UnsafePickleError(f"Refusing _codecs.encode({type(text).__name__}, {encoding!r}) in a pickle: only "
                                "latin-1 text (protocol-2 bytes) is allowed.")
    return text.encode("latin-1", errors)


def _reconstructor(cls: Any, base: Any, state: Any) -> Any:
    """``copyreg._reconstructor`` of plain objects only (``base`` object, no state)."""
    if base is not object or state is not None or not isinstance(cls, type):
        raise UnsafePickleError("Refusing copyreg._reconstructor with a base other than object in a pickle.")
    return object.__new__(cls)


def _numpy_multiarray() -> Any:
    try:
        import numpy._core.multiarray as ma
    except ImportError:  # numpy < 2
        import numpy.core.multiarray as ma  # type: ignore[no-redef]
    return ma


def _frombuffer_function() -> Any:
    try:
        from numpy._core.numeric import _frombuffer
    except ImportError:  # numpy < 2
        from numpy.core.numeric import _frombuffer  # type: ignore[no-redef]
    return _frombuffer


_STORAGE_DTYPES = {"FloatStorage": np.float32, "DoubleStorage": np.float64, "HalfStorage": np.float16,
                   "LongStorage": np.int64, "IntStorage": np.int32, "ShortStorage": np.int16, "CharStorage": np.int8,
                   "ByteStorage": np.uint8, "BoolStorage": np.bool_}
"""torch's legacy storage classes (as ``torch.save(storage)`` names them) and the numpy dtypes of their data."""
_STORAGE_NUMPY = tuple(np.dtype(t) for t in _STORAGE_DTYPES.values())


class _StorageRecordUnpickler(pickle._Unpickler):  # type: ignore[name-defined, misc]
    """Reads the one record of a legacy ``torch.save(storage)`` stream: torch's storage class names become numpy
    dtypes and the persistent id ``('storage', dtype, key, location, numel, view)`` is returned as a tuple."""

    dispatch = None  # set below (the restricted table)

    def find_class(self, module: str, name: str) -> Any:
        if module == "torch" and name in _STORAGE_DTYPES:
            return np.dtype(_STORAGE_DTYPES[name])
        return allowed_global(module, name)

    def persistent_load(self, pid: Any) -> Any:
        if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage" and isinstance(pid[1], np.dtype)
                and pid[1] in _STORAGE_NUMPY and isinstance(pid[2], str)):
            raise UnsafePickleError(f"Refusing a torch storage record {pid!r:.80} in a pickle.")
        return pid

    def _instantiate(self, klass: Any, args: Any) -> None:
        _check_call(klass, tuple(args), budget=_budget(self))
        super()._instantiate(klass, args)


def storage_bytes_to_array(data: bytes) -> np.ndarray:
    """The flat array of a pickled torch storage (``torch.storage._load_from_bytes``'s argument: a legacy
    ``torch.save`` of one storage), parsed without torch and without allocating more than ``data`` holds.

    The stream is: magic number, protocol version, system info (three small pickles), the storage record
    (a persistent id naming the class, i.e. the dtype), the list of storage keys, then per key an 8-byte
    little-endian element count and the raw little-endian elements.

    Raises:
        UnsafePickleError: any other layout, class or byte order.
    """
    fh = io.BytesIO(bytes(data))
    try:
        magic = RestrictedUnpickler(fh).load()
        RestrictedUnpickler(fh).load()  # protocol version
        info = RestrictedUnpickler(fh).load()
        if magic != 0x1950A86A20F9469CFC6C or not isinstance(info, dict) or not info.get("little_endian", False):
            raise UnsafePickleError("Refusing a torch storage that is not a little-endian legacy torch.save stream.")
        unpickler = _StorageRecordUnpickler(fh)
        record = unpickler.load()
        keys = RestrictedUnpickler(fh).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, IndexError, KeyError, AttributeError) as exc:
        if isinstance(exc, UnsafePickleError):
            raise
        raise UnsafePickleError(f"Refusing a corrupt torch storage in a pickle ({type(exc).__name__}).") from None
    if not (isinstance(record, tuple) and len(record) >= 5 and isinstance(keys, list) and keys == [record[2]]):
        raise UnsafePickleError("Refusing a torch storage record that does not hold exactly one storage.")
    dtype: np.dtype = record[1]
    count = int.from_bytes(fh.read(8), "little", signed=True)
    raw = fh.read()
    if count < 0 or count * dtype.itemsize != len(raw):
        raise UnsafePickleError(f"Refusing a torch storage declaring {count} elements but holding {len(raw)} bytes.")
    return np.frombuffer(raw, dtype=dtype.newbyteorder("<")).astype(dtype)


def rebuild_tensor_as_array(storage: Any, offset: Any, size: Any, stride: Any, *_: Any) -> np.ndarray:
    """``torch._utils._rebuild_tensor_v2(storage, offset, size, stride, requires_grad, hooks[, metadata])`` as a
    numpy array (a copy), every index checked to lie inside ``storage`` (a flat array from
    :func:`storage_bytes_to_array`) and the result's size checked before it is allocated."""
    ints = lambda v: isinstance(v, tuple) and all(type(n) is int and n >= 0 for n in v)  # noqa: E731
    if not (isinstance(storage, np.ndarray) and storage.ndim == 1 and type(offset) is int and offset >= 0
            and ints(size) and ints(stride) and len(size) == len(stride)):
        raise UnsafePickleError("Refusing a torch tensor with an invalid storage, offset, size or stride in a pickle.")
    _check_declared(size, storage.dtype.itemsize)
    if any(n == 0 for n in size):
        return np.zeros(size, storage.dtype)
    last = offset + sum((n - 1) * s for n, s in zip(size, stride, strict=True))
    if last >= storage.shape[0]:
        raise UnsafePickleError(f"Refusing a torch tensor of size {size} reaching element {last} of a storage of "
                                f"{storage.shape[0]} in a pickle.")
    view = np.lib.stride_tricks.as_strided(storage[offset:], shape=size,
                                           strides=tuple(s * storage.dtype.itemsize for s in stride), writeable=False)
    return np.array(view)


_BUILTINS = {"dict", "list", "tuple", "set", "frozenset", "bytearray", "bytes", "complex", "slice",
             "int", "float", "str", "bool", "object"}
_NUMPY_MODULES = {"numpy", "numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric",
                  "numpy._core.numeric", "numpy.dtypes"}
_SPARSE = ("csc_matrix", "csr_matrix", "coo_matrix")


def allowed_global(module: str, name: str) -> Any:
    """The object the restricted unpickler returns for ``module.name``; raises :class:`UnsafePickleError`."""
    if module in _NUMPY_MODULES:
        if module == "numpy.dtypes" and name.endswith("DType"):
            import numpy.dtypes

            found = getattr(numpy.dtypes, name, None)
            if found is not None:
                return found
        elif name in ("ndarray", "dtype") and module == "numpy":
            return getattr(np, name)
        elif name == "_frombuffer" and module.endswith("numeric"):
            return _frombuffer_function()
        elif name in ("_reconstruct", "scalar") and module.endswith("multiarray"):
            return getattr(_numpy_multiarray(), name)
    if module in ("builtins", "__builtin__") and name in _BUILTINS:
        import builtins

        return getattr(builtins, name)
    if module == "collections" and name in ("OrderedDict", "defaultdict"):
        return getattr(collections, name)
    if (module, name) == ("_codecs", "encode"):
        return _encode_latin1
    if module in ("copy_reg", "copyreg") and name == "_reconstructor":
        return _reconstructor
    if module == "chumpy" or module.startswith("chumpy."):
        return ChumpyStub
    if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
        return rebuild_tensor_as_array
    if (module, name) == ("torch.storage", "_load_from_bytes"):
        return storage_bytes_to_array
    if module.startswith("scipy.sparse") and name in _SPARSE:
        import scipy.sparse

        return getattr(scipy.sparse, name)
    raise UnsafePickleError(f"Refusing to load global '{module}.{name}' from a pickle: only numpy arrays, builtin "
                            f"containers and chumpy/scipy arrays are allowed (a pickle can run arbitrary code). "
                            f"{TRUST_HINT}")


def _declared_bytes(shape: Any, itemsize: int) -> int:
    if not isinstance(shape, tuple) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise UnsafePickleError(f"Refusing an array of shape {shape!r:.60} in a pickle.")
    count = 1
    for n in shape:
        count *= n
    return count * max(int(itemsize), 1)


def _check_declared(shape: tuple, itemsize: int) -> None:
    """A declared array within :func:`smplik.limits.check_array`'s limits, as an :class:`UnsafePickleError`."""
    from smplik.limits import LimitError, check_array

    try:
        check_array(shape, itemsize, "an array in a pickle")
    except LimitError as exc:
        raise UnsafePickleError(f"Refusing {exc}") from None


_SCALARS = (type(None), bool, int, float, complex, str, bytes, bytearray)
"""What a scalar constructor (``int``, ``float``, ``str``, ``complex``, ``bool``, ``slice``) may take: its cost is
the argument's own length, never a walk over objects (``str(list_dag)`` would format 2**27 lists)."""
MAX_KEY_OBJECTS = 10_000
"""Most objects a dict key or set member may expand to: hashing a tuple walks it (shared references each
time), so a tuple DAG of a few bytes as a key would hash for ever."""


class _CallBudget:
    """What the calls of one pickle stream have materialised so far: container items they copied (within
    :data:`smplik.limits.PICKLE_OBJECTS`) and bytes they allocated (within :data:`smplik.limits.MEMORY_BYTES`).
    Every call adds its cost, computed from its arguments, *before* it runs."""

    def __init__(self) -> None:
        from smplik.limits import MEMORY_BYTES, PICKLE_OBJECTS

        self.objects = self.bytes = 0
        self.object_limit, self.byte_limit = PICKLE_OBJECTS, MEMORY_BYTES
        self.max_objects, self.max_bytes = PICKLE_OBJECTS.value, MEMORY_BYTES.value

    def add(self, *, objects: int = 0, nbytes: int = 0) -> None:
        self.objects += objects
        self.bytes += nbytes
        for used, cap, limit in ((self.objects, self.max_objects, self.object_limit),
                                 (self.bytes, self.max_bytes, self.byte_limit)):
            if used > cap:
                raise UnsafePickleError(f"Refusing a pickle whose calls would materialise more than {cap} "
                                        f"{limit.what} (set {limit.env} to raise the limit if the file is genuine).")


def _check_key(key: Any) -> None:
    """A dict key / set member whose hash costs at most :data:`MAX_KEY_OBJECTS` objects (tuples walked with
    shared references counted each time, sizes memoised: linear in the distinct objects)."""
    if not isinstance(key, (tuple, frozenset)):
        return
    size: dict[int, int] = {}
    stack: list[tuple[Any, bool]] = [(key, False)]
    while stack:
        node, done = stack.pop()
        if done:
            total = 1 + sum(size.get(id(c), 1) for c in node)
            if total > MAX_KEY_OBJECTS:
                raise UnsafePickleError(f"Refusing a dict key or set member that expands to more than "
                                        f"{MAX_KEY_OBJECTS} objects in a pickle (hashing it would not end).")
            size[id(node)] = total
            continue
        if id(node) in size:
            continue
        if len(stack) > MAX_KEY_OBJECTS:
            raise UnsafePickleError(f"Refusing a dict key or set member of more than {MAX_KEY_OBJECTS} objects in "
                                    "a pickle.")
        stack.append((node, True))
        stack.extend((c, False) for c in node if isinstance(c, (tuple, frozenset)) and id(c) not in size)


def _check_call(func: Any, args: Any, kwargs: Any = None, budget: _CallBudget | None = None) -> None:
    """Refuse a call from the pickle stream whose cost is not bounded by its arguments' own sizes (see the
    module docstring), and add that cost to ``budget`` before the call runs."""
    budget = _CallBudget() if budget is None else budget
    if kwargs:
        raise UnsafePickleError("Refusing a call with keyword arguments in a pickle.")
    if not isinstance(args, tuple):
        raise UnsafePickleError("Refusing a call whose arguments are not a tuple in a pickle.")
    ma = _numpy_multiarray()
    name = getattr(func, "__name__", type(func).__name__)
    if func is ma._reconstruct:
        if len(args) != 3 or args[1] != (0,):
            raise UnsafePickleError(f"Refusing numpy _reconstruct{args!r:.60} in a pickle (numpy writes shape (0,)).")
        if not (isinstance(args[0], type) and issubclass(args[0], np.ndarray)):
            raise UnsafePickleError("Refusing numpy _reconstruct of a non-array class in a pickle.")
        return
    if func in (bytes, bytearray):
        if args and not isinstance(args[0], (bytes, bytearray, str)):
            raise UnsafePickleError(f"Refusing builtins.{name}({type(args[0]).__name__}) in a pickle: only bytes "
                                    "from the file are allowed, never a size.")
        if len(args) > 1 and not all(isinstance(a, str) for a in args[1:]):
            raise UnsafePickleError(f"Refusing builtins.{name} with a non-text encoding in a pickle.")
        budget.add(nbytes=len(args[0]) if args else 0)
        return
    if func in (list, tuple, set, frozenset, dict, collections.OrderedDict):
        if len(args) > 1 or (args and not isinstance(args[0], (list, tuple, set, frozenset, dict))):
            raise UnsafePickleError(f"Refusing builtins.{name}({type(args[0]).__name__}) in a pickle.")
        if args:
            budget.add(objects=len(args[0]))
            if func in (set, frozenset) and not isinstance(args[0], (set, frozenset, dict)):
                for item in args[0]:  # hashed by the call (members of a set or keys of a dict are hashed already)
                    _check_key(item)
            elif func in (dict, collections.OrderedDict) and not isinstance(args[0], dict):
                for item in args[0]:  # (key, value) pairs
                    _check_key(item[0] if isinstance(item, (tuple, list)) and item else item)
        return
    if func is collections.defaultdict:
        if len(args) > 1 or (args and args[0] not in (None, list, dict, set, tuple, int, float, str)):
            raise UnsafePickleError("Refusing collections.defaultdict with a custom factory in a pickle.")
        return
    if func is storage_bytes_to_array:
        if len(args) != 1 or not isinstance(args[0], (bytes, bytearray)):
            raise UnsafePickleError("Refusing torch.storage._load_from_bytes of anything but bytes in a pickle.")
        budget.add(nbytes=len(args[0]))
        return
    if func in (int, float, str, complex, slice, bool):
        bad = next((a for a in args if not isinstance(a, _SCALARS)), None)
        if bad is not None or len(args) > 3:
            raise UnsafePickleError(f"Refusing builtins.{name}({type(bad).__name__}) in a pickle: only numbers, text "
                                    "and bytes are converted, never other objects (whose formatting has no bound).")
        budget.add(nbytes=sum(len(a) for a in args if isinstance(a, (str, bytes, bytearray))))
        return
    if func is _encode_latin1:
        budget.add(nbytes=len(args[0]) if args and isinstance(args[0], str) else 0)
        return
    if func is np.dtype or (isinstance(func, type) and issubclass(func, np.dtype)):
        if not all(isinstance(a, (str, bool, int, type(None))) for a in args) or any(
                isinstance(a, str) and len(a) > 64 for a in args):
            raise UnsafePickleError(f"Refusing numpy.dtype{args!r:.60} in a pickle (a short type code only).")
        return
    if func is ma.scalar:
        if not args or not isinstance(args[0], np.dtype) or len(args) > 2 or (
                len(args) == 2 and not isinstance(args[1], (bytes, bytearray, int, float, complex, str))):
            raise UnsafePickleError("Refusing numpy scalar() of anything but a dtype and its bytes in a pickle.")
        _check_declared((1,), args[0].itemsize)
        budget.add(nbytes=args[0].itemsize)
        return
    if func is rebuild_tensor_as_array:
        size = args[2] if len(args) > 2 else None
        if isinstance(args[0] if args else None, np.ndarray) and isinstance(size, tuple):
            budget.add(nbytes=_declared_bytes(size, args[0].dtype.itemsize))
        return
    if func in (_frombuffer_function(), _reconstructor):  # a view of the file's bytes / an empty object
        return
    raise UnsafePickleError(f"Refusing to call {getattr(func, '__module__', '?')}.{name} in a pickle.")


def _check_array_state(inst: np.ndarray, state: Any, budget: _CallBudget | None = None) -> None:
    """An array's ``__setstate__`` allocates its declared shape before checking the data: check first (and add
    the copy it makes to ``budget``)."""
    if not (isinstance(state, tuple) and len(state) in (4, 5)):
        raise UnsafePickleError("Refusing an array state of unexpected form in a pickle.")
    shape, dtype, data = state[-4], state[-3], state[-1]
    if not isinstance(dtype, np.dtype):
        raise UnsafePickleError("Refusing an array state without a dtype in a pickle.")
    size = _declared_bytes(shape, dtype.itemsize)
    _check_declared(shape, dtype.itemsize)
    count = size // max(dtype.itemsize, 1)
    if dtype.hasobject:
        if not isinstance(data, list) or len(data) != count:
            raise UnsafePickleError(f"Refusing an object array of shape {shape} whose data does not match it.")
    elif not isinstance(data, (bytes, bytearray)) or len(data) != size:
        raise UnsafePickleError(f"Refusing an array of shape {shape} whose data does not match it.")
    if budget is not None:
        budget.add(objects=count if dtype.hasobject else 0, nbytes=size)


def _budget(unpickler: Any) -> _CallBudget:
    """The call budget of one unpickler (made at its first call)."""
    budget = getattr(unpickler, "_smplik_budget", None)
    if budget is None:
        budget = unpickler._smplik_budget = _CallBudget()
    return budget


def _after_mark(unpickler: Any) -> list:
    """The items a MARK-terminated opcode (SETITEMS, ADDITEMS, FROZENSET, DICT) is about to take: the stack
    above the last mark (the pure-Python unpickler keeps them in ``stack`` and older stacks in ``metastack``)."""
    return list(unpickler.stack)


def _restricted_dispatch(base: dict) -> dict:
    """``base`` (a pure-Python unpickler's opcode table) with the call opcodes checked first."""
    table = base.copy()

    def load_reduce(self: Any) -> None:
        _check_call(self.stack[-2], self.stack[-1], budget=_budget(self))
        base[pickle.REDUCE[0]](self)

    def load_setitem(self: Any) -> None:
        _check_key(self.stack[-2])
        base[pickle.SETITEM[0]](self)

    def load_setitems(self: Any) -> None:
        for key in _after_mark(self)[::2]:
            _check_key(key)
        base[pickle.SETITEMS[0]](self)

    def load_additems(self: Any) -> None:
        for key in _after_mark(self):
            _check_key(key)
        base[pickle.ADDITEMS[0]](self)

    def load_frozenset(self: Any) -> None:
        for key in _after_mark(self):
            _check_key(key)
        base[pickle.FROZENSET[0]](self)

    def load_dict(self: Any) -> None:
        for key in _after_mark(self)[::2]:
            _check_key(key)
        base[pickle.DICT[0]](self)

    def load_newobj(self: Any) -> None:
        if self.stack[-1] != ():
            raise UnsafePickleError(f"Refusing {getattr(self.stack[-2], '__name__', '?')}.__new__ with arguments "
                                    "in a pickle.")
        base[pickle.NEWOBJ[0]](self)

    def load_newobj_ex(self: Any) -> None:
        if self.stack[-1] or self.stack[-2] != ():
            raise UnsafePickleError("Refusing __new__ with arguments in a pickle.")
        base[pickle.NEWOBJ_EX[0]](self)

    def load_build(self: Any) -> None:
        inst = self.stack[-2]
        if isinstance(inst, np.ndarray):
            _check_array_state(inst, self.stack[-1], _budget(self))
        base[pickle.BUILD[0]](self)

    table[pickle.REDUCE[0]] = load_reduce
    table[pickle.SETITEM[0]] = load_setitem
    table[pickle.SETITEMS[0]] = load_setitems
    table[pickle.ADDITEMS[0]] = load_additems
    table[pickle.FROZENSET[0]] = load_frozenset
    table[pickle.DICT[0]] = load_dict
    table[pickle.NEWOBJ[0]] = load_newobj
    table[pickle.NEWOBJ_EX[0]] = load_newobj_ex
    table[pickle.BUILD[0]] = load_build
    return table


class RestrictedUnpickler(pickle._Unpickler):  # type: ignore[name-defined, misc]
    """The pure-Python unpickler with :func:`allowed_global`'s globals and checked call opcodes."""

    dispatch = _restricted_dispatch(pickle._Unpickler.dispatch)  # type: ignore[attr-defined]

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(f"Refusing a persistent id {pid!r:.60} in a pickle.")

    def find_class(self, module: str, name: str) -> Any:
        return allowed_global(module, name)

    def _instantiate(self, klass: Any, args: Any) -> None:  # INST and OBJ opcodes
        _check_call(klass, tuple(args), budget=_budget(self))
        super()._instantiate(klass, args)

    def load(self) -> Any:
        """The unpickled object, refused by :func:`check_object_graph` when it expands too far."""
        obj = super().load()
        check_object_graph(obj)
        return obj


_StorageRecordUnpickler.dispatch = RestrictedUnpickler.dispatch


def loads_restricted(data: bytes, *, encoding: str = "ASCII") -> Any:
    """Unpickle ``data`` with :class:`RestrictedUnpickler` (``encoding="latin1"`` for Python 2 pickles)."""
    return RestrictedUnpickler(io.BytesIO(data), encoding=encoding).load()


def _joblib_unpickler_class() -> type:
    """joblib's ``NumpyUnpickler`` with the same restrictions, plus its array wrapper."""
    from joblib.numpy_pickle import NumpyArrayWrapper, NumpyUnpickler

    base = NumpyUnpickler.dispatch

    class _Restricted(NumpyUnpickler):  # type: ignore[misc, valid-type]
        dispatch = _restricted_dispatch(base)

        def find_class(self, module: str, name: str) -> Any:
            if module.startswith("joblib") and module.endswith("numpy_pickle") and name == "NumpyArrayWrapper":
                return NumpyArrayWrapper
            return allowed_global(module, name)

        def _instantiate(self, klass: Any, args: Any) -> None:
            _check_call(klass, tuple(args), budget=_budget(self))
            super()._instantiate(klass, args)

        def load_build(self) -> None:
            if isinstance(self.stack[-2], np.ndarray):
                _check_array_state(self.stack[-2], self.stack[-1], _budget(self))
            pickle._Unpickler.load_build(self)  # type: ignore[attr-defined]
            top = self.stack[-1]
            if not isinstance(top, NumpyArrayWrapper):
                return
            wrapper = self.stack.pop()
            if wrapper.subclass not in (np.ndarray, np.memmap):
                raise UnsafePickleError(f"Refusing a joblib array of class {wrapper.subclass!r}; only plain numpy "
                                        f"arrays are allowed. {TRUST_HINT}")
            if not isinstance(wrapper.dtype, np.dtype):
                raise UnsafePickleError("Refusing a joblib array without a dtype.")
            nbytes = _declared_bytes(tuple(wrapper.shape), wrapper.dtype.itemsize)
            _check_declared(tuple(wrapper.shape), wrapper.dtype.itemsize)
            room = getattr(self.file_handle, "room", None)
            if room is not None and not wrapper.dtype.hasobject:
                room(nbytes)  # the stream cannot hold that many more bytes: refused before np.empty
            if wrapper.dtype.hasobject:  # a nested pickle stream: read it with the same restrictions
                self.stack.append(RestrictedUnpickler(self.file_handle).load())
            else:
                self.stack.append(wrapper.read_array(self, self.ensure_native_byte_order))

        dispatch[pickle.BUILD[0]] = load_build

    return _Restricted


_READ_ERRORS = (pickle.UnpicklingError, EOFError, OSError, AttributeError, TypeError, IndexError, KeyError,
                ValueError, OverflowError, MemoryError, RecursionError, UnicodeDecodeError)


def load_pickle(path: str | Path, *, trust_pickle: bool = False) -> Any:
    """Load a pickle or joblib file (plain pickle or joblib, compressed or not).

    Args:
        path: ``.pk``/``.pkl``/``.joblib`` file.
        trust_pickle: load with plain :func:`joblib.load` (runs any code the file names).

    Raises:
        UnsafePickleError: a refused global or call (named), with the opt-in in the message.
        ValueError: missing, unreadable or corrupt file (named).
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"File not found: {path}")
    if trust_pickle:
        import joblib

        return joblib.load(path)
    from joblib.numpy_pickle_utils import _validate_fileobject_and_memmap

    from smplik.limits import CappedReader, LimitError, check_input_file

    check_input_file(path, "pickle")

    def load(encoding: str | None) -> Any:
        """Unpickle straight from the (decompressing) stream, capped at :data:`smplik.limits.PICKLE_BYTES`."""
        with open(path, "rb") as raw, _validate_fileobject_and_memmap(raw, str(path), None) as (fobj, _):
            if isinstance(fobj, str):
                raise ValueError(f"{path}: a joblib < 0.10 multi-file pickle; re-save it with a recent joblib.")
            stream = CappedReader(fobj, f"{path} (decompressed)")
            if encoding is None:
                return _joblib_unpickler_class()(str(path), stream, True).load()
            return RestrictedUnpickler(stream, encoding=encoding).load()

    try:
        try:
            obj = load(None)
        except UnicodeDecodeError:  # Python 2 pickles of numpy arrays need latin1
            obj = load("latin1")
        check_object_graph(obj)
        return obj
    except LimitError:
        raise
    except UnsafePickleError as exc:
        raise UnsafePickleError(f"{path}: {exc}") from None
    except _READ_ERRORS as exc:
        message = str(exc)
        if isinstance(exc, ValueError) and message.startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a readable pickle ({type(exc).__name__}: {message[:200]}).") from None


def read_npz(path: str | Path, *, allow_objects: bool = True) -> dict[str, Any]:
    """Read every array of an ``.npz`` with bounded memory.

    Before anything is decompressed, :func:`smplik.limits.check_npz` checks the zip directory's
    uncompressed sizes and each member's ``.npy`` header against the input budget (a zip bomb, a header
    declaring (10**9, 3), a member holding less than its header declares: refused). Object arrays (e.g.
    ROMP's ``results`` dict, saved with ``np.savez(results=dict)``) are unpickled by
    :class:`RestrictedUnpickler`, never by plain pickle, and refused with ``allow_objects=False``; 0-d
    object arrays are unwrapped to the object they hold.

    Raises:
        UnsafePickleError: a refused global in an object array.
        ValueError: missing, corrupt or oversized file (named; :class:`smplik.limits.LimitError` names the
            limit's environment variable).
    """
    import zlib

    from smplik.limits import CappedReader, check_input_file, check_npz

    path = Path(path)
    if not path.exists():
        raise ValueError(f"File not found: {path}")
    check_input_file(path, ".npz")
    declared = check_npz(path)
    out: dict[str, Any] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for name, (_, dtype) in declared.items():
                with zf.open(name + ".npy") as fh:
                    if dtype.hasobject:
                        if not allow_objects:
                            raise ValueError(f"{path}: array '{name}' holds Python objects (a pickle); "
                                             "only plain numeric arrays are allowed here.")
                        version = np.lib.format.read_magic(fh)
                        header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                  else np.lib.format.read_array_header_2_0)
                        header(fh, max_header_size=10000)
                        value = RestrictedUnpickler(CappedReader(fh, f"{path}: array '{name}'"),
                                                    encoding="latin1").load()
                        if isinstance(value, np.ndarray) and value.shape == () and value.dtype.hasobject:
                            value = value.item()
                        out[name] = value
                        continue
                    out[name] = np.lib.format.read_array(fh, allow_pickle=False)
    except UnsafePickleError as exc:
        raise UnsafePickleError(f"{path}: {exc}") from None
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a readable .npz ({type(exc).__name__}: {str(exc)[:200]}).") from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, pickle.UnpicklingError, EOFError, KeyError,
            TypeError, IndexError, AttributeError, OverflowError, MemoryError, RecursionError, SyntaxError,
            UnicodeDecodeError, NotImplementedError, zlib.error) as exc:
        raise ValueError(f"{path}: not a readable .npz ({type(exc).__name__}: {str(exc)[:200]}).") from None
    return out


def read_npy(path: str | Path) -> Any:
    """One ``.npy`` file: a numeric array as ``np.load(allow_pickle=False)`` reads it, or the object an object
    array holds (``np.save(path, a_dict)``, e.g. TRAM's ``hps_track_*.npy`` dicts of torch tensors, whose
    tensors become numpy arrays) through :class:`RestrictedUnpickler`, never plain pickle.

    Raises:
        UnsafePickleError: a refused global in the object array (named).
        ValueError: a missing or corrupt file (named).
    """
    from smplik.limits import CappedReader, LimitError, check_input_file

    path = Path(path)
    if not path.exists():
        raise ValueError(f"File not found: {path}")
    check_input_file(path, ".npy")
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                      else np.lib.format.read_array_header_2_0)
            _, _, dtype = header(fh, max_header_size=10000)
            if not dtype.hasobject:
                fh.seek(0)
                return np.load(fh, allow_pickle=False)
            value = RestrictedUnpickler(CappedReader(fh, str(path)), encoding="latin1").load()
    except LimitError:
        raise
    except UnsafePickleError as exc:
        raise UnsafePickleError(f"{path}: {exc}") from None
    except _READ_ERRORS as exc:
        raise ValueError(f"{path}: not a readable .npy ({type(exc).__name__}: {str(exc)[:200]}).") from None
    if isinstance(value, np.ndarray) and value.shape == () and value.dtype.hasobject:
        value = value.item()
    return value
