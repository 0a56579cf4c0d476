"""BVH motion files: a small, strict, vectorised reader and a writer.

Conventions (fixed here once):

* A joint's local translation is its OFFSET, except for the axes it has position channels for:
  per the BVH convention those take the channel value in place of the OFFSET (the root's
  position; Mixamo and Rokoko exports carry ``Xposition Yposition Zposition`` on every joint,
  equal to the OFFSETs at rest). MakeHuman's exporter writes zero position channels beside full
  OFFSETs (deltas); :func:`position_channel_mode` detects that layout from the first frame and
  *adds* non-root channels to the OFFSET then (``position_mode="add"``; force either way).
* Rotation channels are Euler angles in degrees, applied in the listed order as **intrinsic**
  rotations: ``Zrotation Yrotation Xrotation`` means ``R = Rz @ Ry @ Rx``
  (``scipy.spatial.transform.Rotation.from_euler("ZYX", ...)``). Any order of 1-3 distinct
  axes is accepted; a joint without rotation channels has identity rotation.
* Matrices act on column vectors: ``p_world_joint = p_world_parent + R_world_parent @ t_parent_joint``,
  ``R_world_joint = R_world_parent @ R_parent_joint``.
* Positions are in the file's own units and axes; unit and up-axis conversion belong to the
  caller (see :mod:`smplik.data.retarget`).

Libraries on PyPI were considered (``bvhio``: an object per joint per frame on PyGLM;
``bvh`` 0.3: string look-ups, unmaintained; ``pymo``: pandas-based, unmaintained). None is
small, strict and fast on long files, hence this ~300-line reader.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from smplik import limits
from smplik.atomic import write_text_atomic
from smplik.limits import BVH_FRAMES, MEMORY_BYTES, TEXT_BYTES, check_array, read_bounded
from smplik.rotations import euler_deg_to_matrix_np

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
_CHANNEL_CANON = {c.lower(): c for c in POSITION_CHANNELS + ROTATION_CHANNELS}
_TOKEN = re.compile(r"[{}]|[^\s{}]+")


class BVHError(ValueError):
    """A BVH file is malformed; the message names the file, and the line or frame where possible."""


@dataclass(frozen=True)
class BVHMotion:
    """A parsed BVH file (J joints, E end sites, T frames, C channels in total).

    Attributes:
        name: where it came from (file path or ``"<string>"``).
        joint_names: (J,) joint names in file order (parents precede children).
        parents: (J,) parent index per joint, -1 for the root.
        offsets: (J, 3) OFFSET of each joint relative to its parent, file units.
        channels: per joint, its channel names in file order (canonical capitalisation).
        end_site_parents: (E,) joint index that owns each End Site.
        end_site_offsets: (E, 3) End Site OFFSETs.
        frame_time: seconds per frame.
        values: (T, C) raw channel values, file order.
        local_translations: (T, J, 3) ``OFFSET + position channels`` (``t_parent_joint``).
        local_rotations: (T, J, 3, 3) ``R_parent_joint`` from the rotation channels.
        global_rotations: (T, J, 3, 3) ``R_world_joint``.
        positions: (T, J, 3) ``p_world_joint`` by forward kinematics, file units.
        position_mode: how non-root position channels were read (:func:`position_channel_mode`).
    """

    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_site_parents: tuple[int, ...]
    end_site_offsets: np.ndarray
    frame_time: float
    values: np.ndarray
    local_translations: np.ndarray
    local_rotations: np.ndarray
    global_rotations: np.ndarray
    positions: np.ndarray
    position_mode: Literal["replace", "add"] = "replace"

    @property
    def num_frames(self) -> int:
        return int(self.values.shape[0])

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def root_positions(self) -> np.ndarray:
        """(T, 3) root position per frame (its OFFSET plus its position channels)."""
        return self.local_translations[:, 0]

    def index(self, joint: str) -> int:
        """Index of ``joint``; raises :class:`KeyError` naming the available joints."""
        try:
            return self.joint_names.index(joint)
        except ValueError:
            raise KeyError(f"{self.name}: no joint {joint!r}; joints: {', '.join(self.joint_names)}") from None

    def end_site_positions(self) -> np.ndarray:
        """(T, E, 3) world positions of the End Sites."""
        p = np.asarray(self.end_site_parents, dtype=np.int64)
        return self.positions[:, p] + np.einsum("teij,ej->tei", self.global_rotations[:, p], self.end_site_offsets)

    def rest_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The zero-rotation OFFSET pose: ``(R_world_joint (J, 3, 3) identity, p_world_joint (J, 3))``."""
        p = np.zeros((self.num_joints, 3))
        for j, parent in enumerate(self.parents):
            p[j] = self.offsets[j] if parent < 0 else p[parent] + self.offsets[j]
        return np.broadcast_to(np.eye(3), (self.num_joints, 3, 3)).copy(), p


