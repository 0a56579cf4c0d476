"""Benchmark files (format :data:`BENCHMARK_VERSION`): making, loading, and the subjects of their samples.

:func:`make_benchmark` builds the files once from one split of a pose cache with a stored seed,
into a folder holding ``manifest.json`` and one ``.npz`` per set:

* ``random_06`` ... ``random_12``: N = 6..12 effectors per pose. Joints are grouped in
  :data:`ZONES` (pelvis/hips, torso/head, left arm, right arm, left leg, right leg). The first
  four effectors are one position effector on a random joint of each limb zone
  (:data:`LIMB_ZONES`); each further effector takes a random zone, a random joint in it and a
  random type (position, rotation, look-at), redrawn until its (joint, type) pair is new.
* ``fixed_5pt`` (spine3, wrists, ankles) and ``fixed_6pt`` (pelvis, neck, wrists, ankles):
  position effectors only.

Every set draws its own frames (without replacement when the split is large enough), and per
sample a body ``beta ~ N(0, I)`` and a gender uniform over neutral/male/female; the frame's
local rotations and translation are kept (no augmentation) and the joints recomputed by FK on
that body. Effectors are exact (tolerance 0, no noise): positions are the joints' world positions,
rotations their global rotations (stored as 6D), look-at targets lie at a distance
``0.1 + 2 |N(0, 1)|`` m along a random unit direction in the joint's frame (as in training). Set
``i`` uses ``numpy.random.default_rng([seed, i])``; the ``.npz`` files are written with sorted
keys and fixed zip timestamps, so the same seed, cache and body models give identical bytes.

``.npz`` keys (S samples, N effectors): ``R_local (S, 24, 3, 3)``, ``transl (S, 3)``,
``betas (S, 10)``, ``gender (S,)`` (:class:`Gender` index), ``joints (S, 24, 3)``, ``frame (S,)``
(row in the split), ``eff_joint (S, N)``, ``eff_type (S, N)``, ``eff_data (S, N, 6)`` (packed as in
:mod:`smplik.effectors`), ``eff_tolerance (S, N)``; floats are float32.

A sample's subject is the subject of its ``frame`` in the source cache's split
(:func:`sample_subjects`; the cache names subjects after its clips, e.g. CMU ``13_29`` -> ``13``).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from smplik.atomic import atomic_path, write_npz_deterministic
from smplik.body_model import BodyModelSet
from smplik.conventions import JOINT_INDEX, LIMB_ZONES, NUM_BETAS, ZONES, EffectorType, Gender
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix

BENCHMARK_FORMAT = "smplik-benchmark"
BENCHMARK_VERSION = 1
MANIFEST = "manifest.json"

RANDOM_COUNTS = tuple(range(6, 13))
FIXED_SETS: dict[str, tuple[str, ...]] = {
    "fixed_5pt": ("spine3", "left_wrist", "right_wrist", "left_ankle", "right_ankle"),
    "fixed_6pt": ("pelvis", "neck", "left_wrist", "right_wrist", "left_ankle", "right_ankle"),
}
LOOKAT_DISTANCE_STD = 2.0


def set_names() -> list[str]:
    """Set names in file order: random_06..random_12, then the fixed sets."""
    return [f"random_{n:02d}" for n in RANDOM_COUNTS] + list(FIXED_SETS)


def _sha256(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


# ----------------------------------------------------------------------------- making the files


def _sample_effector_layout(rng: np.random.Generator, num: int) -> tuple[np.ndarray, np.ndarray]:
    """One random set's (joint, type) pairs: a position per limb zone, then random zone/type. -> (N,), (N,)."""
    zones = list(ZONES)
    pairs: list[tuple[int, int]] = []
    for zone in LIMB_ZONES:
        names = ZONES[zone]
        pairs.append((JOINT_INDEX[names[rng.integers(len(names))]], int(EffectorType.POSITION)))
    while len(pairs) < num:
        names = ZONES[zones[rng.integers(len(zones))]]
        pair = (JOINT_INDEX[names[rng.integers(len(names))]], int(rng.integers(3)))
        if pair not in pairs:
            pairs.append(pair)
    arr = np.array(pairs, dtype=np.int64)
    return arr[:, 0], arr[:, 1]


