"""Pose dataset cache: many clips (BVH or AMASS) -> one compact ``.npz`` -> tensors for training.

Building (:func:`build_cache`): each source clip is read into a :class:`PoseSequence` (BVH
through :func:`smplik.data.retarget.retarget_bvh`, dropping its rest frame 0; AMASS through
:func:`smplik.data.amass.read_amass`), assigned to a split from a split file
(:func:`load_split`; or every clip in train, :func:`split_all_train`; or a seeded split of the
subjects, :func:`split_by_subject`), subsampled to the requested frame rate and appended. The cache is written
atomically (temporary file, then rename): an interrupted build leaves no partial file and keeps
a previous cache intact.

Cache layout (format version :data:`CACHE_VERSION`; N frames, C clips, S subjects):

==================  ==========  ==============================================================
key                 shape       meaning
==================  ==========  ==============================================================
``version``         ()          int, :data:`CACHE_VERSION`
``settings``        ()          JSON string: build settings (fps, preset, dtype, split, ...)
``pose``            (N, 24, 3)  float16/float32 axis-angle local rotations (root first)
``transl``          (N, 3)      float32 smplx translation, y-up, metres
``betas``           (N, 10)     float32 subject shape (zeros where ``has_betas`` is False)
``has_betas``       (N,)        bool, the source carries betas (AMASS) or not (BVH)
``gender``          (N,)        int8, :class:`Gender` index, -1 when unknown
``clip_id``         (N,)        int32 index into ``clip_names``
``subject_id``      (N,)        int32 index into ``subject_names``
``frame``           (N,)        int32 frame index in the source clip
``split``           (N,)        int8: 0 train, 1 validation, 2 test
``clip_names``      (C,)        str, clip name relative to the source folder
``clip_fps``        (C,)        float32, the source clip's frame rate
``subject_names``   (S,)        str
==================  ==========  ==============================================================

Split files use the CMU ``split.json`` format: ``{"train": {"subjects": [...], "files": [...]},
"validation": {...}, "test": {...}}`` (other keys inside a split, like ``motion_frames``, are
ignored; ``"clips"`` is accepted for ``"files"``). A clip listed by name (its path relative to
the source folder, its file name or its stem) goes to that split; otherwise its subject decides.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch
from torch import Tensor

from smplik.atomic import savez_atomic
from smplik.conventions import NUM_BETAS, NUM_JOINTS, Gender
from smplik.data.amass import PoseSequence, read_amass

if TYPE_CHECKING:
    from smplik.data.retarget import RigMapper

__all__ = [
    "CACHE_VERSION",
    "SPLIT_NAMES",
    "ClipSource",
    "SplitSpec",
    "CacheSummary",
    "PoseDataset",
    "PoseSequence",
    "find_sources",
    "load_split",
    "parse_split",
    "split_all_train",
    "split_by_subject",
    "subsample_indices",
    "read_source",
    "build_cache",
    "load_cache",
]

CACHE_VERSION = 1
SPLIT_NAMES: tuple[str, ...] = ("train", "validation", "test")
UNKNOWN_GENDER = -1
SourceKind = Literal["bvh", "amass"]
_SUFFIX: dict[str, str] = {"bvh": ".bvh", "amass": ".npz"}
_AMASS_METADATA_FILES = frozenset({"shape.npz"})  # AMASS per-subject betas files, no motion
_CACHE_KEYS = ("version", "settings", "pose", "transl", "betas", "has_betas", "gender", "clip_id", "subject_id",
               "frame", "split", "clip_names", "clip_fps", "subject_names")


# ----------------------------------------------------------------------------- sources and splits


@dataclass(frozen=True)
class ClipSource:
    """One input clip.

    Attributes:
        path: the file.
        kind: ``"bvh"`` or ``"amass"``.
        name: the clip's name (path relative to the source folder, POSIX separators).
        subject: the subject id: the clip's parent folder when it is in a sub-folder (AMASS:
            ``CMU/01/01_01_poses.npz`` -> ``01``), else the file name up to the first ``_``
            (CMU BVH: ``01_01.bvh`` -> ``01``).
    """

    path: Path
    kind: SourceKind
    name: str
    subject: str
    take: str | None = None
    """FBX files with several animated takes: the take this clip is (its name ends ``#<take>``)."""


def find_sources(root: str | Path, kind: SourceKind) -> list[ClipSource]:
    """All clips of ``kind`` under ``root`` (recursively, sorted by name), or the one clip file ``root``.

    AMASS's per-subject ``shape.npz`` files (betas only) are skipped.

    Raises:
        FileNotFoundError: ``root`` does not exist or is not a folder.
        ValueError: unknown kind, or no clip under ``root``.
    """
    if kind not in _SUFFIX:
        raise ValueError(f"Unknown source kind {kind!r}; expected one of: {', '.join(_SUFFIX)}.")
    root = Path(root)
    suffix = _SUFFIX[kind]
    suffixes = (".bvh", ".fbx") if kind == "bvh" else (suffix,)  # FBX clips are read as BVH (smplik.data.fbx)
    single = root.is_file() and root.suffix.lower() in suffixes  # one clip file: the same as its folder of one
    if not root.is_dir() and not single:
        raise FileNotFoundError(f"Source folder (or {'/'.join(suffixes)} file) not found: {root}")
    out = []
    paths = [root] if single else sorted(p for p in root.rglob("*") if p.suffix.lower() in suffixes)
    if single:
        root = root.parent
    for path in paths:
        if not path.is_file() or (kind == "amass" and path.name in _AMASS_METADATA_FILES):
            continue
        rel = path.relative_to(root)
        subject = rel.parent.name if len(rel.parts) > 1 else path.stem.split("_")[0]
        takes = _fbx_takes(path) if path.suffix.lower() == ".fbx" else []
        if len(takes) > 1:  # an animation pack: one clip per take
            out.extend(ClipSource(path=path, kind=kind, name=f"{rel.as_posix()}#{t}", subject=subject, take=t)
                       for t in takes)
        else:
            out.append(ClipSource(path=path, kind=kind, name=rel.as_posix(), subject=subject))
    if not out:
        raise ValueError(f"No {suffix} files{' (nor .fbx)' if kind == 'bvh' else ''} under {root}.")
    return out


def _fbx_takes(path: Path) -> list[str]:
    """Names of the animated takes of an FBX file ([] when it cannot be listed: reading it names the problem)."""
    from smplik.data.fbx import FbxError, read_fbx_takes

    try:
        return [t.name for t in read_fbx_takes(path) if t.animated > 0]
    except FbxError:
        return []


@dataclass(frozen=True)
class SplitSpec:
    """Which subjects and clips go to which split.

    Attributes:
        subjects: split name -> subject ids.
        clips: split name -> clip names (relative path, file name or stem).
        source: where the spec came from (a path), for messages and metadata.
    """

    subjects: Mapping[str, frozenset[str]]
    clips: Mapping[str, frozenset[str]]
    source: str = "<memory>"

    def assign(self, clip: ClipSource) -> int | None:
        """The split index (0 train, 1 validation, 2 test) of ``clip``, or None if unassigned.

        A clip listed by name wins over its subject.

        Raises:
            ValueError: the clip is listed by name in two splits.
        """
        names = {clip.name, Path(clip.name).name, Path(clip.name).stem}
        by_clip = [i for i, s in enumerate(SPLIT_NAMES) if names & self.clips.get(s, frozenset())]
        if len(by_clip) > 1:
            raise ValueError(f"{self.source}: clip {clip.name} is listed in several splits: "
                             f"{', '.join(SPLIT_NAMES[i] for i in by_clip)}.")
        if by_clip:
            return by_clip[0]
        for i, s in enumerate(SPLIT_NAMES):
            if clip.subject in self.subjects.get(s, frozenset()):
                return i
        return None

    def to_json(self) -> dict[str, Any]:
        return {s: {"subjects": sorted(self.subjects.get(s, ())), "files": sorted(self.clips.get(s, ()))}
                for s in SPLIT_NAMES}


def parse_split(obj: Any, source: str = "<memory>") -> SplitSpec:
    """Validate a split mapping (the ``split.json`` format); errors name the offending key."""
    if not isinstance(obj, Mapping):
        raise ValueError(f"{source}: a split file must hold a JSON object with keys {', '.join(SPLIT_NAMES)}.")
    unknown = [k for k in obj if k not in SPLIT_NAMES]
    if unknown:
        raise ValueError(f"{source}: unknown split key {unknown[0]!r}; expected {', '.join(SPLIT_NAMES)}.")
    if not obj:
        raise ValueError(f"{source}: no split key; expected some of {', '.join(SPLIT_NAMES)}.")
    subjects: dict[str, frozenset[str]] = {}
    clips: dict[str, frozenset[str]] = {}
    for name, entry in obj.items():
        if not isinstance(entry, Mapping):
            raise ValueError(f"{source}: key '{name}' must be an object with 'subjects' and/or 'files' lists.")
        if "files" in entry and "clips" in entry:
            raise ValueError(f"{source}: key '{name}' has both 'files' and 'clips'; use one.")
        lists: dict[str, frozenset[str]] = {}
        for key in ("subjects", "files", "clips"):
            if key not in entry:
                continue
            value = entry[key]
            if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
                raise ValueError(f"{source}: key '{name}.{key}' must be a list of non-empty strings.")
            lists[key] = frozenset(value)
        if not lists:
            raise ValueError(f"{source}: key '{name}' has neither 'subjects' nor 'files'.")
        subjects[name] = lists.get("subjects", frozenset())
        clips[name] = lists.get("files", lists.get("clips", frozenset()))
    for i, a in enumerate(SPLIT_NAMES):
        for b in SPLIT_NAMES[i + 1:]:
            for kind, table in (("subjects", subjects), ("files", clips)):
                both = table.get(a, frozenset()) & table.get(b, frozenset())
                if both:
                    raise ValueError(f"{source}: {kind} {', '.join(sorted(both)[:5])} listed in both "
                                     f"'{a}.{kind}' and '{b}.{kind}'.")
    return SplitSpec(subjects=subjects, clips=clips, source=source)


def split_all_train(sources: Sequence[ClipSource]) -> SplitSpec:
    """Every clip in train (what ``smplik data build`` does without ``--split``)."""
    return SplitSpec(subjects={"train": frozenset(s.subject for s in sources)}, clips={},
                     source="<no split file: every clip in train>")


def split_by_subject(sources: Sequence[ClipSource], seed: int) -> SplitSpec:
    """A seeded split of the subjects of ``sources``: 10 % validation and 10 % test (each at least one
    subject from three subjects on; two subjects: one train, one validation; one: train), the rest train."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise ValueError(f"the split seed must be a non-negative integer, got {seed!r:.40}.")
    subjects = sorted({s.subject for s in sources})
    n = len(subjects)
    order = [subjects[i] for i in np.random.default_rng(seed).permutation(n)]
    n_val = max(1, round(0.1 * n)) if n >= 3 else n - 1
    n_test = max(1, round(0.1 * n)) if n >= 3 else 0
    groups = {"validation": order[:n_val], "test": order[n_val:n_val + n_test], "train": order[n_val + n_test:]}
    return SplitSpec(subjects={k: frozenset(v) for k, v in groups.items()}, clips={},
                     source=f"<split by subject, seed {seed}>")


def load_split(path: str | Path) -> SplitSpec:
    """Read and validate a split file (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Split file not found: {path}")
    from smplik.validation import read_json

    obj = read_json(path, ValueError, what="split file")  # bounded read (smplik.limits.JSON_BYTES)
    return parse_split(obj, str(path))


# ----------------------------------------------------------------------------- reading and building


def subsample_indices(num_frames: int, source_fps: float, fps: float) -> np.ndarray:
    """Frame indices that resample ``num_frames`` frames from ``source_fps`` to ``fps`` (nearest frame).

    An integer ratio keeps every k-th frame, starting at frame 0 (120 -> 30 fps: 0, 4, 8, ...).

    Raises:
        ValueError: ``fps`` is not positive or exceeds ``source_fps`` (no upsampling).
    """
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}.")
    if fps > source_fps * (1 + 1e-6):
        raise ValueError(f"Cannot upsample: fps {fps} exceeds the source's {source_fps}.")
    step = source_fps / fps
    idx = np.round(np.arange(0, num_frames, step) + 1e-9).astype(np.int64)
    return np.unique(idx[idx < num_frames])


def _rest_pelvis_fn(body_models: Any) -> Callable[[np.ndarray | None, Gender | None], np.ndarray]:
    """``(betas, gender) -> J0 (3,)`` from a :class:`BodyModelSet` (neutral/zero betas when unknown)."""

    def rest_pelvis(betas: np.ndarray | None, gender: Gender | None) -> np.ndarray:
        b = torch.zeros(NUM_BETAS) if betas is None else torch.as_tensor(betas, dtype=torch.float32)
        g = torch.tensor((gender or Gender.NEUTRAL).index)
        return body_models.rest_joints(b, g)[0].double().numpy()

    return rest_pelvis


def read_source(source: ClipSource, *, preset: str = "auto", body_models: Any = None,
                rig_mapper: RigMapper | None = None) -> PoseSequence:
    """Read one clip as y-up SMPL poses.

    Args:
        source: the clip.
        preset: BVH rig preset for :func:`smplik.data.retarget.retarget_bvh` (``"auto"``: ``rig_mapper``
            maps each clip).
        body_models: a :class:`smplik.body_model.BodyModelSet` giving AMASS's rest pelvis for the
            z-up -> y-up translation (see :mod:`smplik.data.amass`); None assumes ``J0 = 0``.
        rig_mapper: the rig mapper behind ``preset="auto"`` (:func:`shape_inversion.auto_preset.auto_preset`);
            needed for BVH/FBX clips read with ``preset="auto"``.

    BVH clips drop the source's rest frames (the preset's ``motion_start``; frame 0 for CMU)
    and carry no betas or gender (the retargeted skeleton is the neutral beta = 0 body).
    """
    if source.kind == "amass":
        return read_amass(source.path, rest_pelvis=None if body_models is None else _rest_pelvis_fn(body_models))
    if source.kind == "bvh":
        from smplik.data.retarget import retarget_bvh  # BVH parsing is only needed for BVH sources

        if source.take is not None:
            from smplik.data.fbx import read_fbx

            clip = retarget_bvh(read_fbx(source.path, take=source.take), preset=preset,
                                rig_mapper=rig_mapper)
        else:
            clip = retarget_bvh(source.path, preset=preset, rig_mapper=rig_mapper)
        start = int(clip.motion_start)
        if clip.num_frames <= start:
            raise ValueError(f"{source.path}: no motion frames after the {start} rest frame(s).")
        return PoseSequence(
            global_orient=np.asarray(clip.global_orient[start:], dtype=np.float32),
            body_pose=np.asarray(clip.body_pose[start:], dtype=np.float32),
            transl=np.asarray(clip.transl[start:], dtype=np.float32),
            betas=None,
            gender=None,
            fps=float(clip.fps),
            source=str(source.path),
        )
    raise ValueError(f"Unknown source kind {source.kind!r}.")


@dataclass(frozen=True)
class CacheSummary:
    """What :func:`build_cache` wrote.

    Attributes:
        path: the cache file.
        frames: split name -> number of frames.
        clips: split name -> number of clips.
        skipped: clips assigned to no split (and left out).
        num_bytes: file size.
        seconds: build time.
    """

    path: Path
    frames: dict[str, int]
    clips: dict[str, int]
    skipped: tuple[str, ...]
    num_bytes: int
    seconds: float


def build_cache(
    sources: Sequence[ClipSource],
    *,
    fps: float,
    split: SplitSpec | str | Path | None,
    out: str | Path,
    preset: str = "auto",
    dtype: Literal["float16", "float32"] = "float32",
    body_models: Any = None,
    skip_unassigned: bool = False,
    progress: Callable[[ClipSource], None] | None = None,
    reader: Callable[[ClipSource], PoseSequence] | None = None,
    rig_mapper: RigMapper | None = None,
) -> CacheSummary:
    """Read, split, subsample and write ``sources`` as one cache ``.npz`` (atomically).

    Args:
        sources: clips, e.g. from :func:`find_sources`.
        fps: target frame rate (nearest-frame subsampling; a slower clip keeps every frame at its own rate,
            recorded in ``clip_fps``: no upsampling).
        split: a :class:`SplitSpec`, a split file path, or None for every clip in train
            (:func:`split_all_train`).
        out: the cache path (``.npz``); replaced only once the new cache is complete.
        preset: BVH rig preset for retargeting.
        dtype: storage dtype of the axis-angle rotations.
        body_models: :class:`~smplik.body_model.BodyModelSet` for AMASS's rest pelvis
            (default: loaded with :meth:`BodyModelSet.load` when there are AMASS sources).
        skip_unassigned: leave out clips of no split instead of raising.
        progress: called with each clip once it is done.
        reader: reads one clip (default :func:`read_source`); for tests and custom formats.
        rig_mapper: the rig mapper behind ``preset="auto"`` for BVH/FBX sources
            (:func:`shape_inversion.auto_preset.auto_preset`).

    Raises:
        ValueError: no sources, a bad split, an unassigned clip (unless skipped), a clip that
            cannot be read (the message names the file), nothing left to write.
    """
    start = time.perf_counter()
    out = Path(out)
    if out.suffix != ".npz":
        raise ValueError(f"The cache path must end in .npz, got {out}.")
    if not sources:
        raise ValueError("No source clips to build a cache from.")
    if dtype not in ("float16", "float32"):
        raise ValueError(f"Unknown dtype {dtype!r}; expected float16 or float32.")
    if isinstance(split, SplitSpec):
        spec = split
    else:
        spec = split_all_train(sources) if split is None else load_split(split)
    kinds = sorted({s.kind for s in sources})
    if reader is None:
        if "amass" in kinds and body_models is None:
            from smplik.body_model import BodyModelSet

            body_models = BodyModelSet.load()
        reader = functools.partial(read_source, preset=preset, body_models=body_models,
                                   rig_mapper=rig_mapper)

    assignments = [spec.assign(s) for s in sources]
    unassigned = tuple(s.name for s, a in zip(sources, assignments, strict=True) if a is None)
    if unassigned and not skip_unassigned:
        shown = ", ".join(unassigned[:5]) + (" ..." if len(unassigned) > 5 else "")
        raise ValueError(f"{len(unassigned)} clip(s) belong to no split in {spec.source}: {shown} "
                         "(add them to the split file, or pass --skip-unassigned / skip_unassigned=True to "
                         "leave them out).")

    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("pose", "transl", "betas", "has_betas", "gender",
                                                           "clip_id", "subject_id", "frame", "split")}
    clip_names: list[str] = []
    clip_fps: list[float] = []
    subjects: dict[str, int] = {}
    frames = dict.fromkeys(SPLIT_NAMES, 0)
    clips = dict.fromkeys(SPLIT_NAMES, 0)
    for src, split_index in zip(sources, assignments, strict=True):
        if split_index is None:
            if progress is not None:
                progress(src)
            continue
        try:
            seq = reader(src)
        except (ValueError, OSError, KeyError, IndexError) as exc:
            message = str(exc)
            raise ValueError(message if str(src.path) in message else f"{src.path}: {message}") from exc
        # a clip slower than ``fps`` (a 24 frames/s FBX take, 30 asked) keeps every frame at its own rate
        # (``clip_fps``); none is invented
        idx = subsample_indices(seq.num_frames, seq.fps, min(fps, seq.fps))
        n = len(idx)
        clip_id = len(clip_names)
        clip_names.append(src.name)
        clip_fps.append(seq.fps)
        subject_id = subjects.setdefault(src.subject, len(subjects))
        parts["pose"].append(seq.pose[idx].astype(dtype))
        parts["transl"].append(seq.transl[idx].astype(np.float32))
        has = seq.betas is not None
        parts["betas"].append(np.broadcast_to(seq.betas if has else np.zeros(NUM_BETAS), (n, NUM_BETAS))
                              .astype(np.float32))
        parts["has_betas"].append(np.full(n, has, dtype=bool))
        parts["gender"].append(np.full(n, UNKNOWN_GENDER if seq.gender is None else seq.gender.index, dtype=np.int8))
        parts["clip_id"].append(np.full(n, clip_id, dtype=np.int32))
        parts["subject_id"].append(np.full(n, subject_id, dtype=np.int32))
        parts["frame"].append(idx.astype(np.int32))
        parts["split"].append(np.full(n, split_index, dtype=np.int8))
        frames[SPLIT_NAMES[split_index]] += n
        clips[SPLIT_NAMES[split_index]] += 1
        if progress is not None:
            progress(src)
    if not clip_names or sum(frames.values()) == 0:
        raise ValueError("No frames to write: every clip was skipped or empty.")

    settings = {
        "fps": float(fps),
        "preset": preset,
        "dtype": dtype,
        "kinds": kinds,
        "source_roots": sorted({str(s.path.parent) for s in sources})[:20],
        "split_source": spec.source,
        "split": spec.to_json(),
        "split_sha256": hashlib.sha256(json.dumps(spec.to_json(), sort_keys=True).encode()).hexdigest(),
        "skipped": list(unassigned),
        "rest_pelvis": None if body_models is None else getattr(body_models, "fingerprint", None),
    }
    arrays = {k: np.concatenate(v) for k, v in parts.items()}
    savez_atomic(
        out,
        version=np.asarray(CACHE_VERSION, dtype=np.int64),
        settings=np.asarray(json.dumps(settings, sort_keys=True)),
        clip_names=np.asarray(clip_names, dtype=np.str_),
        clip_fps=np.asarray(clip_fps, dtype=np.float32),
        subject_names=np.asarray(list(subjects), dtype=np.str_),
        **arrays,
    )
    return CacheSummary(path=out, frames=frames, clips=clips, skipped=unassigned, num_bytes=out.stat().st_size,
                        seconds=time.perf_counter() - start)


