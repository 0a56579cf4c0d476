"""Loading pickles from unknown sources without running their code.

A pickle names Python callables that the loader calls (``os.system`` is one line away), so
estimator outputs (HybrIK ``.pk``, 4D-Humans/PHALP, WHAM and PyMAF-X joblib ``.pkl``) are read by
a restricted unpickler that resolves only:

* numpy arrays, dtypes and scalars (``numpy[._core].multiarray._reconstruct``/``scalar``,
  ``numpy.ndarray``, ``numpy.dtype`` and numpy 2's ``numpy.dtypes.*DType`` classes);
* builtin containers and values (dict, list, tuple, set, frozenset, bytearray, complex, slice,
  range, ``collections.OrderedDict``/``defaultdict``, ``_codecs.encode`` for protocol-2 bytes);
* joblib's ``NumpyArrayWrapper``: joblib writes each array's raw bytes after the pickle stream
  and the wrapper tells the reader its dtype/shape/order. The wrapper is resolved to a plain data
  holder; the array bytes are read by joblib's own reader for plain dtypes, while object-dtype
  arrays (a nested pickle) go through this same restricted unpickler. Compressed joblib files
  (zlib, gzip, bz2, lzma, xz, lz4) are decompressed by joblib's file-object helper.

Any other global raises :class:`UnsafePickleError` naming it and the opt-in: ``trust_pickle=True``
(CLI ``--trust-pickle``) loads with plain :func:`joblib.load` (which also reads plain pickles),
i.e. runs whatever the file says. Only use it for files you produced yourself.
"""

from __future__ import annotations

import collections
import io
import pickle
from pathlib import Path
from typing import Any

TRUST_HINT = ("Only if you trust the file's source, pass --trust-pickle (trust_pickle=True) to load it with "
              "plain joblib/pickle, which can run arbitrary code.")


class UnsafePickleError(pickle.UnpicklingError, ValueError):
    """The pickle asks for a global outside the allowed set (numpy arrays and builtin containers)."""


_BUILTINS = {"dict", "list", "tuple", "set", "frozenset", "bytearray", "bytes", "complex", "slice", "range",
             "int", "float", "str", "bool"}
_NUMPY_MODULES = {"numpy", "numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric",
                  "numpy._core.numeric", "numpy.dtypes"}
_NUMPY_NAMES = {"_reconstruct", "scalar", "ndarray", "dtype", "_frombuffer"}


def _resolve_numpy(module: str, name: str) -> Any | None:
    import numpy as np

    if module not in _NUMPY_MODULES:
        return None
    if module == "numpy.dtypes":
        if name.endswith("DType"):
            import numpy.dtypes

            return getattr(numpy.dtypes, name, None)
        return None
    if name not in _NUMPY_NAMES:
        return None
    if name in ("ndarray", "dtype"):
        return getattr(np, name)
    if name == "_frombuffer":
        try:
            from numpy._core.numeric import _frombuffer
        except ImportError:  # numpy < 2
            from numpy.core.numeric import _frombuffer  # type: ignore[no-redef]
        return _frombuffer
    try:
        import numpy._core.multiarray as ma
    except ImportError:  # numpy < 2
        import numpy.core.multiarray as ma  # type: ignore[no-redef]
    return getattr(ma, name)


