"""VR recordings as CSV: the per-frame headset + controller layouts that VR studies and tools publish.

One row per sample, one column per coordinate; the header names each device and coordinate. Producers whose
layouts are read (each with a fixture in its exact column layout in ``tests/test_tracking_recordings.py``):

* ``who-is-alyx``: the *Who Is Alyx?* dataset (Schell, Sieper, Latoschik 2022, doi 10.5281/zenodo.6472410; CC BY-NC-SA
  4.0, so not committed here; 37 players of Half-Life: Alyx on an HTC Vive Pro, recorded through OpenVR at 60
  falling to 10-15 frames/s; ``players/<id>/<date>/vr-controllers.csv``): ``timestamp, delta_time_ms`` (ms since
  the start), ``hmd_pos_x .. hmd_rot_w, left_controller_pos_x .. left_controller_rot_w, right_controller_pos_x ..``,
  then the buttons (``left_controller_trigger``, ...); a few rows have empty controller cells.
* ``unity-hmd-recorder``: Unity HMD Recorder (Meta Quest, Meta XR SDK ``OVRCameraRig`` anchors,
  ``HMDDataRecorder.cs``): ``timestamp_ms, frame, unity_time, hmd_pos_x .. hmd_rot_w, left_pos_x .., right_pos_x ..``.
* ``omnicept``: HP Omnicept Unity samples (``HeadTrackingData.cs``): ``time_stamp, head_pos_x .. head_rot_w,
  lefthand_pos_x .. lefthand_rot_w, righthand_pos_x ..``.
* ``magic-xroom``: Magic XRoom ``VR_*.csv`` logs: ``timestamp, head_posX .. head_rotW, lcontroller_posX ..
  (version 1.0 spells lcontroller_pposY), rcontroller_posX ..``.

Any other header of the same shape is read too (``<device>_<pos|rot>_<x|y|z|w>`` with device names such as
hmd/head/headset, left/lcontroller/left_controller/lefthand, right/..., waist/pelvis/tracker; separators and case
free), named ``generic``.

Detected, each with an override: **units** (``units``: m, cm or mm; from the median head-to-controller distance,
about half a metre for any user), **time unit** (``time_unit``: s, ms, us or ns; from the column name's suffix,
else from the median interval, VR runs at 30-144 Hz), elapsed times or per-row intervals (a ``delta``/``dt``
column that does not increase is summed), **axes** (``axes``: ``openvr``, right-handed, the headset looking
along its -z, or ``unity``, left-handed, looking along +z: the one in which the controllers are in front of the
headset, else the producer's). Samples need not be regular (repeated timestamps are dropped); a row with an empty
or non-numeric cell, or a zero quaternion, is a lost pose for that device and is interpolated. Anything else is
refused with one line naming the file and what is missing (:class:`smplik.tracking.io.TrackerFileError`).
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smplik.tracking.calibrate import DeviceRecording
from smplik.tracking.io import MAX_FRAMES, TrackerFileError

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
AXES = ("openvr", "unity")


@dataclass(frozen=True)
class Producer:
    """A published CSV layout: ``name``, ``title`` (who writes it), ``signature`` (normalised columns that
    identify it), ``axes`` (its default handedness), ``controller`` (:data:`smplik.tracking.calibrate.CONTROLLERS`
    key of its controllers' tracked frame)."""

    name: str
    title: str
    signature: frozenset[str]
    axes: str
    controller: str


PRODUCERS: tuple[Producer, ...] = (
    Producer("who-is-alyx", "Who Is Alyx? dataset (HTC Vive Pro)",
             frozenset({"delta_time_ms", "hmd_pos_x", "left_controller_pos_x", "right_controller_rot_w"}),
             "openvr", "vive"),
    Producer("unity-hmd-recorder", "Unity HMD Recorder (Meta Quest, OVRCameraRig)",
             frozenset({"timestamp_ms", "unity_time", "hmd_pos_x", "left_pos_x", "right_rot_w"}), "unity", "touch"),
    Producer("omnicept", "HP Omnicept Unity samples (HeadTrackingData)",
             frozenset({"time_stamp", "head_pos_x", "lefthand_pos_x", "righthand_rot_w"}), "unity", "none"),
    Producer("magic-xroom", "Magic XRoom VR log",
             frozenset({"timestamp", "head_posx", "lcontroller_posx", "rcontroller_rotw"}), "unity", "none"),
)
GENERIC = Producer("generic", "a headset + controllers CSV", frozenset(), "openvr", "none")

_DEVICES = {
    "hmd": ("hmd", "head", "headset", "camera", "centereye", "center_eye", "maincamera", "main_camera", "eye"),
    "left": ("left_controller", "lcontroller", "l_controller", "leftcontroller", "controller_left", "left_hand",
             "lefthand", "lhand", "l_hand", "left"),
    "right": ("right_controller", "rcontroller", "r_controller", "rightcontroller", "controller_right", "right_hand",
              "righthand", "rhand", "r_hand", "right"),
    "waist": ("waist", "waist_tracker", "pelvis", "hip", "hips", "tracker", "tracker_0", "tracker0"),
}
_DEVICE_OF = {alias: dev for dev, aliases in _DEVICES.items() for alias in aliases}
_COLUMN = re.compile(r"^(?P<dev>[a-z0-9_]+?)_?(?P<kind>p?pos|position|rot|rotation|quat|quaternion|orientation|ori|q)"
                     r"_?(?P<axis>[xyzw])$")
_TIME = re.compile(r"(time|stamp|^t$|^dt$|delta)")
_TIME_SUFFIX = {"ms": "ms", "msec": "ms", "millis": "ms", "milliseconds": "ms", "s": "s", "sec": "s", "secs": "s",
                "seconds": "s", "us": "us", "usec": "us", "microseconds": "us", "ns": "ns", "nsec": "ns",
                "nanoseconds": "ns"}


def normalise(name: str) -> str:
    """A header cell as matched: lower case, runs of other characters than letters and digits -> ``_``."""
    return re.sub(r"[^a-z0-9]+", "_", name.strip().strip('"').lower()).strip("_")


def _time_column(cols: list[str], table: np.ndarray) -> int | None:
    """The time column: of the time-like columns whose cells are numbers (a date-time text is not read), one with
    an explicit unit suffix first, then the first."""
    cands = [i for i, c in enumerate(cols) if _TIME.search(c) and c not in ("frame", "frame_count")
             and np.isfinite(table[:, i]).mean() > 0.99]
    if not cands:
        return None
    with_unit = [i for i in cands if cols[i].rsplit("_", 1)[-1] in _TIME_SUFFIX and "_" in cols[i]]
    return (with_unit or cands)[0]


def _time_unit_of(name: str) -> str | None:
    if "100ns" in name:
        return None
    tail = name.rsplit("_", 1)[-1] if "_" in name else ""
    return _TIME_SUFFIX.get(tail)


def _layout(cols: list[str], err: str) -> tuple[dict[str, dict[str, dict[str, int]]], Producer]:
    """{device: {"pos": {axis: column}, "rot": {axis: column}}} and the producer."""
    found: dict[str, dict[str, dict[str, int]]] = {}
    for i, c in enumerate(cols):
        m = _COLUMN.match(c)
        if not m:
            continue
        dev = _DEVICE_OF.get(m["dev"].rstrip("_"))
        if dev is None:
            continue
        kind = "pos" if m["kind"] in ("pos", "ppos", "position") else "rot"
        found.setdefault(dev, {}).setdefault(kind, {}).setdefault(m["axis"], i)
    missing = [d for d in ("hmd", "left", "right") if set(found.get(d, {}).get("pos", {})) != set("xyz")]
    if missing:
        names = {"hmd": "headset", "left": "left controller", "right": "right controller"}
        example = {"hmd": "hmd_pos_x", "left": "left_controller_pos_x", "right": "right_controller_pos_x"}
        raise TrackerFileError(f"{err}: not a VR recording: no {names[missing[0]]} position columns (expected e.g. "
                               f"{example[missing[0]]}, _y, _z; columns: {', '.join(cols[:12])}"
                               f"{', ...' if len(cols) > 12 else ''}).")
    if set(found["hmd"].get("rot", {})) != set("xyzw"):
        raise TrackerFileError(f"{err}: no headset rotation quaternion columns (e.g. hmd_rot_x, _y, _z, _w); the "
                               "head's rotation is needed (Euler angles are not read).")
    colset = set(cols)
    producer = next((p for p in PRODUCERS if p.signature <= colset or p.signature <= {c.replace("pposy", "posy")
                                                                                        for c in colset}), GENERIC)
    return found, producer


def _parse_rows(text: str, path: str) -> tuple[list[str], np.ndarray]:
    """Header (normalised) and the numeric table (rows, columns), NaN where a cell is empty or not a number.
    Lines of asterisks (separators some loggers write between runs) and blank lines are skipped."""
    sample = text[:4096]
    try:
        dialect = csv.Sniffer().sniff(sample, delimiters=",;\t")
        delim = dialect.delimiter
    except csv.Error:
        delim = ","
    reader = csv.reader(io.StringIO(text), delimiter=delim)
    header: list[str] | None = None
    rows: list[list[float]] = []
    for n, row in enumerate(reader):
        if not row or all(not c.strip() or set(c.strip()) <= {"*"} for c in row):
            continue
        if header is None:
            header = [normalise(c) for c in row]
            if not any(_COLUMN.match(c) for c in header):
                raise TrackerFileError(f"{path}: line {n + 1}: not a CSV header naming device columns (e.g. "
                                       f"hmd_pos_x); got {', '.join(row[:6])[:120]}.")
            continue
        if len(rows) >= MAX_FRAMES:
            raise TrackerFileError(f"{path}: more than {MAX_FRAMES} rows; at most {MAX_FRAMES} are read.")
        vals = []
        for c in row[:len(header)]:
            try:
                vals.append(float(c))
            except ValueError:
                vals.append(np.nan)
        vals += [np.nan] * (len(header) - len(vals))
        rows.append(vals)
    if header is None:
        raise TrackerFileError(f"{path}: empty CSV file.")
    if len(rows) < 2:
        raise TrackerFileError(f"{path}: fewer than 2 rows of samples.")
    table = np.asarray(rows, dtype=np.float64)
    table[~np.isfinite(table)] = np.nan
    return header, table


def _times(col: np.ndarray, name: str, time_unit: str | None, path: str) -> tuple[np.ndarray, str, bool]:
    """Seconds (N,) and the unit used, and whether per-row intervals were summed."""
    if np.isnan(col).any():
        raise TrackerFileError(f"{path}: column {name!r}: row {int(np.argmax(np.isnan(col))) + 2} has no time.")
    summed = False
    d = np.diff(col)
    if ("delta" in name or name in ("dt",)) and not (d > 0).all():
        if (col < 0).any():
            raise TrackerFileError(f"{path}: column {name!r}: negative intervals.")
        col, summed = np.concatenate([[0.0], np.cumsum(col[1:])]), True
        d = np.diff(col)
    if (d < 0).any():
        raise TrackerFileError(f"{path}: column {name!r}: time goes back at row {int(np.argmax(d < 0)) + 3}.")
    unit = time_unit or _time_unit_of(name)
    if unit is None:
        step = float(np.median(d[d > 0])) if (d > 0).any() else 0.0
        # VR samples at 30-144 Hz: 7-33 ms between rows, whatever the unit
        unit = min(TIME_UNITS, key=lambda u: abs(np.log(max(step, 1e-30) * TIME_UNITS[u] / 0.015)))
    return col * TIME_UNITS[unit], unit, summed


def _forward_evidence(times: np.ndarray, hmd: tuple[np.ndarray, np.ndarray, np.ndarray],
                      left: tuple[np.ndarray, np.ndarray, np.ndarray], right: tuple[np.ndarray, np.ndarray, np.ndarray],
                      both: np.ndarray) -> tuple[float, int]:
    """(mean sign, number of votes) that the headset's -z (OpenVR) rather than its +z (Unity) is forward: one vote
    per sample whose controllers' midpoint is more than 10 cm in front of or behind the headset (horizontally),
    one per sample where the headset moves faster than 0.5 m/s horizontally. Positions in any length unit: the
    thresholds are scaled by the median headset-to-controller distance (about 0.45 m)."""
    from smplik.rotations import quat_wxyz_to_matrix

    P, Q = hmd[0][both], hmd[1][both]
    fwd = -quat_wxyz_to_matrix(Q)[..., :, 2]
    fwd[:, 1] = 0.0
    mid = 0.5 * (left[0][both] + right[0][both]) - P
    unit = float(np.median(np.linalg.norm(mid, axis=1))) / 0.45 or 1.0
    mid[:, 1] = 0.0
    ahead = np.einsum("ij,ij->i", fwd, mid) / unit
    votes = [np.sign(ahead[np.abs(ahead) > 0.1])]
    if len(P) > 2:
        v = np.gradient(P, times[both], axis=0) / unit
        v[:, 1] = 0.0
        fast = np.linalg.norm(v, axis=1) > 0.5
        votes.append(np.sign(np.einsum("ij,ij->i", fwd[fast], v[fast])))
    allv = np.concatenate(votes)
    return (float(allv.mean()) if len(allv) else 0.0), len(allv)


def read_csv_devices(path: str | Path, *, units: str | None = None, time_unit: str | None = None,
                     axes: str | None = None) -> DeviceRecording:
    """Read a VR CSV recording (module docstring) into a :class:`DeviceRecording` in OpenVR axes and metres.
    ``units``, ``time_unit``, ``axes``: overrides of what is detected. Raises TrackerFileError (one line)."""
    from smplik.validation import read_text

    path = Path(path)
    src = str(path)
    for value, allowed, option in ((units, UNITS, "--csv-units"), (time_unit, TIME_UNITS, "--csv-time-unit"),
                                   (axes, AXES, "--csv-axes")):
        if value is not None and value not in allowed:
            raise TrackerFileError(f"{option} must be one of {', '.join(allowed)}, got {value!r}.")
    text = read_text(path, TrackerFileError, what="tracker file")
    cols, table = _parse_rows(text, src)
    found, producer = _layout(cols, src)
    ti = _time_column(cols, table)
    if ti is None:
        raise TrackerFileError(f"{src}: no time column of numbers (a column named time, timestamp, time_ms, "
                               "delta_time_ms, ...); the samples' times are needed to resample them.")
    times, tunit, summed = _times(table[:, ti], cols[ti], time_unit, src)
    keep = np.r_[True, np.diff(times) > 0]  # repeated timestamps: the first sample is kept
    times, table = times[keep], table[keep]
    if len(times) < 2 or times[-1] - times[0] <= 0:
        raise TrackerFileError(f"{src}: column {cols[ti]!r}: fewer than 2 distinct times.")

    def device(dev: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        spec = found.get(dev)
        if spec is None or set(spec.get("pos", {})) != set("xyz"):
            return None
        P = table[:, [spec["pos"][a] for a in "xyz"]]
        rot = spec.get("rot", {})
        if set(rot) == set("xyzw"):
            Q = table[:, [rot[a] for a in "wxyz"]]
        else:
            Q = np.tile([1.0, 0.0, 0.0, 0.0], (len(P), 1))
        valid = np.isfinite(P).all(1) & np.isfinite(Q).all(1)
        norm = np.linalg.norm(np.where(np.isfinite(Q), Q, 0.0), axis=1)
        valid &= norm > 1e-6
        Q = np.where(valid[:, None], Q / np.where(norm > 1e-6, norm, 1.0)[:, None], [1.0, 0.0, 0.0, 0.0])
        P = np.where(valid[:, None], P, 0.0)
        return P, Q, valid

    hmd, left, right, waist = device("hmd"), device("left"), device("right"), device("waist")
    assert hmd is not None and left is not None and right is not None  # _layout checked the columns
    for what, d in (("headset", hmd), ("left controller", left), ("right controller", right)):
        if d[2].sum() < 2:
            raise TrackerFileError(f"{src}: the {what} has fewer than 2 rows with a valid pose.")
    has_ctrl_rot = all(set(found[d].get("rot", {})) == set("xyzw") for d in ("left", "right"))

    # units: the head-to-controller distance is about half a metre whatever the user does
    both = hmd[2] & left[2] & right[2]
    if not both.any():
        raise TrackerFileError(f"{src}: no row where the headset and both controllers all have a valid pose.")
    dist = float(np.median(np.concatenate([np.linalg.norm(hmd[0][both] - left[0][both], axis=1),
                                           np.linalg.norm(hmd[0][both] - right[0][both], axis=1)])))
    unit = units or min(UNITS, key=lambda u: abs(np.log(max(dist, 1e-30) * UNITS[u] / 0.45)))
    if units is None and not 0.08 <= dist * UNITS[unit] <= 2.0:
        raise TrackerFileError(f"{src}: cannot tell the position units (median headset-to-controller distance "
                               f"{dist:g} in the file's units); give --csv-units m, cm or mm.")
    scale = UNITS[unit]

    # axes: in OpenVR the headset looks along its -z, in Unity along its +z; the forward one is where the
    # controllers are (when clearly in front or behind) and where the user walks (when walking)
    if axes is None:
        score, count = _forward_evidence(times, hmd, left, right, both)
        if count >= 10 and abs(score) > 0.3:
            axes, how = ("openvr" if score > 0 else "unity"), "detected"
        else:
            axes, how = producer.axes, f"the {producer.name} default"
    else:
        how = "given"
    flip = np.array([1.0, 1.0, -1.0]) if axes == "unity" else np.ones(3)
    qflip = np.array([1.0, -1.0, -1.0, 1.0]) if axes == "unity" else np.ones(4)

    def convert(d: tuple[np.ndarray, np.ndarray, np.ndarray] | None):
        if d is None:
            return None
        return d[0] * scale * flip, d[1] * qflip, d[2]

    notes = (f"layout {producer.name}", f"positions in {unit}", f"times in {tunit}" + (" (per-row intervals)"
                                                                                      if summed else ""),
             f"{axes} axes ({how})")
    return DeviceRecording(times - times[0], convert(hmd), convert(left), convert(right), convert(waist),
                           has_ctrl_rot, src, producer.name, notes)


def read_csv_trackers(path: str | Path, *, fps: float = 60.0, units: str | None = None,
                      time_unit: str | None = None, axes: str | None = None, controller: str | None = None):
    """Read a VR CSV recording (module docstring) as :class:`smplik.tracking.io.TrackerSignals` resampled to
    ``fps`` (head, left_wrist, right_wrist, and pelvis with a waist tracker). ``controller``: the controllers'
    kind (:data:`smplik.tracking.calibrate.CONTROLLERS`; default: the producer's)."""
    from smplik.tracking.calibrate import CalibrationError, signals_from_devices

    rec = read_csv_devices(path, units=units, time_unit=time_unit, axes=axes)
    producer = next((p for p in PRODUCERS if p.name == rec.producer), GENERIC)
    try:
        return signals_from_devices(rec, fps, producer.controller if controller is None else controller)
    except CalibrationError as exc:
        msg = str(exc)
        raise TrackerFileError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