# ----------------------------------------------------------------------------- loading


@dataclass(frozen=True)
class PoseDataset:
    """A loaded pose cache (torch tensors, CPU). N frames.

    Attributes:
        pose: (N, 24, 3) float32 axis-angle local rotations (root first).
        transl: (N, 3) float32 smplx translation, y-up.
        betas: (N, 10) float32 (zeros where ``has_betas`` is False).
        has_betas: (N,) bool.
        gender: (N,) long :class:`Gender` index, -1 when unknown.
        clip_id, subject_id, frame, split: (N,) long.
        clip_names, subject_names: name tables indexed by ``clip_id``/``subject_id``.
        settings: the build settings stored in the cache.
        source: the cache path.
    """

    pose: Tensor
    transl: Tensor
    betas: Tensor
    has_betas: Tensor
    gender: Tensor
    clip_id: Tensor
    subject_id: Tensor
    frame: Tensor
    split: Tensor
    clip_names: tuple[str, ...]
    subject_names: tuple[str, ...]
    settings: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    source: str = ""

    def __len__(self) -> int:
        return int(self.pose.shape[0])

    @property
    def fps(self) -> float:
        return float(self.settings.get("fps", float("nan")))

    @property
    def global_orient(self) -> Tensor:
        """(N, 3)."""
        return self.pose[:, 0]

    @property
    def body_pose(self) -> Tensor:
        """(N, 23, 3)."""
        return self.pose[:, 1:]

    def subset(self, split: str) -> PoseDataset:
        """The frames of one split (``"train"``, ``"validation"`` or ``"test"``); name tables are kept."""
        if split not in SPLIT_NAMES:
            raise ValueError(f"Unknown split {split!r}; expected one of: {', '.join(SPLIT_NAMES)}.")
        return self.select(self.split == SPLIT_NAMES.index(split))

    def hold_out_clips(self, fraction: float, seed: int) -> tuple[PoseDataset, PoseDataset]:
        """``(rest, held_out)``: whole clips, a seeded ``fraction`` of them (at least one, never all), held out.

        Raises:
            ValueError: ``fraction`` outside (0, 1), or fewer than two clips.
        """
        if not 0.0 < fraction < 1.0:
            raise ValueError(f"The held-out fraction must be in (0, 1), got {fraction}.")
        clips = torch.unique(self.clip_id)
        if len(clips) < 2:
            raise ValueError(f"{self.source or 'dataset'}: holding out clips needs at least 2 clips, "
                             f"found {len(clips)}.")
        n = min(len(clips) - 1, max(1, round(fraction * len(clips))))
        held = clips[torch.randperm(len(clips), generator=torch.Generator().manual_seed(seed))[:n]]
        mask = torch.isin(self.clip_id, held)
        return self.select(~mask), self.select(mask)

    def select(self, index: Tensor) -> PoseDataset:
        """Rows picked by a boolean mask or index tensor (N,)."""
        rows = {f.name: getattr(self, f.name)[index] for f in dataclasses.fields(self)
                if isinstance(getattr(self, f.name), Tensor)}
        return dataclasses.replace(self, **rows)