def _effector_data(rng: np.random.Generator, joint: np.ndarray, kind: np.ndarray, R_world: np.ndarray,
                   p_world: np.ndarray) -> np.ndarray:
    """Exact effector data (S, N, 6) from ground truth. joint/kind (S, N); R_world (S, 24, 3, 3); p_world (S, 24, 3)."""
    S, N = joint.shape
    rows = np.arange(S)[:, None]
    pos = p_world[rows, joint]  # (S, N, 3)
    rot = R_world[rows, joint]  # (S, N, 3, 3)
    d_local = rng.standard_normal((S, N, 3))
    d_local /= np.linalg.norm(d_local, axis=-1, keepdims=True)
    dist = 0.1 + LOOKAT_DISTANCE_STD * np.abs(rng.standard_normal((S, N, 1)))
    target = pos + dist * np.einsum("snij,snj->sni", rot, d_local)
    data = np.zeros((S, N, 6))
    is_pos, is_rot, is_look = (kind == 0), (kind == 1), (kind == 2)
    data[is_pos, :3] = pos[is_pos]
    data[is_rot] = np.concatenate([rot[is_rot][..., :, 0], rot[is_rot][..., :, 1]], axis=-1)
    data[is_look] = np.concatenate([target[is_look], d_local[is_look]], axis=-1)
    return data


SAMPLE_BYTES = 16384
"""Memory one sample of a set takes (an upper estimate) while :func:`make_benchmark` builds it (float64 local and
world rotations, positions, rest joints, effector layout and data, their float32 copies), checked before a set is
drawn."""


def make_benchmark(data: str | Path, out: str | Path, *, split: str = "test", seed: int = 0,
                   samples_per_count: int = 500, model_dir: str | Path | None = None) -> Path:
    """Write the benchmark files (see the module docstring) into ``out``; returns the manifest path.

    Raises:
        ValueError: unknown split, empty split, or a non-positive sample count.
    """
    from smplik.data.dataset import load_cache

    if samples_per_count < 1:
        raise ValueError(f"samples_per_count must be positive, got {samples_per_count}.")
    from smplik.limits import MEMORY_BYTES

    MEMORY_BYTES.check(samples_per_count * SAMPLE_BYTES, f"--samples-per-count {samples_per_count} (one set's "
                       f"arrays at {SAMPLE_BYTES} bytes a sample)")
    dataset = load_cache(data).subset(split)
    if len(dataset) == 0:
        raise ValueError(f"{data}: the {split!r} split is empty.")
    bodies = BodyModelSet.load(model_dir)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pose_all = dataset.pose.double()
    transl_all = dataset.transl.double()
    S = samples_per_count
    entries = []
    for set_index, name in enumerate(set_names()):
        rng = np.random.default_rng([seed, set_index])
        frame = rng.choice(len(dataset), size=S, replace=S > len(dataset))
        betas = rng.standard_normal((S, NUM_BETAS))
        gender = rng.integers(0, len(Gender), size=S)
        R_local = axis_angle_to_matrix(pose_all[torch.from_numpy(frame)])
        transl = transl_all[torch.from_numpy(frame)]
        J_rest = bodies.rest_joints(torch.from_numpy(betas), torch.from_numpy(gender))
        R_world, p_world = forward_kinematics(R_local, J_rest, transl)
        if name.startswith("random_"):
            num = int(name.split("_")[1])
            layouts = [_sample_effector_layout(rng, num) for _ in range(S)]
            joint = np.stack([j for j, _ in layouts])
            kind = np.stack([k for _, k in layouts])
            fixed: list[str] | None = None
        else:
            fixed = list(FIXED_SETS[name])
            joint = np.tile([JOINT_INDEX[j] for j in fixed], (S, 1))
            kind = np.zeros_like(joint)
        eff_data = _effector_data(rng, joint, kind, R_world.numpy(), p_world.numpy())
        arrays = {
            "R_local": R_local.numpy().astype(np.float32),
            "transl": transl.numpy().astype(np.float32),
            "betas": betas.astype(np.float32),
            "gender": gender.astype(np.int8),
            "joints": p_world.numpy().astype(np.float32),
            "frame": frame.astype(np.int64),
            "eff_joint": joint.astype(np.int16),
            "eff_type": kind.astype(np.int8),
            "eff_data": eff_data.astype(np.float32),
            "eff_tolerance": np.zeros(joint.shape, np.float32),
        }
        path = write_npz_deterministic(out / f"{name}.npz", arrays)
        entries.append({"name": name, "file": path.name, "kind": "random" if fixed is None else "fixed",
                        "num_effectors": int(joint.shape[1]), "samples": S, "joints": fixed,
                        "sha256": _sha256(path)})
    manifest = {
        "format": BENCHMARK_FORMAT,
        "version": BENCHMARK_VERSION,
        "seed": int(seed),
        "source": {"data": str(data), "split": split, "frames_in_split": len(dataset)},
        "samples_per_count": S,
        "body_fingerprint": bodies.fingerprint,
        "zones": {k: list(v) for k, v in ZONES.items()},
        "limb_zones": list(LIMB_ZONES),
        "lookat_distance": f"0.1 + {LOOKAT_DISTANCE_STD} * |N(0, 1)| m",
        "sets": entries,
    }
    path = out / MANIFEST
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return path


