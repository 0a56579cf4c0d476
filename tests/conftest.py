"""Shared fixtures: an isolated cache folder, the built-in body models, a tiny pose dataset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"
CMU_DIR = SHARED / "data" / "cmu"


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Generated files (built-in body, SMPL-SI banks) go to a temporary cache, never to ~/.cache."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SMPLIK_CACHE_DIR", str(tmp_path_factory.mktemp("smplik-cache")))
    mp.delenv("SMPLIK_MODEL_DIR", raising=False)
    yield
    mp.undo()


@pytest.fixture(scope="session")
def bodies():
    from smplik.body_model import BodyModelSet

    return BodyModelSet.load()


def write_amass_clips(folder: Path, clips: int = 6, frames: int = 40, seed: int = 0) -> Path:
    """Plain-SMPL AMASS-layout clips (smooth random motion) plus a clip-level split file."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for c in range(clips):
        t = np.linspace(0, 2 * np.pi, frames)[:, None]
        base, amp = rng.normal(0, 0.25, 72), rng.normal(0, 0.3, 72)
        poses = base + amp * np.sin(t + rng.uniform(0, 6, 72))
        poses[:, :3] = [np.pi / 2, 0, 0]  # upright in AMASS's z-up world
        name = f"clip{c}"
        np.savez(folder / f"{name}.npz", poses=poses, trans=np.zeros((frames, 3)), betas=rng.normal(0, 1, 10),
                 gender="neutral", mocap_framerate=30.0)
        names.append(f"{name}.npz")
    split = {"train": {"files": names[:-2]}, "validation": {"files": names[-2:-1]}, "test": {"files": names[-1:]}}
    (folder / "split.json").write_text(json.dumps(split))
    return folder / "split.json"


@pytest.fixture(scope="session")
def tiny_cache(tmp_path_factory) -> Path:
    from smplik.data.dataset import build_cache, find_sources

    root = tmp_path_factory.mktemp("amass")
    split = write_amass_clips(root / "clips")
    out = root / "cache.npz"
    build_cache(find_sources(root / "clips", "amass"), fps=30, split=split, out=out)
    return out