def allowed_global(module: str, name: str) -> Any:
    """The object a restricted unpickler may return for ``module.name``; raises :class:`UnsafePickleError`."""
    found = _resolve_numpy(module, name)
    if found is not None:
        return found
    if module in ("builtins", "__builtin__") and name in _BUILTINS:
        import builtins

        return getattr(builtins, name)
    if module == "collections" and name in ("OrderedDict", "defaultdict"):
        return getattr(collections, name)
    if (module, name) == ("_codecs", "encode"):
        import codecs

        return codecs.encode
    raise UnsafePickleError(f"Refusing to load global '{module}.{name}' from a pickle: only numpy arrays and builtin "
                            f"containers are allowed (a pickle can run arbitrary code). {TRUST_HINT}")


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` that resolves only :func:`allowed_global`'s globals."""

    def find_class(self, module: str, name: str) -> Any:
        return allowed_global(module, name)


def _joblib_unpickler_class() -> type:
    """A joblib ``NumpyUnpickler`` restricted to :func:`allowed_global` plus the array wrapper."""
    from joblib.numpy_pickle import NumpyArrayWrapper, NumpyUnpickler

    class _Restricted(NumpyUnpickler):  # type: ignore[misc, valid-type]
        dispatch = NumpyUnpickler.dispatch.copy()

        def find_class(self, module: str, name: str) -> Any:
            if module.startswith("joblib") and module.endswith("numpy_pickle") and name == "NumpyArrayWrapper":
                return NumpyArrayWrapper
            return allowed_global(module, name)

        def load_build(self) -> None:
            pickle._Unpickler.load_build(self)  # type: ignore[attr-defined]
            top = self.stack[-1]
            if not isinstance(top, NumpyArrayWrapper):
                return
            wrapper = self.stack.pop()
            import numpy as np

            if wrapper.subclass not in (np.ndarray, np.memmap):
                raise UnsafePickleError(f"Refusing a joblib array of class {wrapper.subclass!r}; only plain numpy "
                                        f"arrays are allowed. {TRUST_HINT}")
            if wrapper.dtype.hasobject:  # a nested pickle stream: read it with the same restrictions
                inner = RestrictedUnpickler(self.file_handle)
                self.stack.append(inner.load())
            else:
                self.stack.append(wrapper.read_array(self, self.ensure_native_byte_order))

        dispatch[pickle.BUILD[0]] = load_build

    return _Restricted


def load_pickle(path: str | Path, *, trust_pickle: bool = False) -> Any:
    """Load a pickle or joblib file.

    Args:
        path: ``.pk``/``.pkl``/``.joblib`` file (plain pickle or joblib, compressed or not).
        trust_pickle: load with plain :func:`joblib.load` (runs any code the file names).

    Raises:
        UnsafePickleError: a refused global (named), with the opt-in in the message.
        ValueError: unreadable or corrupt file.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"File not found: {path}")
    if trust_pickle:
        import joblib

        return joblib.load(path)
    from joblib.numpy_pickle_utils import _validate_fileobject_and_memmap

    unpickler_cls = _joblib_unpickler_class()
    try:
        with open(path, "rb") as raw, _validate_fileobject_and_memmap(raw, str(path), None) as (fobj, _):
            if isinstance(fobj, str):
                raise ValueError(f"{path}: a joblib < 0.10 multi-file pickle; re-save it with a recent joblib.")
            data = fobj.read()
        return unpickler_cls(str(path), io.BytesIO(data), True).load()
    except UnsafePickleError as exc:
        raise UnsafePickleError(f"{path}: {exc}") from None
    except (pickle.UnpicklingError, EOFError, OSError, AttributeError, TypeError, IndexError) as exc:
        raise ValueError(f"{path}: not a readable pickle ({type(exc).__name__}: {exc}).") from exc
    except UnicodeDecodeError:
        try:  # Python 2 pickles of numpy arrays need latin1
            return RestrictedUnpickler(io.BytesIO(path.read_bytes()), encoding="latin1").load()
        except UnsafePickleError:
            raise
        except Exception as exc:  # noqa: BLE001 - any failure here means an unreadable file
            raise ValueError(f"{path}: not a readable pickle ({type(exc).__name__}: {exc}).") from exc


def load_npz(path: str | Path) -> dict[str, Any]:
    """Read every array of an ``.npz``; object arrays (e.g. ROMP's ``results`` dict, saved with
    ``np.savez(results=dict)``) are unpickled by :class:`RestrictedUnpickler`, never by plain pickle.

    0-d object arrays are unwrapped to the object they hold.
    """
    import zipfile

    import numpy as np

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"File not found: {path}")
    out: dict[str, Any] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for member in zf.namelist():
                if not member.endswith(".npy"):
                    continue
                with zf.open(member) as fh:
                    fp = io.BytesIO(fh.read())
                version = np.lib.format.read_magic(fp)
                reader = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                          else np.lib.format.read_array_header_2_0)
                shape, fortran, dtype = reader(fp)
                if dtype.hasobject:
                    value = RestrictedUnpickler(fp, encoding="latin1").load()
                    if isinstance(value, np.ndarray) and value.shape == () and value.dtype.hasobject:
                        value = value.item()
                else:
                    fp.seek(0)
                    value = np.lib.format.read_array(fp, allow_pickle=False)
                out[member[:-4]] = value
    except UnsafePickleError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, pickle.UnpicklingError, EOFError) as exc:
        raise ValueError(f"{path}: not a readable .npz ({type(exc).__name__}: {exc}).") from exc
    return out