# ----------------------------------------------------------------------------- loading


@dataclass(frozen=True)
class BenchmarkSet:
    """One benchmark set (float32 tensors). S samples of N effectors.

    Attributes:
        name, kind ("random" | "fixed"), num_effectors.
        R_local (S, 24, 3, 3), transl (S, 3), betas (S, 10), gender (S,) long, joints (S, 24, 3): ground truth.
        effectors: the packed effectors (S rows of N, no padding).
        frame: (S,) long, each sample's row in the source split (None for a set built in memory).
    """

    name: str
    kind: str
    num_effectors: int
    R_local: Tensor
    transl: Tensor
    betas: Tensor
    gender: Tensor
    joints: Tensor
    effectors: EffectorBatch
    frame: Tensor | None = None

    def __len__(self) -> int:
        return int(self.R_local.shape[0])

    def head(self, n: int) -> BenchmarkSet:
        """The first ``n`` samples."""
        e = self.effectors
        return BenchmarkSet(self.name, self.kind, self.num_effectors, self.R_local[:n], self.transl[:n],
                            self.betas[:n], self.gender[:n], self.joints[:n],
                            EffectorBatch(e.joint[:n], e.type[:n], e.data[:n], e.tolerance[:n], e.mask[:n]),
                            None if self.frame is None else self.frame[:n])


@dataclass(frozen=True)
class Benchmark:
    """Loaded benchmark files: the manifest and the sets in manifest order."""

    manifest: dict[str, Any]
    sets: tuple[BenchmarkSet, ...]
    folder: str


class BenchmarkFileError(ValueError):
    """A benchmark folder's manifest or one of its files is malformed (the message names file and key)."""


_SET_ARRAYS = {  # key: (shape after S, integer?, value range or None)
    "eff_joint": (("N",), True, (0, 23)), "eff_type": (("N",), True, (0, len(EffectorType) - 1)),
    "eff_data": (("N", 6), False, None), "eff_tolerance": (("N",), False, (0.0, 1.0)),
    "R_local": ((24, 3, 3), False, (-1.0001, 1.0001)), "transl": ((3,), False, (-1e3, 1e3)),
    "betas": ((NUM_BETAS,), False, (-1e3, 1e3)), "gender": ((), True, (0, len(Gender) - 1)),
    "joints": ((24, 3), False, (-1e3, 1e3)), "frame": ((), True, (0, 2**62)),
}


def _manifest_entry(entry: Any, i: int, mpath: Path) -> tuple[str, str, str, str]:
    """(file, sha256, name, kind) of ``sets[i]``, each a string; the file a plain name in the folder."""
    if not isinstance(entry, dict):
        raise BenchmarkFileError(f"{mpath}: sets[{i}] is {type(entry).__name__}, not an object.")
    values = []
    for key in ("file", "sha256", "name", "kind"):
        value = entry.get(key)
        if not isinstance(value, str) or not value or len(value) > 200:
            raise BenchmarkFileError(f"{mpath}: sets[{i}].{key} is missing or not a short string.")
        values.append(value)
    if Path(values[0]).name != values[0] or values[0] in (".", "..") or not values[0].endswith(".npz"):
        raise BenchmarkFileError(f"{mpath}: sets[{i}].file must be the name of an .npz file in the folder, got "
                                 f"{values[0]!r:.80}.")
    return values[0], values[1], values[2], values[3]


def _set_arrays(path: Path) -> dict[str, np.ndarray]:
    """A set file's arrays, bounded (:func:`smplik.safe_pickle.read_npz`) and checked: keys, shapes, dtypes, ranges."""
    from smplik.safe_pickle import read_npz

    try:
        a = read_npz(path, allow_objects=False)
    except ValueError as exc:
        raise BenchmarkFileError(str(exc)) from None
    S = N = None
    for key, (tail, integer, bounds) in _SET_ARRAYS.items():
        if key not in a:
            raise BenchmarkFileError(f"{path}: missing array '{key}'.")
        arr = a[key]
        if not isinstance(arr, np.ndarray) or arr.dtype.kind not in ("iu" if integer else "iuf") or arr.ndim < 1:
            raise BenchmarkFileError(f"{path}: array '{key}' must hold {'integers' if integer else 'numbers'}, got "
                                     f"{getattr(arr, 'dtype', type(arr).__name__)}.")
        S = arr.shape[0] if S is None else S
        if key == "eff_joint" and arr.ndim == 2:
            N = arr.shape[1]
        expected = (S, *(N if d == "N" else d for d in tail))
        if arr.shape != expected or N is None or N < 1:
            raise BenchmarkFileError(f"{path}: array '{key}' has shape {arr.shape}; expected {expected} (S samples, "
                                     "N effectors).")
        if not integer and not np.isfinite(arr).all():
            raise BenchmarkFileError(f"{path}: array '{key}' contains NaN or inf.")
        if bounds is not None and arr.size and (arr.min() < bounds[0] or arr.max() > bounds[1]):
            raise BenchmarkFileError(f"{path}: array '{key}' has values outside [{bounds[0]}, {bounds[1]}].")
    return a


