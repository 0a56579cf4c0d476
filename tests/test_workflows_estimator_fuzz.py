"""Bounded fuzz of every estimator reader (issue 11 items 3, 4, 7, 8): seeded mutations of valid files.

Contract: a mutated file either reads (people with finite numbers) or raises the project's error
(:class:`EstimateFormatError` / :class:`UnsafePickleError`) with a one-line message; never another
exception type, never a hang or a memory blow-up. Two kinds of mutation, all seeded:

* data-level: a leaf of the loaded structure replaced by NaN, inf, a huge number, an empty or
  misshaped array, a string, None, a nested dict, or a key deleted / renamed, then read by the
  same code path as a file's content (:func:`people_from_data`);
* byte-level: the file truncated or some bytes flipped, then read from disk (:func:`read_estimate`).

Plus the hand-made cases of issue 11: a corrupt ``.npz``, a zip bomb, 300 people, inf thetas,
empty arrays. About 15 s in all.
"""

from __future__ import annotations

import copy
import io
import zipfile

import numpy as np
import pytest
from estimator_fixtures import (
    CAMERA_WRITERS,
    SINGLE_PERSON,
    people,
    write_agora,
    write_aist,
    write_amass,
    write_humandata,
    write_hybrik,
    write_romp,
    write_sam3d,
    write_smplerx,
    write_smplifyx,
    write_tram,
)

from smplik.safe_pickle import UnsafePickleError
from workflows.estimators import EstimatedPerson, EstimateFormatError, _load_raw, people_from_data, read_estimate

ALLOWED = (EstimateFormatError, UnsafePickleError)
DATA_MUTATIONS = 60
BYTE_MUTATIONS = 40


def _fixtures(tmp_path):
    files = {}
    for fmt, writer in CAMERA_WRITERS.items():
        n = 1 if fmt in SINGLE_PERSON else 2
        aa, transl, betas = people(seed=1, n=n)
        d = tmp_path / fmt
        d.mkdir()
        files[fmt] = writer(d, aa, transl, betas).path
    aa, transl, _ = people(seed=2, n=3)
    (tmp_path / "aist").mkdir()
    files["aist"] = write_aist(tmp_path / "aist", aa, transl)
    (tmp_path / "amass").mkdir()
    files["amass"] = write_amass(tmp_path / "amass", aa, transl)
    (tmp_path / "sam3d").mkdir()
    files["sam3d"] = write_sam3d(tmp_path / "sam3d", aa[:2], transl[:2])[0].path
    files["tram"] = write_tram(tmp_path / "tram", aa[:2], transl[:2], np.zeros((2, 10)))[1][0]
    files["smplerx"] = write_smplerx(tmp_path / "smplerx", aa[:2], transl[:2], np.zeros((2, 10)),
                                     [(100.0, 80.0, 180.0, 240.0), (380.0, 60.0, 210.0, 280.0)])[0][1]
    files["agora"] = write_agora(tmp_path / "agora", aa[:2], transl[:2], np.zeros((2, 10)), smplx=True)[1]
    files["humandata"] = write_humandata(tmp_path / "hd.npz", aa, transl, np.zeros((3, 10)), rows=[0, 1, 2],
                                         images=["a.jpg", "a.jpg", "b.jpg"])
    write_smplifyx(tmp_path / "smplifyx.pkl", aa[0], transl[0])
    files["smplifyx"] = tmp_path / "smplifyx.pkl"
    return files


