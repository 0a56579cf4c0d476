"""Pose cache: sources, splits, subsampling, atomic writes, loading, and the ``build`` command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from shape_inversion.data_build_cli import build
from smplik.body_model import BodyModelSet
from smplik.conventions import NUM_BETAS, Gender
from smplik.data.dataset import (
    CACHE_VERSION,
    ClipSource,
    PoseSequence,
    build_cache,
    find_sources,
    load_cache,
    load_split,
    parse_split,
    subsample_indices,
)


def toy_body_models() -> BodyModelSet:
    """A BodyModelSet without meshes: rest pelvis at y = 0.9 (+ 0.01 per beta_0)."""
    J_template = torch.zeros(3, 24, 3)
    J_template[:, :, 1] = 0.9
    J_dirs = torch.zeros(3, 24, 3, NUM_BETAS)
    J_dirs[:, :, 1, 0] = 0.01
    return BodyModelSet((), J_template, J_dirs)


def write_clip(path: Path, T: int, fps: float = 120.0, seed: int = 0, gender: str = "male") -> None:
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, poses=rng.normal(scale=0.2, size=(T, 156)), trans=rng.normal(size=(T, 3)),
             betas=rng.normal(size=16), gender=np.array(gender), mocap_framerate=np.array(fps))


@pytest.fixture
def amass_dir(tmp_path: Path) -> Path:
    """Three subjects (01, 02, 03), two clips each, 120 fps; plus a betas-only shape.npz."""
    root = tmp_path / "amass" / "CMU"
    for s, subject in enumerate(("01", "02", "03")):
        for c in (1, 2):
            write_clip(root / subject / f"{subject}_0{c}_poses.npz", T=40 + 10 * c, seed=10 * s + c)
        np.savez(root / subject / "shape.npz", betas=np.zeros(16), gender=np.array("male"))
    return root


SPLIT = {"train": {"subjects": ["01"], "files": []},
         "validation": {"subjects": ["02"], "files": ["03_02"]},
         "test": {"subjects": ["03"], "files": []}}


@pytest.fixture
def split_file(tmp_path: Path) -> Path:
    path = tmp_path / "split.json"
    path.write_text(json.dumps(SPLIT))
    return path


def test_find_sources(amass_dir: Path, tmp_path: Path) -> None:
    sources = find_sources(amass_dir, "amass")
    assert [s.name for s in sources][:2] == ["01/01_01_poses.npz", "01/01_02_poses.npz"]
    assert len(sources) == 6 and {s.subject for s in sources} == {"01", "02", "03"}
    with pytest.raises(FileNotFoundError, match="not found"):
        find_sources(tmp_path / "nope", "bvh")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="No .bvh files"):
        find_sources(tmp_path / "empty", "bvh")


def test_bvh_subject_from_file_name(tmp_path: Path) -> None:
    (tmp_path / "01_02.bvh").write_text("")
    (src,) = find_sources(tmp_path, "bvh")
    assert (src.name, src.subject, src.kind) == ("01_02.bvh", "01", "bvh")


def test_subsample_indices() -> None:
    np.testing.assert_array_equal(subsample_indices(10, 120, 30), [0, 4, 8])
    np.testing.assert_array_equal(subsample_indices(5, 30, 30), np.arange(5))
    np.testing.assert_array_equal(subsample_indices(6, 50, 20), [0, 3, 5])
    with pytest.raises(ValueError, match="upsample"):
        subsample_indices(10, 30, 60)
    with pytest.raises(ValueError, match="positive"):
        subsample_indices(10, 30, 0)


def test_split_file_errors(tmp_path: Path) -> None:
    path = tmp_path / "s.json"
    cases = [
        ({"training": {"subjects": []}}, "'training'"),
        ({"train": ["01"]}, "key 'train'"),
        ({"train": {"subjects": "01"}}, "'train.subjects'"),
        ({"train": {"files": [1]}}, "'train.files'"),
        ({"train": {"motion_frames": 3}}, "key 'train' has neither"),
        ({"train": {"subjects": ["01"]}, "test": {"subjects": ["01"]}}, "'train.subjects' and 'test.subjects'"),
        ([], "JSON object"),
    ]
    for obj, match in cases:
        path.write_text(json.dumps(obj))
        with pytest.raises(ValueError, match=match):
            load_split(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="invalid JSON"):
        load_split(path)
    with pytest.raises(FileNotFoundError):
        load_split(tmp_path / "missing.json")


def test_split_by_clip_wins_over_subject() -> None:
    spec = parse_split(SPLIT)
    clip = ClipSource(Path("x/03/03_02_poses.npz"), "amass", "03/03_02_poses.npz", "03")
    assert spec.assign(clip) == 2  # by subject: "03_02" is not the stem "03_02_poses"
    spec = parse_split({"test": {"subjects": ["03"]}, "validation": {"clips": ["03_02_poses"]}})
    assert spec.assign(clip) == 1
    assert spec.assign(ClipSource(Path("a.bvh"), "bvh", "03_01.bvh", "03")) == 2
    assert spec.assign(ClipSource(Path("a.bvh"), "bvh", "04_01.bvh", "04")) is None


def test_cmu_split_file_parses(shared_data) -> None:
    cmu_dir = shared_data.cmu()
    spec = load_split(shared_data.cmu("split.json"))
    assert spec.assign(ClipSource(cmu_dir / "01_01.bvh", "bvh", "01_01.bvh", "01")) == 0
    assert spec.assign(ClipSource(cmu_dir / "35_01.bvh", "bvh", "35_01.bvh", "35")) == 1
    assert spec.assign(ClipSource(cmu_dir / "02_01.bvh", "bvh", "02_01.bvh", "02")) == 2


def test_build_and_load(amass_dir: Path, split_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "cache.npz"
    done: list[str] = []
    summary = build_cache(find_sources(amass_dir, "amass"), fps=30, split=split_file, out=out,
                          body_models=toy_body_models(), progress=lambda s: done.append(s.name))
    assert len(done) == 6
    # 50 frames -> 13 at 30 fps, 60 frames -> 15.
    assert summary.frames == {"train": 28, "validation": 28, "test": 28}
    assert summary.clips == {"train": 2, "validation": 2, "test": 2}
    assert summary.num_bytes == out.stat().st_size
    ds = load_cache(out)
    assert len(ds) == 84
    assert ds.pose.shape == (84, 24, 3) and ds.pose.dtype == torch.float32
    assert ds.transl.shape == (84, 3) and ds.betas.shape == (84, NUM_BETAS)
    assert bool(ds.has_betas.all()) and bool((ds.gender == Gender.MALE.index).all())
    assert ds.clip_names[0] == "01/01_01_poses.npz" and ds.subject_names == ("01", "02", "03")
    assert ds.settings["fps"] == 30 and ds.settings["split"]["validation"]["subjects"] == ["02"]
    assert ds.fps == 30.0
    np.testing.assert_array_equal(ds.frame[:13].numpy(), np.arange(0, 50, 4))
    # Frames are subsampled from the converted sequence.
    from smplik.data.dataset import read_source

    seq = read_source(find_sources(amass_dir, "amass")[0], body_models=toy_body_models())
    np.testing.assert_allclose(ds.pose[:13].numpy(), seq.pose[::4], atol=1e-6)
    val = ds.subset("validation")
    assert len(val) == 28 and bool((val.split == 1).all())
    assert {val.subject_names[i] for i in val.subject_id.tolist()} == {"02"}
    with pytest.raises(ValueError, match="Unknown split"):
        ds.subset("val")


def test_float16_storage(amass_dir: Path, split_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "cache16.npz"
    build_cache(find_sources(amass_dir, "amass"), fps=30, split=split_file, out=out, dtype="float16",
                body_models=toy_body_models())
    with np.load(out) as npz:
        assert npz["pose"].dtype == np.float16
    assert load_cache(out).pose.dtype == torch.float32


def test_unassigned_clips(amass_dir: Path, tmp_path: Path) -> None:
    spec = parse_split({"train": {"subjects": ["01", "02"]}})
    sources = find_sources(amass_dir, "amass")
    with pytest.raises(ValueError, match="2 clip.s. belong to no split"):
        build_cache(sources, fps=30, split=spec, out=tmp_path / "c.npz", body_models=toy_body_models())
    summary = build_cache(sources, fps=30, split=spec, out=tmp_path / "c.npz", body_models=toy_body_models(),
                          skip_unassigned=True)
    assert summary.skipped == ("03/03_01_poses.npz", "03/03_02_poses.npz")
    assert summary.frames["train"] == 56


def _fake_reader(fail_on: str | None = None):
    def reader(src: ClipSource) -> PoseSequence:
        if src.name == fail_on:
            raise RuntimeError("simulated crash mid-build")
        T = 8
        return PoseSequence(np.zeros((T, 3), np.float32), np.zeros((T, 23, 3), np.float32),
                            np.zeros((T, 3), np.float32), None, None, 120.0, str(src.path))

    return reader


def _leftovers(folder: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name not in keep)


def test_interrupted_build_keeps_old_cache(amass_dir: Path, split_file: Path, tmp_path: Path) -> None:
    out_dir = tmp_path / "out"
    out = out_dir / "cache.npz"
    sources = find_sources(amass_dir, "amass")
    build_cache(sources, fps=30, split=split_file, out=out, reader=_fake_reader())
    before = out.read_bytes()
    # A crash while reading the clips: nothing is written.
    with pytest.raises(RuntimeError, match="simulated"):
        build_cache(sources, fps=30, split=split_file, out=out, reader=_fake_reader(fail_on=sources[3].name))
    assert out.read_bytes() == before and _leftovers(out_dir, {"cache.npz"}) == []
    # A crash (or Ctrl-C) in the middle of writing the file: the partial temp file is removed.
    for exc in (OSError("disk full"), KeyboardInterrupt()):
        real = np.savez_compressed

        def partial_write(fh, *args, exc=exc, **kwargs):  # noqa: ANN001, ANN002, ANN003
            fh.write(b"PK\x03\x04 partial")
            raise exc

        np.savez_compressed = partial_write
        try:
            with pytest.raises(type(exc)):
                build_cache(sources, fps=30, split=split_file, out=out, reader=_fake_reader())
        finally:
            np.savez_compressed = real
        assert out.read_bytes() == before and _leftovers(out_dir, {"cache.npz"}) == []
    # A crash on a first build leaves no file at all.
    fresh = tmp_path / "fresh" / "cache.npz"
    with pytest.raises(RuntimeError):
        build_cache(sources, fps=30, split=split_file, out=fresh, reader=_fake_reader(fail_on=sources[0].name))
    assert not fresh.exists()
    assert not fresh.parent.exists() or _leftovers(fresh.parent, set()) == []


def test_read_errors_name_the_file(amass_dir: Path, split_file: Path, tmp_path: Path) -> None:
    bad = amass_dir / "01" / "01_01_poses.npz"
    np.savez(bad, poses=np.zeros((5, 99)), trans=np.zeros((5, 3)), mocap_framerate=np.array(120.0))
    with pytest.raises(ValueError, match="01_01_poses.npz.*'poses' has shape"):
        build_cache(find_sources(amass_dir, "amass"), fps=30, split=split_file, out=tmp_path / "c.npz",
                    body_models=toy_body_models())
    assert not (tmp_path / "c.npz").exists()


def test_load_cache_validation(amass_dir: Path, split_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "cache.npz"
    build_cache(find_sources(amass_dir, "amass"), fps=30, split=split_file, out=out, reader=_fake_reader())
    with np.load(out) as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez(tmp_path / "v.npz", **{**arrays, "version": np.asarray(CACHE_VERSION + 1)})
    with pytest.raises(ValueError, match="version"):
        load_cache(tmp_path / "v.npz")
    np.savez(tmp_path / "k.npz", **{k: v for k, v in arrays.items() if k != "transl"})
    with pytest.raises(ValueError, match="'transl'"):
        load_cache(tmp_path / "k.npz")
    np.savez(tmp_path / "s.npz", **{**arrays, "betas": arrays["betas"][:, :3]})
    with pytest.raises(ValueError, match="'betas' has shape"):
        load_cache(tmp_path / "s.npz")
    np.savez(tmp_path / "x.npz", foo=np.zeros(3))
    with pytest.raises(ValueError, match="not a pose cache"):
        load_cache(tmp_path / "x.npz")
    with pytest.raises(FileNotFoundError):
        load_cache(tmp_path / "missing.npz")


def test_build_from_cmu_bvh(tmp_path: Path, shared_data) -> None:
    """Two real CMU clips: the rest frame 0 is dropped, 120 -> 30 fps, no betas or gender."""
    pytest.importorskip("smplik.data.retarget", reason="smplik.data.retarget is not importable")
    cmu_dir = shared_data.cmu("09_06.bvh").parent
    import shutil

    from shape_inversion.auto_preset import auto_preset  # preset "auto", build_cache's default
    from smplik.data.retarget import retarget_bvh

    src_dir = tmp_path / "bvh"
    src_dir.mkdir()
    for name in ("09_06.bvh", "02_03.bvh"):  # 142 and 174 frames, both test subjects
        shutil.copy(cmu_dir / name, src_dir / name)
    out = tmp_path / "cmu.npz"
    summary = build_cache(find_sources(src_dir, "bvh"), fps=30, split=cmu_dir / "split.json", out=out,
                          rig_mapper=auto_preset)
    assert summary.frames == {"train": 0, "validation": 0, "test": 44 + 36}
    ds = load_cache(out)
    assert ds.clip_names == ("02_03.bvh", "09_06.bvh") and ds.subject_names == ("02", "09")
    assert not bool(ds.has_betas.any()) and bool((ds.gender == -1).all()) and bool((ds.split == 2).all())
    clip = retarget_bvh(cmu_dir / "09_06.bvh", preset="cmu")
    first = ds.pose[ds.clip_id == 1][0].numpy()
    np.testing.assert_allclose(first[0], clip.global_orient[1], atol=1e-5)  # motion frame 1, not rest frame 0
    np.testing.assert_allclose(first[1:], clip.body_pose[1], atol=1e-5)
    np.testing.assert_allclose(ds.transl[ds.clip_id == 1][1].numpy(), clip.transl[5], atol=1e-5)


# ----------------------------------------------------------------------------- the build command


def _cli() -> typer.Typer:
    app = typer.Typer()
    app.command("build")(build)

    @app.command("noop")
    def noop() -> None:  # a second command keeps typer from collapsing the app into `build`
        pass

    return app


def test_build_command(amass_dir: Path, split_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(BodyModelSet, "load", classmethod(lambda cls, model_dir=None: toy_body_models()))
    out = tmp_path / "cli.npz"
    result = CliRunner().invoke(_cli(), ["build", "--amass", str(amass_dir), "--fps", "30", "--split",
                                         str(split_file), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert len(load_cache(out)) == 84


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ([], "exactly one of --bvh"),
        (["--bvh", "{tmp}", "--amass", "{tmp}"], "exactly one of --bvh"),
        (["--bvh", "{tmp}/missing"], "not found"),
        (["--bvh", "{tmp}/empty"], "No .bvh files"),
        (["--amass", "{amass}", "--split", "{tmp}/bad_split.json"], "train.subjects"),
        (["--amass", "{amass}", "--out", "{tmp}/c.txt"], "must end in .npz"),
    ],
)
def test_build_command_errors(amass_dir: Path, split_file: Path, tmp_path: Path, args: list[str], match: str) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad_split.json").write_text(json.dumps({"train": {"subjects": "01"}}))
    base = {"--split": str(split_file), "--out": str(tmp_path / "c.npz")}
    args = [a.format(tmp=tmp_path, amass=amass_dir) for a in args]
    for key, value in base.items():
        if key not in args:
            args += [key, value]
    result = CliRunner().invoke(_cli(), ["build", *args])
    assert result.exit_code != 0
    assert match in " ".join(result.output.split()), result.output
    assert not (tmp_path / "c.npz").exists()