def load_benchmark(folder: str | Path, *, verify: bool = True) -> Benchmark:
    """Read a benchmark folder. ``verify`` checks each file's SHA-256 against the manifest.

    Every manifest field and array is checked before use (keys, types, shapes, ranges; sizes bounded by
    :mod:`smplik.limits`), so a malformed folder gives one :class:`BenchmarkFileError` naming file and key.

    Raises:
        FileNotFoundError: no manifest. ValueError: another format or version, a modified or malformed file.
    """
    from smplik.validation import read_json

    folder = Path(folder)
    mpath = folder / MANIFEST
    if not mpath.is_file():
        raise FileNotFoundError(f"No {MANIFEST} in {folder}; create the files with `smplik benchmark make`.")
    manifest = read_json(mpath, BenchmarkFileError, what="benchmark manifest")
    if not isinstance(manifest, dict) or manifest.get("format") != BENCHMARK_FORMAT:
        raise BenchmarkFileError(f"{mpath}: not an smplik benchmark manifest.")
    if manifest.get("version") != BENCHMARK_VERSION:
        raise BenchmarkFileError(f"{mpath}: benchmark version {str(manifest.get('version'))[:20]}, this smplik reads "
                                 f"{BENCHMARK_VERSION}; re-create the files with `smplik benchmark make`.")
    source = manifest.get("source")
    if not (isinstance(source, dict) and isinstance(source.get("data"), str) and isinstance(source.get("split"), str)
            and type(source.get("frames_in_split")) is int):
        raise BenchmarkFileError(f"{mpath}: 'source' must hold 'data' and 'split' (strings) and 'frames_in_split' "
                                 "(an integer).")
    for key in ("seed", "samples_per_count"):
        if type(manifest.get(key)) is not int:
            raise BenchmarkFileError(f"{mpath}: '{key}' is missing or not an integer.")
    if manifest.get("body_fingerprint") is not None and not isinstance(manifest["body_fingerprint"], str):
        raise BenchmarkFileError(f"{mpath}: 'body_fingerprint' must be a string.")
    entries = manifest.get("sets")
    if not isinstance(entries, list) or not entries:
        raise BenchmarkFileError(f"{mpath}: 'sets' must be a non-empty list.")
    sets = []
    for i, entry in enumerate(entries):
        file, sha256, name, kind = _manifest_entry(entry, i, mpath)
        path = folder / file
        if not path.is_file():
            raise BenchmarkFileError(f"{mpath}: sets[{i}].file {file} does not exist in {folder}.")
        if verify and _sha256(path) != sha256:
            raise BenchmarkFileError(f"{path}: content differs from the manifest's SHA-256 (modified file?).")
        a = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in _set_arrays(path).items()}
        S, N = a["eff_joint"].shape
        eff = EffectorBatch(a["eff_joint"].long(), a["eff_type"].long(), a["eff_data"].float(),
                            a["eff_tolerance"].float(), torch.ones(S, N, dtype=torch.bool))
        sets.append(BenchmarkSet(name, kind, N, a["R_local"].float(), a["transl"].float(), a["betas"].float(),
                                 a["gender"].long(), a["joints"].float(), eff, a["frame"].long()))
    return Benchmark(manifest, tuple(sets), str(folder))


def sample_subjects(bench: Benchmark, dataset: Any) -> dict[str, tuple[str, ...]]:
    """Each set's per-sample subject names: set name -> S names.

    Args:
        bench: loaded benchmark files.
        dataset: the source pose cache (:class:`smplik.data.dataset.PoseDataset`, whole or already the
            manifest's split); the subject of a sample is ``subject_names[subject_id[frame]]`` in that split.

    Raises:
        ValueError: the cache's split does not have the manifest's frame count (another cache).
    """
    source = bench.manifest["source"]
    split = dataset.subset(source["split"])  # idempotent: a subset keeps its rows' split column
    if len(split) != source["frames_in_split"]:
        raise ValueError(f"{dataset.source or 'pose cache'}: its {source['split']!r} split has {len(split)} frames, "
                         f"the benchmark {bench.folder} was made from one with {source['frames_in_split']}; "
                         "pass the cache the files were made from.")
    out = {}
    for bset in bench.sets:
        if bset.frame is None:
            raise ValueError(f"{bench.folder}: set {bset.name} has no frame indices.")
        ids = split.subject_id[bset.frame].tolist()
        out[bset.name] = tuple(split.subject_names[i] for i in ids)
    return out

