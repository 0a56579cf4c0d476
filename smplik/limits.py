"""Resource limits of inputs: one budget, checked before anything sized by a number in a file is allocated.

A file can declare any size: an ``.npy`` header says shape ``(10**9, 3)``, a zip member says it
inflates to 4 GiB, a ``.pt`` tensor is a stride-0 view that expands to 8 GB, a BVH says
``Frames: 10000000``, a PNG header says 13000 x 13000, a pickle of a few KB shares references so
that it expands to 2**28 objects. Every reader checks such numbers against the limits below *before*
allocating, and raises :class:`LimitError` (a ``ValueError``: the CLI prints it as one ``error:``
line, exit 1) naming the input, the amount, the limit and the environment variable that raises it.

==========================  ================================  ============================================
limit                       environment variable              default
==========================  ================================  ============================================
:data:`INPUT_BYTES`         ``SMPLIK_MAX_INPUT_BYTES``        2 GiB: all arrays of one input file together
:data:`ARRAY_BYTES`         ``SMPLIK_MAX_ARRAY_BYTES``        1 GiB: one array (npz/npy member, tensor)
:data:`ARRAY_ELEMENTS`      ``SMPLIK_MAX_ARRAY_ELEMENTS``     2*10**8 elements of one array
:data:`JSON_BYTES`          ``SMPLIK_MAX_JSON_BYTES``         32 MiB: a JSON file (effectors, scene, joints)
:data:`TEXT_BYTES`          ``SMPLIK_MAX_TEXT_BYTES``         128 MiB: another text file (BVH)
:data:`IMAGE_PIXELS`        ``SMPLIK_MAX_IMAGE_PIXELS``       64 * 10**6 pixels (8000 x 8000)
:data:`BVH_FRAMES`          ``SMPLIK_MAX_BVH_FRAMES``         10**6 frames (2.3 h at 120 fps)
:data:`PICKLE_OBJECTS`      ``SMPLIK_MAX_PICKLE_OBJECTS``     10**7 objects, shared references counted
                                                              as often as they are reachable (a DAG
                                                              counts as the tree it expands to)
:data:`PICKLE_BYTES`        ``SMPLIK_MAX_PICKLE_BYTES``       512 MiB: a pickle stream once decompressed
                                                              (``.pkl``/joblib, an object member of an
                                                              ``.npz``/``.npy``), read with a running cap
:data:`MEMORY_BYTES`        ``SMPLIK_MAX_MEMORY_BYTES``       1.5 GiB: what one step of work will allocate,
                                                              estimated before it starts (a model's weights
                                                              and activations, a render or decoded image, a
                                                              dtype conversion, a parsed motion, a set of
                                                              benchmark samples)
:data:`OUTPUT_FRAMES`       ``SMPLIK_MAX_OUTPUT_FRAMES``      10**6 frames that a resampling or interpolation
                                                              will make (duration x rate, counted before
                                                              any array is made)
:data:`TRACK_FRAMES`        ``SMPLIK_MAX_TRACK_FRAMES``       36,000 frames run through the tracker (10
                                                              minutes at 60 frames/s: 91 s and 1.17 GB peak;
                                                              about 2 ms and 17 KB a frame,
                                                              benchmarks/results/track_frames.json)
==========================  ================================  ============================================

Frame rates read from any file or option (a tracker file's ``fps``, SteamVR timestamps, an animation's
``fps``, AMASS ``mocap_framerate``, a model file's ``fps``) lie in [:data:`MIN_FPS`, :data:`MAX_FPS`]
(:func:`check_rate`); a rate outside is a mistake, not a budget, so it has no variable.

Inputs must be regular files (:func:`check_input_file`): a named pipe, a device (``/dev/zero``) or a
socket, directly or through a symlink, is refused before it is opened, and sizes are read through links.

Values are integers, optionally with a ``K``/``M``/``G`` suffix (powers of 1024): ``SMPLIK_MAX_INPUT_BYTES=8G``.
The defaults keep any one input under 2 GB, which fits a 24 GB machine with room to spare.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["ALL_LIMITS", "ARRAY_BYTES", "ARRAY_ELEMENTS", "BVH_FRAMES", "IMAGE_PIXELS", "INPUT_BYTES", "JSON_BYTES",
           "MAX_FPS", "MEMORY_BYTES", "MIN_FPS", "OUTPUT_FRAMES", "PICKLE_BYTES", "PICKLE_OBJECTS",
           "TEXT_BYTES", "TRACK_FRAMES", "CappedReader", "Limit", "LimitError", "check_array", "check_input_file",
           "check_npz", "check_rate", "check_render_size", "check_resampled_frames", "check_tensors",
           "check_torch_zip", "read_bounded"]

_SUFFIX = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


class LimitError(ValueError):
    """An input declares more than a resource limit allows (the message names the limit's variable)."""


@dataclass(frozen=True)
class Limit:
    """One resource limit: ``default``, overridden by the environment variable ``env``."""

    what: str
    """What is counted, for messages ("bytes", "pixels", ...)."""
    env: str
    """Environment variable that overrides the default."""
    default: int

    @property
    def value(self) -> int:
        """The limit in force (the environment variable, read at each check, else the default)."""
        raw = os.environ.get(self.env, "").strip()
        if not raw:
            return self.default
        scale = _SUFFIX.get(raw[-1].upper(), 1)
        digits = raw[:-1] if scale > 1 else raw
        try:
            value = int(float(digits) * scale)
        except ValueError:
            raise LimitError(f"{self.env}={raw!r} is not a number (e.g. {self.default} or 4G).") from None
        if value < 0:
            raise LimitError(f"{self.env}={raw!r} must be >= 0.")
        return value

    def check(self, amount: int, source: str) -> None:
        """Raise :class:`LimitError` when ``amount`` (declared by ``source``) is over the limit."""
        limit = self.value
        if amount > limit:
            raise LimitError(f"{source}: {amount} {self.what} is over the limit of {limit} {self.what} (set "
                             f"{self.env} to raise it if the input is genuine).")


INPUT_BYTES = Limit("bytes (all arrays of the input)", "SMPLIK_MAX_INPUT_BYTES", 2 << 30)
ARRAY_BYTES = Limit("bytes (one array)", "SMPLIK_MAX_ARRAY_BYTES", 1 << 30)
ARRAY_ELEMENTS = Limit("elements (one array)", "SMPLIK_MAX_ARRAY_ELEMENTS", 200_000_000)
JSON_BYTES = Limit("bytes (JSON file)", "SMPLIK_MAX_JSON_BYTES", 32 << 20)
TEXT_BYTES = Limit("bytes (text file)", "SMPLIK_MAX_TEXT_BYTES", 128 << 20)
IMAGE_PIXELS = Limit("pixels", "SMPLIK_MAX_IMAGE_PIXELS", 64_000_000)
BVH_FRAMES = Limit("frames", "SMPLIK_MAX_BVH_FRAMES", 1_000_000)
PICKLE_OBJECTS = Limit("objects (shared references counted each time)", "SMPLIK_MAX_PICKLE_OBJECTS", 10_000_000)
PICKLE_BYTES = Limit("bytes (decompressed pickle stream)", "SMPLIK_MAX_PICKLE_BYTES", 512 << 20)
MEMORY_BYTES = Limit("bytes (estimated memory of the work)", "SMPLIK_MAX_MEMORY_BYTES", 3 << 29)
OUTPUT_FRAMES = Limit("frames (made by resampling)", "SMPLIK_MAX_OUTPUT_FRAMES", 1_000_000)
TRACK_FRAMES = Limit("frames (run through the tracker)", "SMPLIK_MAX_TRACK_FRAMES", 36_000)
ALL_LIMITS = (INPUT_BYTES, ARRAY_BYTES, ARRAY_ELEMENTS, JSON_BYTES, TEXT_BYTES, IMAGE_PIXELS, BVH_FRAMES,
              PICKLE_OBJECTS, PICKLE_BYTES, MEMORY_BYTES, OUTPUT_FRAMES, TRACK_FRAMES)
"""Every limit (the docs' security page lists each with its variable and default; a test keeps them in step)."""

RENDER_BYTES_PER_PIXEL = 64
"""Memory an offscreen render takes per output pixel (GL colour and depth buffers, their read-back, the float32
compositing of overlay and marker passes, the PNG written): ``body render --width 8192 --height 8192`` (two
4096 x 8192 views) peaked at 2.97 GB, i.e. 44 bytes a pixel of the views, plus a margin."""


MIN_FPS = 1.0
"""Lowest frame rate read from a file or option (frames per second)."""
MAX_FPS = 1000.0
"""Highest frame rate read from a file or option (frames per second)."""


def check_rate(value: Any, source: str) -> float:
    """``value`` as a frame rate: a number (not a bool or a string), finite, within [:data:`MIN_FPS`,
    :data:`MAX_FPS`]. Raises :class:`LimitError` naming ``source`` (the file and key, or the option)."""
    import math

    if isinstance(value, bool) or not isinstance(value, (int, float)):
        # numpy scalars are numbers too; strings, lists and None are not
        if not (hasattr(value, "dtype") and getattr(value, "shape", None) == () and value.dtype.kind in "iuf"):
            text = repr(value)
            raise LimitError(f"{source}: must be a frame rate (a number) in [{MIN_FPS:g}, {MAX_FPS:g}] frames/s, got "
                             f"{text[:60]}.")
    try:
        rate = float(value)
    except (OverflowError, ValueError):
        rate = math.inf
    if not (math.isfinite(rate) and MIN_FPS <= rate <= MAX_FPS):
        raise LimitError(f"{source}: must be a frame rate in [{MIN_FPS:g}, {MAX_FPS:g}] frames/s, got {rate:g}.")
    return rate


def check_resampled_frames(duration_s: float, fps: float, source: str) -> int:
    """The number of frames a resampling of ``duration_s`` seconds at ``fps`` makes (``floor(duration x fps) +
    1``), counted in floating point before any array is made and checked against :data:`OUTPUT_FRAMES`.

    Raises:
        LimitError: naming ``source``, the frame count and ``SMPLIK_MAX_OUTPUT_FRAMES`` (a non-finite or
            negative duration too).
    """
    import math

    frames = float(duration_s) * float(fps)
    if not math.isfinite(frames) or frames < 0:
        raise LimitError(f"{source}: a span of {duration_s:g} s at {fps:g} frames/s cannot be resampled.")
    if frames + 1 > OUTPUT_FRAMES.value:
        OUTPUT_FRAMES.check(math.floor(min(frames, 1e18)) + 1,
                            f"{source} (a span of {duration_s:g} s resampled at {fps:g} frames/s)")
    return int(math.floor(frames + 1e-9)) + 1


def check_array(shape: Iterable[Any], itemsize: int, source: str) -> int:
    """Check a declared array (``shape`` of non-negative ints, ``itemsize`` bytes per element) against
    :data:`ARRAY_ELEMENTS` and :data:`ARRAY_BYTES` before it is allocated; returns its size in bytes."""
    count = 1
    dims = tuple(shape)
    for n in dims:
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise LimitError(f"{source}: an array of shape {dims!r:.80} (sizes must be non-negative integers).")
        count *= n
    ARRAY_ELEMENTS.check(count, f"{source} (shape {dims})")
    size = count * max(int(itemsize), 1)
    ARRAY_BYTES.check(size, f"{source} (shape {dims})")
    return size


def check_input_file(path: str | Path, what: str = "input file") -> int:
    """Check that ``path`` names a regular file, following symlinks (``z.glb -> /dev/zero`` is the device it
    points at), before anything opens it: a named pipe would block the reader forever and a device reports
    size 0 but never ends. Returns the real size in bytes (read through any link).

    Raises:
        FileNotFoundError / PermissionError: as ``os.stat`` (the CLI prints them as one line).
        LimitError: a folder, a named pipe, a device or a socket (named).
    """
    import stat

    st = os.stat(path)  # follows symlinks
    mode = st.st_mode
    if stat.S_ISREG(mode):
        return int(st.st_size)
    kind = ("a folder" if stat.S_ISDIR(mode) else "a named pipe (FIFO)" if stat.S_ISFIFO(mode)
            else "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    link = f" (through a link to {os.path.realpath(path)})" if os.path.islink(path) else ""
    raise LimitError(f"{path}: {what} is {kind}{link}; smplik reads only regular files.")


class CappedReader:
    """A binary file object that reads at most ``limit``'s value bytes from ``raw`` (a decompressing stream:
    gzip/zlib/bz2/lzma) and raises :class:`LimitError` naming ``source`` as soon as a read would pass it, so a
    decompression bomb stops at the cap instead of being inflated whole. A single read asking for more than
    what is left is refused before anything is allocated. ``read``, ``readline``, ``readinto`` and ``peek``
    (what :mod:`pickle` and joblib use) are supported."""

    def __init__(self, raw: Any, source: str, limit: Limit | None = None) -> None:
        self.raw, self.source = raw, source
        self.limit = PICKLE_BYTES if limit is None else limit
        self.cap = self.limit.value
        self.count = 0

    def _take(self, n: int) -> None:
        if self.count + n > self.cap:
            raise LimitError(f"{self.source}: more than {self.cap} {self.limit.what} (set {self.limit.env} to "
                             "raise the limit if the file is genuine).")

    def _room(self, size: int | None) -> int:
        left = self.cap - self.count
        if size is None or size < 0:
            return left + 1
        if size > left:
            self._take(size)
        return size

    def room(self, size: int) -> None:
        """Raise :class:`LimitError` when ``size`` more bytes would pass the cap (before they are allocated)."""
        self._take(size)

    def read(self, size: int | None = -1) -> bytes:
        data = self.raw.read(self._room(size))
        self.count += len(data)
        self._take(0)
        return data

    def readline(self, size: int | None = -1) -> bytes:
        data = self.raw.readline(self._room(size))
        self.count += len(data)
        self._take(0)
        return data

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        data = self.read(len(view))
        view[:len(data)] = data
        return len(data)

    def peek(self, size: int = 1) -> bytes:
        peek = getattr(self.raw, "peek", None)
        return peek(size) if peek is not None else b""

    def seekable(self) -> bool:
        return False

    def readable(self) -> bool:
        return True


def read_bounded(path: str | Path, limit: Limit = TEXT_BYTES) -> bytes:
    """The bytes of ``path``, reading at most ``limit`` + 1 of them (so a file that grows while read cannot
    exhaust memory); :class:`LimitError` when there are more. ``path`` must be a regular file
    (:func:`check_input_file`: a named pipe or a device is refused before it is opened).

    Raises:
        OSError: the file cannot be opened or read (the caller names it).
    """
    check_input_file(path)
    cap = limit.value
    with open(path, "rb") as fh:
        # what fstat says plus one byte (a read of cap + 1 would allocate the whole cap for a small file),
        # then the rest up to the cap only if the file grew meanwhile
        data = fh.read(min(cap, os.fstat(fh.fileno()).st_size) + 1)
        if cap >= len(data) > os.fstat(fh.fileno()).st_size:
            data += fh.read(cap + 1 - len(data))
    if len(data) > cap:
        raise LimitError(f"{path}: more than {cap} {limit.what} (set {limit.env} to raise the limit if the file is "
                         "genuine).")
    return data


def open_checked_npz(path: Path, missing: str, unreadable: Callable[[Exception], Exception]) -> Any:
    """``np.load(path)`` of an ``.npz`` after :func:`check_npz`: FileNotFoundError ``f"{missing}: {path}"`` when
    there is no such file; ``unreadable(exc)`` raised when numpy cannot read it. Returns the open ``NpzFile``."""
    import zipfile

    import numpy as np

    if not path.is_file():
        raise FileNotFoundError(f"{missing}: {path}")
    check_npz(path)  # declared sizes within the input budget before anything is decompressed
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise unreadable(exc) from None


def check_npz(path: str | Path) -> dict[str, tuple[tuple[int, ...], Any]]:
    """Check an ``.npz`` before anything in it is decompressed beyond its ``.npy`` headers: the zip
    directory's uncompressed sizes together within :data:`INPUT_BYTES`, and each member's declared shape
    and dtype within :func:`check_array` and consistent with the member's size (a header that declares
    more than its member holds, or a compressed member that inflates beyond its declared size, is refused).

    Returns:
        member name (without ``.npy``) -> (shape, dtype) as declared.

    Raises:
        LimitError: over a limit. ValueError: not a readable ``.npz`` (the message names the file).
    """
    import zipfile
    import zlib

    import numpy as np

    path = Path(path)
    out: dict[str, tuple[tuple[int, ...], Any]] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            infos = [i for i in zf.infolist() if i.filename.endswith(".npy")]
            INPUT_BYTES.check(sum(i.file_size for i in infos), f"{path} (uncompressed members)")
            for info in infos:
                name = info.filename[:-4]
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(fh, max_header_size=10000)
                    header_bytes = fh.tell()
                if dtype.hasobject:  # a pickle stream: its declared size within the pickle cap, before reading
                    PICKLE_BYTES.check(info.file_size - header_bytes, f"{path}: object array '{name}' (a pickle)")
                    out[name] = (tuple(shape), dtype)
                    continue
                size = check_array(tuple(shape), dtype.itemsize, f"{path}: array '{name}'")
                if size != info.file_size - header_bytes:
                    raise ValueError(f"{path}: array '{name}' declares shape {tuple(shape)} ({size} bytes) but its "
                                     f"member holds {info.file_size - header_bytes} bytes of data.")
                out[name] = (tuple(shape), dtype)
    except LimitError:
        raise
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a readable .npz ({' '.join(str(exc).split())[:200]}).") from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, KeyError, TypeError, IndexError,
            OverflowError, MemoryError, SyntaxError, UnicodeDecodeError, NotImplementedError, zlib.error) as exc:
        raise ValueError(f"{path}: not a readable .npz ({type(exc).__name__}: "
                         f"{' '.join(str(exc).split())[:200]}).") from None
    return out


def check_tensors(obj: Any, source: str, *, max_depth: int = 50, as_itemsize: int | None = None) -> None:
    """Check every tensor in a loaded ``.pt`` structure (dicts, lists, tuples) before it is used: each
    tensor's *logical* size (shape x element size, what ``.numpy()``, ``.contiguous()`` or arithmetic
    allocate; a stride-0 view of one stored number counts as its full shape) within :func:`check_array`,
    and all of them together within :data:`INPUT_BYTES`.

    ``as_itemsize``: the caller converts every floating-point tensor to this element size (8 for
    ``.double()``): the elements that conversion materialises, across the whole file, must also fit
    :data:`MEMORY_BYTES`, checked before any conversion.

    Raises:
        LimitError: naming ``source``, the key path and the limit's environment variable.
    """
    total = converted = 0
    stack: list[tuple[Any, str, int]] = [(obj, "", 0)]
    while stack:
        node, where, depth = stack.pop()
        if depth > max_depth:
            raise LimitError(f"{source}: nested deeper than {max_depth} levels.")
        if hasattr(node, "untyped_storage") and hasattr(node, "element_size"):  # a torch.Tensor
            shape = tuple(int(n) for n in node.shape)
            size = check_array(shape, int(node.element_size()), f"{source}: tensor {where or '(root)'}")
            total += size
            if as_itemsize is not None and node.is_floating_point():
                converted += size // max(int(node.element_size()), 1) * as_itemsize
        elif isinstance(node, dict):
            stack.extend((v, f"{where}.{k}" if where else str(k), depth + 1) for k, v in node.items())
        elif isinstance(node, (list, tuple)):
            stack.extend((v, f"{where}[{i}]", depth + 1) for i, v in enumerate(node))
    INPUT_BYTES.check(total, f"{source} (all tensors)")
    if as_itemsize is not None:
        MEMORY_BYTES.check(converted, f"{source} (all tensors as {8 * as_itemsize}-bit floats)")


TORCH_COMPRESSED_MEMBER_BYTES = 64 << 20
"""Largest compressed member a ``.pt`` zip may hold: ``torch.save`` stores every member uncompressed, so a
large compressed one can only be a decompression bomb (refused from the zip directory, nothing inflated)."""


def check_torch_zip(path: str | Path) -> None:
    """Check a ``torch.save`` zip from its directory before :func:`smplik.model_io.read_torch_file` unpickles
    anything: every storage member's declared size within :data:`ARRAY_BYTES`, all together within
    :data:`INPUT_BYTES`, and no compressed member over :data:`TORCH_COMPRESSED_MEMBER_BYTES` (torch never
    compresses). A file that is not a zip (a legacy ``.pt``) is left to the loader.

    Raises:
        LimitError: over a limit (named, with its variable). ValueError: a compressed storage.
    """
    import zipfile

    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, NotImplementedError):
        return
    for info in infos:
        ARRAY_BYTES.check(info.file_size, f"{path}: member '{info.filename}'")
        if info.compress_type != zipfile.ZIP_STORED and info.file_size > TORCH_COMPRESSED_MEMBER_BYTES:
            raise LimitError(f"{path}: member '{info.filename}' is compressed and inflates to {info.file_size} "
                             "bytes; torch.save never compresses, so this is not a torch file.")
    INPUT_BYTES.check(sum(i.file_size for i in infos), f"{path} (uncompressed members)")


def check_render_size(width: int, height: int, source: str = "render") -> None:
    """An offscreen render of ``width`` x ``height`` within :data:`IMAGE_PIXELS` and, at
    :data:`RENDER_BYTES_PER_PIXEL`, within :data:`MEMORY_BYTES` (checked before any buffer is made)."""
    IMAGE_PIXELS.check(width * height, f"{source} ({width} x {height} image)")
    MEMORY_BYTES.check(width * height * RENDER_BYTES_PER_PIXEL,
                       f"{source} ({width} x {height} image at {RENDER_BYTES_PER_PIXEL} bytes a pixel)")


DEFAULT_MAX_JOINTS = 10_000
"""Joint cap of the skeleton readers (:func:`smplik.data.bvh.read_bvh`, glTF and joints JSON; real rigs
have < 500; raise it with ``max_joints`` / ``--max-joints``). The command line shows it as an option
default, so this module imports nothing heavy."""
