"""smplik.paths: the environment variables and repo-relative defaults, and that every user of a path goes through it."""

from __future__ import annotations

from pathlib import Path

import pytest

from smplik import paths


@pytest.fixture
def clean_env(monkeypatch):
    for name in (paths.SHARED_DIR_ENV, paths.CMU_DIR_ENV, paths.CACHE_DIR_ENV, paths.POSE_CACHE_ENV,
                 "XDG_CACHE_HOME"):
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


def test_cmu_dir_env_wins_else_the_repo_relative_shared_folder(clean_env, tmp_path):
    fake_repo = tmp_path / "checkout"
    (fake_repo / "smplik").mkdir(parents=True)
    clean_env.setattr(paths, "repo_root", lambda: fake_repo)
    assert paths.shared_dir() is None and paths.cmu_dir() is None  # nothing next to the checkout
    assert "SMPLIK_CMU_DIR" in paths.missing_cmu_reason()
    (tmp_path / "shared" / "data" / "cmu").mkdir(parents=True)
    assert paths.shared_dir() == tmp_path / "shared"
    assert paths.cmu_dir() == tmp_path / "shared" / "data" / "cmu"
    clean_env.setenv("SMPLIK_SHARED_DIR", str(tmp_path / "elsewhere"))
    assert paths.shared_dir() == tmp_path / "elsewhere" and paths.cmu_dir() is None
    clean_env.setenv("SMPLIK_CMU_DIR", str(tmp_path / "mocap"))
    assert paths.cmu_dir() == tmp_path / "mocap"  # named even when missing, so errors can say where
    assert str(tmp_path / "mocap") in paths.missing_cmu_reason()
    clean_env.setenv("SMPLIK_CMU_DIR", "")
    assert paths.cmu_dir() is None  # empty counts as unset


def test_cache_dir_and_the_defaults_under_it(clean_env, tmp_path):
    clean_env.setenv("HOME", str(tmp_path / "home"))
    assert paths.cache_dir() == tmp_path / "home" / ".cache" / "smplik"
    clean_env.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert paths.cache_dir() == tmp_path / "xdg" / "smplik"
    clean_env.setenv("SMPLIK_CACHE_DIR", str(tmp_path / "cache"))
    assert paths.cache_dir() == tmp_path / "cache"
    assert paths.cache_dir(tmp_path / "explicit") == tmp_path / "explicit"
    assert paths.pose_cache() == tmp_path / "cache" / "cmu30.npz"
    assert paths.benchmark_files_dir("test", 0, 500) == tmp_path / "cache" / "benchmark" / "test-seed0-n500"
    clean_env.setenv("SMPLIK_POSE_CACHE", str(tmp_path / "poses.npz"))
    assert paths.pose_cache() == tmp_path / "poses.npz"


def test_builtin_body_and_shape_banks_share_the_one_cache_lookup(clean_env, tmp_path):
    """Both generated-file caches follow smplik.paths.cache_dir (here: $XDG_CACHE_HOME, which neither read before)."""
    from shape_inversion.bank import BankConfig, bank_cache_path
    from smplik.builtin_body import builtin_cache_dir
    from smplik.conventions import Gender

    clean_env.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    root = tmp_path / "xdg" / "smplik"
    assert builtin_cache_dir().parent == root
    assert bank_cache_path("abc", Gender.MALE, BankConfig()).parent == root / "shape_inversion"


def test_no_default_path_is_an_absolute_path_of_one_machine():
    """The library and the benchmark scripts default to paths from smplik.paths, never to a fixed root."""
    repo = Path(__file__).resolve().parents[1]
    files = [*repo.glob("smplik/**/*.py"), *repo.glob("shape_inversion/**/*.py"), *repo.glob("workflows/**/*.py"),
             *(repo / "benchmarks" / n for n in ("ik_benchmark.py", "speed.py", "retarget_quality.py",
                                                  "tolerance_tracking.py", "fk_speed.py", "_common.py"))]
    offenders = [f"{f.relative_to(repo)}: {line.strip()}" for f in files for line in f.read_text().splitlines()
                 if any(root in line for root in ('"/work/', "'/work/", '"/home/', '"/tmp/'))]
    assert not offenders, offenders


def test_data_commands_find_clips_through_the_cmu_dir(clean_env, tmp_path):
    import typer

    from shape_inversion.data_cli import resolve_clip

    (tmp_path / "mocap").mkdir()
    (tmp_path / "mocap" / "07_01.bvh").write_text("HIERARCHY\n")
    clean_env.setenv("SMPLIK_CMU_DIR", str(tmp_path / "mocap"))
    assert resolve_clip("07_01") == tmp_path / "mocap" / "07_01.bvh"
    assert resolve_clip("07_01.bvh") == tmp_path / "mocap" / "07_01.bvh"
    with pytest.raises(typer.BadParameter, match=f"neither a file nor a clip in {tmp_path / 'mocap'}"):
        resolve_clip("99_99")
    clean_env.setattr(paths, "repo_root", lambda: tmp_path / "bare" / "checkout")
    clean_env.delenv("SMPLIK_CMU_DIR")
    with pytest.raises(typer.BadParameter, match="no CMU BVH folder: set \\$SMPLIK_CMU_DIR"):
        resolve_clip("07_01")