# ----------------------------------------------------------------------------- math


def bvh_forward_kinematics(
    local_rotations: np.ndarray, local_translations: np.ndarray, parents: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """BVH forward kinematics.

    local_rotations (T, J, 3, 3), local_translations (T, J, 3) -> (R_world (T, J, 3, 3), p_world (T, J, 3)).
    """
    R_world = np.empty_like(local_rotations)
    p_world = np.empty_like(local_translations)
    for j, parent in enumerate(parents):
        if parent < 0:
            R_world[:, j] = local_rotations[:, j]
            p_world[:, j] = local_translations[:, j]
        else:
            R_world[:, j] = R_world[:, parent] @ local_rotations[:, j]
            p_world[:, j] = p_world[:, parent] + np.einsum("tij,tj->ti", R_world[:, parent], local_translations[:, j])
    return R_world, p_world


# ----------------------------------------------------------------------------- reading


class _Tokens:
    """Hierarchy tokens with their 1-based line numbers."""

    def __init__(self, tokens: list[tuple[str, int]], name: str) -> None:
        self.tokens, self.pos, self.name = tokens, 0, name

    def error(self, msg: str, line: int | None = None) -> BVHError:
        if line is None:
            line = self.tokens[min(self.pos, len(self.tokens) - 1)][1] if self.tokens else 1
        return BVHError(f"{self.name}: line {line}: {msg}")

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.tokens):
            raise BVHError(f"{self.name}: unexpected end of hierarchy while reading {what} (missing MOTION section?)")
        tok = self.tokens[self.pos]
        self.pos += 1
        return tok

    def peek(self) -> str | None:
        return self.tokens[self.pos][0] if self.pos < len(self.tokens) else None

    def expect(self, value: str, what: str) -> int:
        tok, line = self.next(what)
        if tok.upper() != value.upper():
            raise self.error(f"expected {value!r} {what}, found {tok!r}", line)
        return line

    def floats(self, n: int, what: str) -> list[float]:
        out = []
        for _ in range(n):
            tok, line = self.next(what)
            try:
                out.append(float(tok))
            except ValueError:
                raise self.error(f"expected a number in {what}, found {tok!r}", line) from None
        return out