def _leaves(obj, path=()):
    """Paths to every leaf (and every dict key) of a nested dict/list structure."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield path + (k,)
            yield from _leaves(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj[:4]):
            yield path + (i,)
            yield from _leaves(v, path + (i,))


def _bad_value(rng, old):
    shape = np.shape(old) if isinstance(old, np.ndarray) else ()
    choices = [
        lambda: np.full(shape, np.nan), lambda: np.full(shape, np.inf), lambda: np.full(shape, 1e308),
        lambda: np.zeros((0,) + tuple(shape[1:])), lambda: np.zeros(tuple(s + 1 for s in shape) or (2,)),
        lambda: "garbage [red]x[/red]", lambda: None, lambda: {"nested": np.zeros(3)}, lambda: [],
        lambda: np.zeros(shape, dtype=bool), lambda: -1, lambda: np.array(["a", "b"]), lambda: [[1, 2], [3]],
        lambda: np.full(shape, -1e5),
    ]
    return choices[rng.integers(len(choices))]()


def _mutate(data, rng):
    data = copy.deepcopy(data)
    paths = list(_leaves(data))
    if not paths:
        return None
    target = paths[rng.integers(len(paths))]
    parent = data
    for k in target[:-1]:
        parent = parent[k]
    key = target[-1]
    what = rng.integers(4)
    if isinstance(parent, dict) and what == 0:
        del parent[key]
    elif isinstance(parent, dict) and what == 1:
        parent[f"{key}_renamed"] = parent.pop(key)
    else:
        parent[key] = _bad_value(rng, parent[key])
    return data


def _check(call):
    try:
        out = call()
    except ALLOWED as exc:
        assert "\n" not in str(exc) and str(exc), repr(exc)
        return "error"
    assert isinstance(out, list) and out and all(isinstance(p, EstimatedPerson) for p in out)
    for p in out:
        for a in (p.global_orient, p.body_pose, p.transl, p.betas):
            assert np.isfinite(a).all()
    return "ok"


def test_data_level_mutations_of_every_reader(tmp_path):
    files = _fixtures(tmp_path)
    outcomes = {}
    for fmt, path in files.items():
        if fmt == "amass":  # read from the file only: covered by the byte-level test
            continue
        raw = _load_raw(path, False, 1 << 30)
        rng = np.random.default_rng(abs(hash(fmt)) % 2**32)
        counts = {"ok": 0, "error": 0}
        for _ in range(DATA_MUTATIONS):
            mutated = _mutate(raw, rng)
            if mutated is None:
                continue
            counts[_check(lambda m=mutated, p=path: people_from_data(m, source=str(p), space="camera", path=p))] += 1
        outcomes[fmt] = counts
        assert counts["error"] > 0, (fmt, counts)  # the mutations do reach the checks
    assert len(outcomes) == len(files) - 1


# Known, reported: one byte-flipped HybrIK pickle makes the restricted unpickler (workflows/safe_pickle.py)
# build an int64 dtype with numpy's object flag; numpy then reports an unraisable RuntimeError
# ("get_clear_loop not set") when the array is freed. The read itself fails cleanly.
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_byte_level_mutations_of_every_reader(tmp_path):
    files = _fixtures(tmp_path)
    rng = np.random.default_rng(7)
    for path in files.values():
        original = path.read_bytes()
        for k in range(BYTE_MUTATIONS):
            blob = bytearray(original)
            if k % 3 == 0:
                blob = blob[: int(rng.integers(0, len(blob)))]
            else:
                for i in rng.integers(0, len(blob), size=int(rng.integers(1, 8))):
                    blob[i] = int(rng.integers(0, 256))
            bad = path.with_name(f"m{k}{path.suffix}")
            bad.write_bytes(bytes(blob))
            _check(lambda b=bad: read_estimate(b, space="camera"))


def test_corrupt_npz_is_one_clear_line(tmp_path):
    bad = tmp_path / "results.npz"
    bad.write_bytes(b"PK\x03\x04 definitely not a zip")
    with pytest.raises(EstimateFormatError, match=r"results.npz: not a readable zip"):
        read_estimate(bad)


def test_zip_bomb_is_refused_from_the_zip_directory(tmp_path):
    path = tmp_path / "bomb.npz"
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (8_000_000,)})
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open("smpl_thetas.npy", "w") as fh:  # 64 MB of zeros in ~60 kB (the same scheme at 7 GB)
            fh.write(header.getvalue())
            for _ in range(4):
                fh.write(bytes(1 << 24))
    assert path.stat().st_size < 1 << 20
    with pytest.raises(EstimateFormatError, match=r"64 MiB uncompressed .*smpl_thetas.npy.*--max-bytes"):
        read_estimate(path, max_bytes=16 << 20)  # refused before a byte is decompressed


def test_people_cap_with_an_option_to_raise_it(tmp_path):
    aa, transl, betas = people(seed=3, n=300)
    path = write_romp(tmp_path, aa, transl, betas).path
    with pytest.raises(EstimateFormatError, match=r"300 people .* cap of 100; pass --max-people 300"):
        read_estimate(path)
    assert len(read_estimate(path, max_people=300)) == 300


def test_inf_thetas_and_empty_arrays(tmp_path):
    aa, transl, betas = people(seed=4, n=2)
    aa[0, 3] = np.inf
    with pytest.raises(EstimateFormatError, match="pred_thetas.*NaN or inf"):
        read_estimate(write_hybrik(tmp_path, aa, transl, betas).path)
    empty = tmp_path / "empty.npz"
    np.savez(empty, results={"smpl_thetas": np.zeros((0, 72)), "smpl_betas": np.zeros((0, 10)),
                             "cam_trans": np.zeros((0, 3))})
    with pytest.raises(EstimateFormatError, match="no people"):
        read_estimate(empty)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, results={"smpl_thetas": "abc", "smpl_betas": np.zeros((1, 10)), "cam_trans": np.zeros((1, 3))})
    with pytest.raises(EstimateFormatError, match="smpl_thetas"):
        read_estimate(wrong)
