"""Atomic file writes: write to a temporary file in the target folder, then rename.

A crash or Ctrl-C mid-write never leaves a half-written file and never destroys the previous one.
Temporary files are named ``.NAME.PID-XXXXXXXX.tmp.EXT`` next to the target ``NAME``; one left by a
killed process (SIGKILL cannot be caught) is removed by the next write to the same path once its
process is gone (and, for names without a process id, once it is over an hour old).
"""

from __future__ import annotations

import contextlib
import errno
import glob
import io
import json
import os
import re
import tempfile
import time
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it replaces ``path``, on error it is removed.

    ``suffix`` (default: ``path``'s own suffix) lets writers that insist on an extension
    (``np.savez``, ``matplotlib``) write to the temporary name unchanged.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a folder, not a file", str(path))
    if path.exists() and not path.is_file():  # never replace a device, pipe or socket by a regular file
        raise OSError(errno.EINVAL, "is not a regular file (a device, pipe or socket); give a file path", str(path))
    for parent in path.parents:  # mkdir says "File exists" for a file in the way: name the real problem
        if parent.exists():
            if not parent.is_dir():
                raise NotADirectoryError(errno.ENOTDIR, f"{parent} is a file, not a folder", str(path))
            break
    path.parent.mkdir(parents=True, exist_ok=True)
    ext = path.suffix if suffix is None else suffix
    remove_stale_temp_files(path, ext)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}-", suffix=".tmp" + ext, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp creates 0600; give the final file the usual mode
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


STALE_AGE_S = 3600.0
"""Age after which a temporary file of ours without a process id in its name counts as stale."""
_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?:(?P<pid>\d+)-)?[A-Za-z0-9_]{8}\.tmp(?P<ext>.*)$")


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` may still be running (this one, or one that exists; when unsure: yes, so that a
    leftover of ours is kept rather than removed under a live writer)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # exists (another user's), or cannot tell: keep the file
    return True


def remove_stale_temp_files(path: str | Path, suffix: str | None = None) -> list[Path]:
    """Remove our leftover temporary files for ``path`` (``.NAME.PID-XXXXXXXX.tmp.EXT``) whose writer is gone.

    Returns the removed paths. Files of a live process are kept (it may still be writing)."""
    path = Path(path)
    ext = path.suffix if suffix is None else suffix
    removed = []
    try:
        candidates = list(path.parent.glob(f".{glob.escape(path.name)}.*.tmp{glob.escape(ext)}"))
    except OSError:
        return removed
    for candidate in candidates:
        m = _TEMP_NAME.match(candidate.name)
        if m is None or m["name"] != path.name or m["ext"] != ext:
            continue
        try:
            if m["pid"] is not None:
                stale = not process_alive(int(m["pid"]))
            else:
                stale = time.time() - candidate.stat().st_mtime > STALE_AGE_S
            if stale and candidate.is_file():
                candidate.unlink()
                removed.append(candidate)
        except OSError:
            continue
    return removed


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | Path, obj: Any, indent: int = 2) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically."""
    return write_text_atomic(path, json.dumps(obj, indent=indent) + "\n")


def savez_atomic(path: str | Path, compressed: bool = True, **arrays: np.ndarray) -> Path:
    """``np.savez[_compressed]`` to ``path`` atomically (``path`` should end in ``.npz``)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            (np.savez_compressed if compressed else np.savez)(fh, **arrays)
    return Path(path)


NPZ_DATE = (1980, 1, 1, 0, 0, 0)
"""The fixed zip member date of :func:`write_npz_deterministic`."""


def write_npz_deterministic(path: str | Path, arrays: Mapping[str, np.ndarray], *, compressed: bool = True) -> Path:
    """The one deterministic ``.npz`` writer: bytes depend only on the arrays (sorted keys, fixed zip dates,
    fixed member modes), unlike ``np.savez`` which stamps each member with the current time. Atomic.

    Args:
        path: the target ``.npz``.
        arrays: name -> array (plain dtypes; object arrays are refused).
        compressed: deflate the members (``np.savez_compressed``'s layout) or store them (``np.savez``'s).
    """
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w") as zf:
        for key in sorted(arrays):
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(arrays[key]), allow_pickle=False)  # keeps 0-d arrays 0-d
            info = zipfile.ZipInfo(f"{key}.npy", date_time=NPZ_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())
    return Path(path)