def _parse_hierarchy(tk: _Tokens, max_joints: int):
    """Joints depth-first, iteratively (no recursion limit), in time linear in the token count."""
    names: list[str] = []
    seen: set[str] = set()
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[list[float]] = []
    has_offset: list[bool] = []

    tok, line = tk.next("the ROOT joint")
    if tok.upper() != "ROOT":
        raise tk.error(f"expected 'ROOT' after HIERARCHY, found {tok!r}", line)

    def open_joint(parent: int) -> int:
        name, line = tk.next("a joint name")
        if name in ("{", "}"):
            raise tk.error(f"missing joint name before {name!r}", line)
        while tk.pos < len(tk.tokens) and tk.tokens[tk.pos][1] == line and tk.tokens[tk.pos][0] != "{":
            name += " " + tk.next("a joint name")[0]  # 3ds Max names: "JOINT Bip01 L Thigh"
        if name in seen:
            raise tk.error(f"duplicate joint name {name!r}", line)
        if len(names) >= max_joints:
            raise tk.error(f"more than {max_joints} joints (raise the limit with max_joints / --max-joints "
                           "if this file is legitimate)", line)
        seen.add(name)
        names.append(name)
        parents.append(parent)
        offsets.append([0.0, 0.0, 0.0])
        channels.append(())
        has_offset.append(False)
        tk.expect("{", f"after joint {name!r}")
        return len(names) - 1

    stack = [open_joint(-1)]
    while stack:
        j = stack[-1]
        name = names[j]
        tok, line = tk.next(f"the body of joint {name!r}")
        key = tok.upper()
        if key == "}":
            if not has_offset[j]:
                raise tk.error(f"joint {name!r} has no OFFSET", line)
            stack.pop()
        elif key == "OFFSET":
            offsets[j] = tk.floats(3, f"the OFFSET of joint {name!r}")
            has_offset[j] = True
        elif key == "CHANNELS":
            count_tok, cline = tk.next(f"the channel count of joint {name!r}")
            try:
                count = int(count_tok)
            except ValueError:
                raise tk.error(f"joint {name!r}: channel count {count_tok!r} is not an integer", cline) from None
            if not 0 <= count <= 6:
                raise tk.error(f"joint {name!r}: CHANNELS {count}: a joint has 0 to 6 channels", cline)
            chans: list[str] = []
            while len(chans) < count and tk.peek() is not None and tk.peek().lower() in _CHANNEL_CANON:
                chans.append(_CHANNEL_CANON[tk.next("a channel name")[0].lower()])
            if len(chans) != count:
                found = tk.peek()
                if found is not None and found.upper() not in ("JOINT", "END", "OFFSET", "CHANNELS", "{", "}"):
                    raise tk.error(f"joint {name!r}: unknown channel name {found!r} (expected one of "
                                   f"{', '.join(POSITION_CHANNELS + ROTATION_CHANNELS)})")
                raise tk.error(f"joint {name!r}: CHANNELS declares {count} channels but lists {len(chans)}", cline)
            if tk.peek() is not None and tk.peek().lower() in _CHANNEL_CANON:
                raise tk.error(f"joint {name!r}: CHANNELS declares {count} channels but lists more", cline)
            if len(set(chans)) != len(chans):
                raise tk.error(f"joint {name!r}: unsupported rotation order / repeated channel in "
                               f"{' '.join(chans)} (each axis may appear once)", cline)
            channels[j] = tuple(chans)
        elif key == "JOINT":
            stack.append(open_joint(j))
        elif key == "END":
            tk.expect("Site", "after 'End'")
            tk.expect("{", "after 'End Site'")
            tk.expect("OFFSET", "in End Site")
            end_offsets.append(tk.floats(3, f"the End Site OFFSET of joint {name!r}"))
            end_parents.append(j)
            tk.expect("}", "closing End Site")
        elif key == "ROOT":
            raise tk.error("several ROOT joints are not supported", line)
        else:
            raise tk.error(f"unexpected {tok!r} in joint {name!r}", line)
    offsets_np = np.asarray(offsets, dtype=np.float64).reshape(len(names), 3)
    if not np.isfinite(offsets_np).all():
        bad = names[int(np.nonzero(~np.isfinite(offsets_np).all(axis=1))[0][0])]
        raise BVHError(f"{tk.name}: the OFFSET of joint {bad!r} holds a non-finite value")
    end_np = np.asarray(end_offsets, dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(end_np).all():
        raise BVHError(f"{tk.name}: an End Site OFFSET holds a non-finite value")
    return names, parents, offsets_np, channels, end_parents, end_np


DEFAULT_MAX_JOINTS = limits.DEFAULT_MAX_JOINTS
"""Joint cap of :func:`read_bvh` (:data:`smplik.limits.DEFAULT_MAX_JOINTS`)."""

MIN_FRAME_TIME_S = 1e-6
"""Smallest accepted ``Frame Time`` (1 MHz); smaller or denormal values are refused."""

PositionMode = Literal["auto", "replace", "add"]


def position_channel_mode(offsets: np.ndarray, channels: Sequence[Sequence[str]], first_frame: np.ndarray,
                          parents: Sequence[int]) -> Literal["replace", "add"]:
    """How a file's non-root position channels combine with OFFSETs, judged from its first frame.

    ``"replace"`` (the BVH convention; Mixamo and Rokoko exports): the channels are the joint's
    translation. ``"add"`` (MakeHuman's exporter writes zero channels beside full OFFSETs): the
    channels are added to the OFFSET. ``auto`` picks ``"add"`` only when the first frame's channels
    are closer to zero than to the OFFSETs.
    """
    to_offset = to_zero = 0.0
    start = 0
    for j, chans in enumerate(channels):
        if parents[j] >= 0:
            for axis, c in enumerate(POSITION_CHANNELS):
                if c in chans:
                    v = first_frame[start + chans.index(c)]
                    to_offset += abs(v - offsets[j, axis])
                    to_zero += abs(v)
        start += len(chans)
    return "add" if to_zero < to_offset else "replace"


def read_bvh(path: str | Path, *, position_mode: PositionMode = "auto", max_joints: int = DEFAULT_MAX_JOINTS
             ) -> BVHMotion:
    """Read a BVH file. Raises :class:`BVHError` (a ``ValueError``) naming the file and the problem.

    ``position_mode``: see :func:`position_channel_mode`; ``max_joints`` caps the joint count.
    """
    path = Path(path)
    try:
        text = read_bounded(path, TEXT_BYTES).decode("utf-8", errors="replace")
    except OSError as exc:
        raise BVHError(f"{path}: cannot read BVH file: {exc.strerror or exc}") from exc
    return parse_bvh(text, name=str(path), position_mode=position_mode, max_joints=max_joints)


def parse_bvh(text: str, name: str = "<string>", *, position_mode: PositionMode = "auto",
              max_joints: int = DEFAULT_MAX_JOINTS) -> BVHMotion:
    """Parse BVH text; ``name`` is used in error messages. See :func:`read_bvh`."""
    if position_mode not in ("auto", "replace", "add"):
        raise BVHError(f"{name}: unknown position_mode {position_mode!r}; expected auto, replace or add")
    # every frame is a line: bound the line count before splitting (the hierarchy takes < 8 lines a joint)
    BVH_FRAMES.check(max(0, text.count("\n") - 8 * max_joints - 100), f"{name} (lines of the MOTION section)")
    lines = text.splitlines()
    # Hierarchy: tokenise line by line up to the MOTION keyword.
    tokens: list[tuple[str, int]] = []
    motion_line = -1
    for i, line in enumerate(lines):
        toks = _TOKEN.findall(line)
        if toks and toks[0].upper() == "MOTION":
            motion_line = i
            break
        tokens.extend((t, i + 1) for t in toks)
    if not tokens or tokens[0][0].upper() != "HIERARCHY":
        first = tokens[0][0] if tokens else "nothing"
        raise BVHError(f"{name}: missing HIERARCHY section (the file starts with {first[:40]!r})")
    tk = _Tokens(tokens[1:], name)
    names, parents, offsets_np, channels, end_parents, end_offsets = _parse_hierarchy(tk, max_joints)
    if tk.pos < len(tk.tokens):
        raise tk.error(f"unexpected {tk.tokens[tk.pos][0][:40]!r} after the hierarchy (expected MOTION)")
    if motion_line < 0:
        raise BVHError(f"{name}: missing MOTION section after the hierarchy")

    values, frame_time = _parse_motion(lines, motion_line, sum(len(c) for c in channels), name, len(names))
    J, T = len(names), values.shape[0]
    check_array((T, J, 3, 3), 8, f"{name}: {T} frames of {J} joints (rotations)")
    if position_mode == "auto":
        position_mode = position_channel_mode(offsets_np, channels, values[0], parents) if T else "replace"
    local_t = np.broadcast_to(offsets_np, (T, J, 3)).copy()
    local_R = np.empty((T, J, 3, 3))
    start = 0
    by_order: dict[str, list[tuple[int, list[int]]]] = {}
    for j, chans in enumerate(channels):
        cols = {c: start + k for k, c in enumerate(chans)}
        replace = parents[j] < 0 or position_mode == "replace"
        for axis, c in enumerate(POSITION_CHANNELS):
            if c in cols:
                if replace:
                    local_t[:, j, axis] = values[:, cols[c]]
                else:
                    local_t[:, j, axis] += values[:, cols[c]]
        rot = [c for c in chans if c in ROTATION_CHANNELS]
        by_order.setdefault("".join(c[0] for c in rot), []).append((j, [cols[c] for c in rot]))
        start += len(chans)
    for order, items in by_order.items():
        js = [j for j, _ in items]
        cols = np.asarray([c for _, cs in items for c in cs], dtype=np.int64)
        angles = values[:, cols].reshape(T, len(js), len(order))
        local_R[:, js] = euler_deg_to_matrix_np(angles, order)
    global_R, positions = bvh_forward_kinematics(local_R, local_t, parents)
    return BVHMotion(
        name=name,
        joint_names=tuple(names),
        parents=tuple(parents),
        offsets=offsets_np,
        channels=tuple(channels),
        end_site_parents=tuple(end_parents),
        end_site_offsets=end_offsets,
        frame_time=frame_time,
        values=values,
        local_translations=local_t,
        local_rotations=local_R,
        global_rotations=global_R,
        positions=positions,
        position_mode=position_mode,
    )


def _header_value(lines: list[str], i: int, key: str, name: str) -> tuple[str, int]:
    """Value after ``key`` (e.g. ``"Frames:"``) on the next non-empty line from ``i``; returns (value, next line)."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise BVHError(f"{name}: file ends before the MOTION header line {key!r}")
    line = lines[i].strip()
    if not line.lower().startswith(key.lower()):
        raise BVHError(f"{name}: line {i + 1}: expected {key!r} in the MOTION header, found {line[:40]!r}")
    return line[len(key):].strip(), i + 1


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


MOTION_BYTES_PER_JOINT_FRAME = 848
"""Peak memory :func:`parse_bvh` takes per joint and frame (the text and its lines, the channel values, the
Euler-to-matrix temporaries, local and global rotations and positions): 843 bytes measured on CMU 01_06
(31 joints, 5134 frames, tracemalloc); checked against ``SMPLIK_MAX_MEMORY_BYTES`` before the frames are parsed."""


def _parse_motion(lines: list[str], motion_line: int, num_channels: int, name: str, num_joints: int = 0
                  ) -> tuple[np.ndarray, float]:
    after = lines[motion_line].split()[1:]
    if after:  # "MOTION Frames: 10" on one line: keep the rest
        lines = lines[: motion_line + 1] + [" ".join(after)] + lines[motion_line + 1:]
    raw, i = _header_value(lines, motion_line + 1, "Frames:", name)
    try:
        num_frames = int(raw)
    except ValueError:
        raise BVHError(f"{name}: line {i}: 'Frames:' must be an integer, found {raw!r}") from None
    if num_frames < 0:
        raise BVHError(f"{name}: line {i}: negative frame count {num_frames}")
    BVH_FRAMES.check(num_frames, f"{name}: line {i}: 'Frames: {num_frames}'")
    check_array((num_frames, num_channels), 8, f"{name}: {num_frames} frames of {num_channels} channels")
    MEMORY_BYTES.check(num_frames * max(num_joints, 1) * MOTION_BYTES_PER_JOINT_FRAME,
                       f"{name}: {num_frames} frames of {num_joints} joints, parsed at {MOTION_BYTES_PER_JOINT_FRAME} "
                       "bytes a joint and frame")
    raw, i = _header_value(lines, i, "Frame Time:", name)
    try:
        frame_time = float(raw)
    except ValueError:
        raise BVHError(f"{name}: line {i}: 'Frame Time:' must be a number, found {raw!r}") from None
    if not (np.isfinite(frame_time) and frame_time >= MIN_FRAME_TIME_S):
        raise BVHError(f"{name}: line {i}: 'Frame Time:' must be a finite number of seconds >= {MIN_FRAME_TIME_S:g}, "
                       f"found {raw!r}")
    data_start = i
    rows = [k for k, ln in enumerate(lines[data_start:], start=data_start + 1) if ln.strip()]  # line numbers
    if len(rows) < num_frames:
        last = rows[-1] if rows else data_start
        raise BVHError(f"{name}: truncated file: 'Frames: {num_frames}' but only {len(rows)} frame lines "
                       f"(file ends after line {last})")
    if len(rows) > num_frames:
        raise BVHError(f"{name}: line {rows[num_frames]}: {len(rows)} frame lines but 'Frames: {num_frames}'")
    values = np.empty((num_frames, num_channels))  # one line split at a time: memory is the array's
    for f, line_no in enumerate(rows):
        row = lines[line_no - 1].split()
        if len(row) != num_channels:
            raise BVHError(f"{name}: line {line_no}: frame {f} has {len(row)} values, the hierarchy declares "
                           f"{num_channels} channels" + (" (truncated file?)" if f == len(rows) - 1 else ""))
        try:
            values[f] = np.array(row, dtype=np.float64) if num_channels else values[f]
        except ValueError:
            bad = next(v for v in row if not _is_number(v))
            raise BVHError(f"{name}: line {line_no}: frame {f}: {bad!r} is not a number") from None
    rows = [(line_no, None) for line_no in rows]
    if not np.isfinite(values).all():
        f = int(np.nonzero(~np.isfinite(values).all(axis=1))[0][0])
        raise BVHError(f"{name}: line {rows[f][0]}: frame {f} holds a non-finite value")
    return values, frame_time


# ----------------------------------------------------------------------------- writing


def format_bvh(
    joint_names: Sequence[str],
    parents: Sequence[int],
    offsets: np.ndarray,
    channels: Sequence[Sequence[str]],
    values: np.ndarray,
    frame_time: float,
    end_sites: dict[int, Sequence[float]] | None = None,
    precision: int = 6,
) -> str:
    """BVH text for a skeleton and its channel values (T, C). ``end_sites``: joint index -> End Site OFFSET.

    Joints must be listed parents-first with exactly one root (index 0); the columns of
    ``values`` follow ``joint_names``' order. The file lists joints depth-first, so the columns
    are permuted to that order (reading the file back gives the joints in depth-first order).
    """
    J = len(joint_names)
    if len(parents) != J or offsets.shape != (J, 3) or len(channels) != J:
        raise ValueError("joint_names, parents, offsets (J, 3) and channels must describe the same J joints.")
    C = sum(len(c) for c in channels)
    if values.ndim != 2 or values.shape[1] != C:
        raise ValueError(f"Invalid values shape {values.shape}; expected (T, {C}).")
    end_sites = end_sites or {}
    children: dict[int, list[int]] = {j: [] for j in range(J)}
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    out: list[str] = ["HIERARCHY"]

    def num(x: float) -> str:
        return f"{x:.{precision}f}"

    order: list[int] = []  # depth-first, iteratively (deep chains need no recursion)
    stack: list[tuple[int, int, bool]] = [(0, 0, False)]
    while stack:
        j, depth, closing = stack.pop()
        pad = "\t" * depth
        if closing:
            if j in end_sites:
                out.extend([f"{pad}\tEnd Site", f"{pad}\t{{",
                            f"{pad}\t\tOFFSET {' '.join(num(x) for x in end_sites[j])}", f"{pad}\t}}"])
            out.append(f"{pad}}}")
            continue
        order.append(j)
        out.append(f"{pad}{'ROOT' if parents[j] < 0 else 'JOINT'} {joint_names[j]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET {' '.join(num(x) for x in offsets[j])}")
        out.append(f"{pad}\tCHANNELS {len(channels[j])} {' '.join(channels[j])}".rstrip())
        stack.append((j, depth, True))
        stack.extend((c, depth + 1, False) for c in reversed(children[j]))
    if sorted(order) != list(range(J)):
        raise ValueError("The skeleton must have exactly one root, joint 0, and parents listed before children.")
    starts = np.cumsum([0] + [len(c) for c in channels])
    columns = np.concatenate([np.arange(starts[j], starts[j + 1]) for j in order]).astype(np.int64)
    out += ["MOTION", f"Frames: {values.shape[0]}", f"Frame Time: {frame_time:.7f}"]
    out += [" ".join(num(x) for x in row) for row in values[:, columns]]
    return "\n".join(out) + "\n"


def write_bvh(path: str | Path, motion: BVHMotion, precision: int = 6) -> Path:
    """Write ``motion``'s hierarchy and raw channel values to ``path`` (atomically)."""
    end_sites = dict(zip(motion.end_site_parents, motion.end_site_offsets, strict=True))
    text = format_bvh(motion.joint_names, motion.parents, motion.offsets, motion.channels, motion.values,
                      motion.frame_time, end_sites, precision)
    return write_text_atomic(path, text)
