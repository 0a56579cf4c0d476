"""``smplik data build`` without a split file: every clip in train, or a seeded subject split."""

from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from smplik.data.dataset import find_sources, load_cache, split_all_train, split_by_subject

CLIPS = [f"clip{c}.npz" for c in range(6)]  # conftest's tiny AMASS clips: one subject per clip


@pytest.fixture()
def clips(tiny_cache):
    return tiny_cache.parent / "clips"


def build(*args):
    from smplik.cli.main import app

    return CliRunner().invoke(app, ["data", "build", *args])


def test_build_without_split_puts_every_clip_in_train(clips, tmp_path):
    out = tmp_path / "all.npz"
    res = build("--amass", str(clips), "--out", str(out))
    assert res.exit_code == 0, res.output
    assert "split: every clip in train (no --split given" in res.output
    ds = load_cache(out)
    assert len(ds) == 6 * 40 and bool((ds.split == 0).all())
    assert ds.settings["split_source"] == "<no split file: every clip in train>"


def test_split_by_subject_is_seeded_and_stated(clips, tmp_path):
    res = build("--amass", str(clips), "--out", str(tmp_path / "a.npz"), "--split-by-subject", "7")
    assert res.exit_code == 0, res.output
    ds = load_cache(tmp_path / "a.npz")
    counts = [int((ds.split == i).sum()) for i in range(3)]
    assert counts == [4 * 40, 40, 40]  # 6 subjects: 1 validation, 1 test, 4 train
    spec = split_by_subject(find_sources(clips, "amass"), 7)
    assert f"validation {next(iter(spec.subjects['validation']))}" in res.output and "seed 7" in res.output
    assert split_by_subject(find_sources(clips, "amass"), 7) == spec
    assert any(split_by_subject(find_sources(clips, "amass"), s) != spec for s in range(8, 12))
    res = build("--amass", str(clips), "--out", str(tmp_path / "b.npz"), "--split-by-subject", "7", "--split",
                str(clips / "split.json"))
    assert res.exit_code != 0 and "not both" in res.output


def test_small_subject_counts():
    from smplik.data.dataset import ClipSource

    def sources(n):
        return [ClipSource(path=None, kind="amass", name=f"s{i}.npz", subject=f"s{i}") for i in range(n)]  # type: ignore[arg-type]

    assert {k: len(v) for k, v in split_by_subject(sources(1), 0).subjects.items()} == \
        {"validation": 0, "test": 0, "train": 1}
    assert {k: len(v) for k, v in split_by_subject(sources(2), 0).subjects.items()} == \
        {"validation": 1, "test": 0, "train": 1}
    assert split_all_train(sources(3)).assign(sources(3)[2]) == 0


def test_unassigned_clips_error_names_skip_unassigned(clips, tmp_path):
    split = tmp_path / "split.json"
    split.write_text(json.dumps({"train": {"files": CLIPS[:4]}}))
    res = build("--amass", str(clips), "--out", str(tmp_path / "c.npz"), "--split", str(split))
    assert res.exit_code == 1 and "--skip-unassigned" in res.output, res.output
    res = build("--amass", str(clips), "--out", str(tmp_path / "c.npz"), "--split", str(split), "--skip-unassigned")
    assert res.exit_code == 0 and "skipped 2 clip(s)" in res.output


def test_bvh_folder_without_split(shared_cmu, tmp_path):
    src = tmp_path / "bvh"
    src.mkdir()
    shutil.copy(shared_cmu / "09_06.bvh", src / "09_06.bvh")
    res = build("--bvh", str(src), "--out", str(tmp_path / "bvh.npz"))
    assert res.exit_code == 0, res.output
    assert "every clip in train" in res.output and bool((load_cache(tmp_path / "bvh.npz").split == 0).all())


@pytest.fixture()
def shared_cmu(shared_data):
    return shared_data.cmu("09_06.bvh").parent