class CacheError(ValueError):
    """A pose cache that is not readable or whose keys or values are not what :func:`build_cache` writes."""


CACHE_VALUE_BOUNDS = {"pose": 1e3, "transl": 1e5, "betas": 1e3}
"""Largest magnitude accepted in a cache's float arrays (radians, metres, shape units): far beyond any real
pose, small enough that every rotation and FK stays finite."""


def _check_cache_values(path: Path, a: dict[str, np.ndarray]) -> None:
    """Raise :class:`CacheError` naming the key when an array of a cache has the wrong shape, dtype or values."""
    if a["pose"].ndim != 3:
        raise CacheError(f"{path}: key 'pose' has shape {a['pose'].shape}; expected (N, {NUM_JOINTS}, 3).")
    N = a["pose"].shape[0]
    expected = {"pose": (N, NUM_JOINTS, 3), "transl": (N, 3), "betas": (N, NUM_BETAS)}
    expected.update({k: (N,) for k in ("has_betas", "gender", "clip_id", "subject_id", "frame", "split")})
    for key, shape in expected.items():
        if a[key].shape != shape:
            raise CacheError(f"{path}: key '{key}' has shape {a[key].shape}; expected {shape}.")
    for key, bound in CACHE_VALUE_BOUNDS.items():
        if a[key].dtype.kind not in "fiu":
            raise CacheError(f"{path}: key '{key}' must hold numbers, got dtype {a[key].dtype}.")
        if N and not (np.isfinite(a[key]).all() and np.abs(a[key]).max() <= bound):
            raise CacheError(f"{path}: key '{key}' holds non-finite values or values beyond ±{bound:g}.")
    for key in ("has_betas", "gender", "clip_id", "subject_id", "frame", "split"):
        if a[key].dtype.kind not in "biu":
            raise CacheError(f"{path}: key '{key}' must hold integers, got dtype {a[key].dtype}.")
    for key in ("clip_names", "subject_names"):
        if a[key].ndim != 1 or a[key].dtype.kind != "U":
            raise CacheError(f"{path}: key '{key}' must be a 1-D array of strings, got {a[key].dtype} "
                             f"{a[key].shape}.")
    if a["settings"].shape != () or a["settings"].dtype.kind != "U":
        raise CacheError(f"{path}: key 'settings' must be one JSON string, got {a['settings'].dtype} "
                         f"{a['settings'].shape}.")
    C, S = len(a["clip_names"]), len(a["subject_names"])
    fps = a["clip_fps"]
    if fps.shape != (C,) or fps.dtype.kind not in "fiu" or not (np.isfinite(fps).all() and (fps > 0).all()):
        raise CacheError(f"{path}: key 'clip_fps' must hold {C} positive finite frame rates (one per clip).")
    ranges = {"clip_id": (0, C - 1, f"'clip_names' ({C} clips)"), "subject_id": (0, S - 1, f"'subject_names' ({S} "
              "subjects)"), "split": (0, len(SPLIT_NAMES) - 1, f"0..{len(SPLIT_NAMES) - 1}"),
              "gender": (UNKNOWN_GENDER, len(Gender) - 1, f"{UNKNOWN_GENDER}..{len(Gender) - 1}"),
              "has_betas": (0, 1, "0..1"), "frame": (0, np.iinfo(np.int64).max, "0 and up")}
    for key, (low, high, what) in ranges.items():
        if N and (a[key].min() < low or a[key].max() > high):
            if key in ("clip_id", "subject_id"):
                raise CacheError(f"{path}: key '{key}' indexes outside {what}.")
            raise CacheError(f"{path}: key '{key}' has values outside {what}.")


def load_cache(path: str | Path) -> PoseDataset:
    """Load and validate a cache written by :func:`build_cache`: keys, shapes, dtypes and values (finite,
    in range, indices inside their tables).

    Raises:
        FileNotFoundError: no such file. CacheError (a ValueError): not a cache, another format version, a
            missing, misshaped or out-of-range key (named).
    """
    from smplik.limits import open_checked_npz

    path = Path(path)
    npz = open_checked_npz(path, "Pose cache not found",
                           lambda exc: CacheError(f"{path}: not a readable .npz pose cache ({exc})."))
    with npz:
        missing = [k for k in _CACHE_KEYS if k not in npz.files]
        if "version" in missing:
            raise CacheError(f"{path}: not a pose cache (no 'version' key).")
        try:
            version_array = npz["version"]
        except ValueError as exc:  # e.g. an object array (allow_pickle=False)
            raise CacheError(f"{path}: key 'version' is not readable ({exc}).") from None
        if version_array.shape != () or version_array.dtype.kind not in "iu":
            raise CacheError(f"{path}: key 'version' must be a scalar integer, got {version_array.dtype} "
                             f"{version_array.shape}.")
        version = int(version_array)
        if version != CACHE_VERSION:
            raise CacheError(f"{path}: cache format version {version}, this smplik reads version {CACHE_VERSION}; "
                             "rebuild it with `smplik data build`.")
        if missing:
            raise CacheError(f"{path}: missing key '{missing[0]}'.")
        try:
            a = {k: npz[k] for k in _CACHE_KEYS}
        except ValueError as exc:  # an object array (allow_pickle=False) or a corrupt member
            raise CacheError(f"{path}: a key is not readable ({exc}).") from None
    _check_cache_values(path, a)
    try:
        settings = json.loads(str(a["settings"]))
    except json.JSONDecodeError:
        raise CacheError(f"{path}: key 'settings' is not JSON.") from None
    if not isinstance(settings, dict):
        raise CacheError(f"{path}: key 'settings' must hold a JSON object, got {type(settings).__name__}.")

    def long(key: str) -> Tensor:
        return torch.from_numpy(a[key].astype(np.int64))

    return PoseDataset(
        pose=torch.from_numpy(a["pose"].astype(np.float32)),
        transl=torch.from_numpy(a["transl"].astype(np.float32)),
        betas=torch.from_numpy(a["betas"].astype(np.float32)),
        has_betas=torch.from_numpy(a["has_betas"].astype(bool)),
        gender=long("gender"),
        clip_id=long("clip_id"),
        subject_id=long("subject_id"),
        frame=long("frame"),
        split=long("split"),
        clip_names=tuple(str(x) for x in a["clip_names"]),
        subject_names=tuple(str(x) for x in a["subject_names"]),
        settings=settings,
        source=str(path),
    )
