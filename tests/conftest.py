"""Shared fixtures: isolation (cache folder, environment, seeds, torch threads), the built-in body models,
tiny pose caches and models, stand-in and oracle solvers, and the ``shared_data`` folder.

Test modules never import each other; what several of them need lives here as a fixture.
"""

from __future__ import annotations

import os

# Headless rendering for every test, set before anything imports pyrender/PyOpenGL (the CLI does the same).
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import signal  # noqa: E402

# A test run started in the background by a shell without job control (`.ci/run &`) inherits SIGINT ignored, and
# every command the tests start would inherit that too: the Ctrl-C tests' signals would be lost and their commands
# run on. The tests' own process takes Python's usual handler, which a started command resets to the default.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

import json  # noqa: E402
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "smplik" / "checkpoints" / "smplik_cmu.pt"
"""The shipped model file (tests that need it skip with this path in the reason when it is absent)."""


# ----------------------------------------------------------------------------- isolation


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Generated files (built-in body, SMPL-SI banks) go to a temporary cache, never to ~/.cache; no
    real-SMPL folder or pose cache from the user's environment leaks in."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SMPLIK_CACHE_DIR", str(tmp_path_factory.mktemp("smplik-cache")))
    mp.delenv("SMPLIK_MODEL_DIR", raising=False)
    mp.delenv("SMPLIK_POSE_CACHE", raising=False)
    yield
    mp.undo()


@pytest.fixture(autouse=True)
def _seeded_and_threads_restored():
    """Every test starts from the same global RNG state and leaves torch's thread count as it found it."""
    torch.manual_seed(0)
    np.random.seed(0)  # noqa: NPY002 - only for third-party code that draws from the global state
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def torch_threads():
    """``torch_threads(n)`` sets torch's intra-op threads for this test only (restored afterwards)."""
    return torch.set_num_threads


# ----------------------------------------------------------------------------- shared data


@dataclass(frozen=True)
class SharedData:
    """The shared folder (``$SMPLIK_SHARED_DIR`` or ``../shared``) and the CMU folder (``$SMPLIK_CMU_DIR`` or
    ``<shared>/data/cmu``); each accessor skips the test with the reason when its file is absent."""

    root: Path | None
    cmu_dir: Path | None

    def cmu(self, name: str = "") -> Path:
        """The CMU folder, or a file in it (``"02_01.bvh"``, ``"split.json"``)."""
        from smplik.paths import missing_cmu_reason

        if self.cmu_dir is None or not self.cmu_dir.is_dir():
            pytest.skip(missing_cmu_reason())
        path = self.cmu_dir / name
        if not path.exists():
            pytest.skip(f"{path} not found in the CMU folder ($SMPLIK_CMU_DIR).")
        return path

    def file(self, relative: str) -> Path:
        """A file of the shared folder, e.g. ``"data/custom-characters/mh_default_tpose.bvh"``."""
        if self.root is None:
            pytest.skip("no shared folder: set $SMPLIK_SHARED_DIR or place it next to the repository (../shared).")
        path = self.root / relative
        if not path.exists():
            pytest.skip(f"{path} not found in the shared folder ($SMPLIK_SHARED_DIR).")
        return path


@pytest.fixture(scope="session")
def shared_data() -> SharedData:
    """The shared data, found through :mod:`smplik.paths`; skips when neither folder exists."""
    from smplik import paths

    found = SharedData(paths.shared_dir(), paths.cmu_dir())
    if found.root is None and found.cmu_dir is None:
        pytest.skip("no shared data: set $SMPLIK_CMU_DIR or $SMPLIK_SHARED_DIR, or place ../shared next to the "
                    "repository.")
    return found


# ----------------------------------------------------------------------------- bodies, caches, models


@pytest.fixture(scope="session")
def bodies():
    from smplik.body_model import BodyModelSet

    return BodyModelSet.load()


def write_amass_clips(folder: Path, clips: int = 6, frames: int = 40, seed: int = 0,
                      names: list[str] | None = None, test_clips: int = 1) -> Path:
    """Plain-SMPL AMASS-layout clips (smooth random motion) plus a clip-level split file.

    The layout is AMASS's (``poses``, ``trans``, ``betas``, ``gender``, ``mocap_framerate``; as read by
    smplik.data.amass). Clips are named ``names`` (default ``clip0`` ...); the last ``test_clips`` go to
    the test split, the one before them to validation, the others to train.
    """
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    names = names or [f"clip{c}" for c in range(clips)]
    files = []
    for name in names:
        t = np.linspace(0, 2 * np.pi, frames)[:, None]
        base, amp = rng.normal(0, 0.25, 72), rng.normal(0, 0.3, 72)
        poses = base + amp * np.sin(t + rng.uniform(0, 6, 72))
        poses[:, :3] = [np.pi / 2, 0, 0]  # upright in AMASS's z-up world
        np.savez(folder / f"{name}.npz", poses=poses, trans=np.zeros((frames, 3)), betas=rng.normal(0, 1, 10),
                 gender="neutral", mocap_framerate=30.0)
        files.append(f"{name}.npz")
    k = len(files) - test_clips
    split = {"train": {"files": files[:k - 1]}, "validation": {"files": files[k - 1:k]}, "test": {"files": files[k:]}}
    (folder / "split.json").write_text(json.dumps(split))
    return folder / "split.json"


def _build_cache(root: Path, **clips) -> Path:
    from smplik.data.dataset import build_cache, find_sources

    split = write_amass_clips(root / "clips", **clips)
    out = root / "cache.npz"
    build_cache(find_sources(root / "clips", "amass"), fps=30, split=split, out=out)
    return out


@pytest.fixture(scope="session")
def tiny_cache(tmp_path_factory) -> Path:
    """A pose cache of six short clips: four train, one validation, one test."""
    return _build_cache(tmp_path_factory.mktemp("amass"))


@pytest.fixture(scope="session")
def two_subject_cache(tmp_path_factory) -> Path:
    """A pose cache whose test split holds two CMU-named subjects: ``13`` (clips 13_01, 13_02) and ``86`` (86_05)."""
    names = ["01_01", "02_01", "05_01", "07_01", "13_01", "13_02", "86_05"]
    return _build_cache(tmp_path_factory.mktemp("amass2"), names=names, test_clips=3, seed=1)


TINY_NETWORK = {"width": 32, "encoder_blocks": 2, "decoder_blocks": 2, "layers_per_block": 1}


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory, bodies) -> Path:
    """A train-free model file (seed 0) in the exported format, written through ``export_model``."""
    from smplik.model_io import export_model
    from smplik.network import NetworkConfig, ProtoResIK

    config = NetworkConfig(**TINY_NETWORK)
    torch.manual_seed(0)
    model = ProtoResIK(config, bodies.J_template, bodies.J_dirs)
    ckpt = tmp_path_factory.mktemp("tiny-model") / "tiny.ckpt"
    torch.save({"format": "smplik-checkpoint", "version": 1, "step": 0, "config": {}, "network": config.to_dict(),
                "model": model.state_dict(), "body_fingerprint": bodies.fingerprint, "metrics": {}}, ckpt)
    return export_model(ckpt, ckpt.with_suffix(".pt"))


# ----------------------------------------------------------------------------- solvers and poses


@pytest.fixture(scope="session")
def stand_in_solver(tiny_model):
    """An IKSolver around the tiny untrained network (for plumbing tests when no model is shipped)."""
    from smplik.solver import IKSolver

    return IKSolver.load(tiny_model)


@pytest.fixture(scope="session")
def best_solver(stand_in_solver):
    """The shipped model when present, else the stand-in."""
    from smplik.solver import IKSolver

    return IKSolver.load(SHIPPED) if SHIPPED.is_file() else stand_in_solver


@pytest.fixture(scope="session")
def shipped_solver():
    """The shipped model's solver; skips when the file is absent."""
    from smplik.solver import IKSolver

    if not SHIPPED.is_file():
        pytest.skip(f"no shipped model at {SHIPPED}")
    return IKSolver.load(SHIPPED)


@pytest.fixture()
def animate_shipped(monkeypatch, shipped_solver):
    """``animate_shipped(*args)``: ``smplik scene animate ARGS`` (typer's CliRunner) on the shipped solver."""
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: shipped_solver)
    return lambda *args: CliRunner().invoke(scene_app, ["animate", *map(str, args)])


class OracleSolver:
    """A solver whose answer improves with every effector: joints start 0.3 m off the target; an
    effector on joint j puts j on the target (a rotation effector also its children). Counts its calls."""

    def __init__(self, target_joints: torch.Tensor):
        self.target = target_joints.float()
        self.calls = 0

    def solve_tensors(self, eff, betas: torch.Tensor, gender: torch.Tensor, *, refine: object = None):
        from smplik.conventions import NUM_JOINTS, PARENTS
        from smplik.network import IKOutput

        self.calls += 1
        B = eff.joint.shape[0]
        fixed = torch.zeros(B, NUM_JOINTS, dtype=torch.bool)
        fixed[torch.arange(B)[:, None], eff.joint] = True
        rot = torch.zeros(B, NUM_JOINTS, dtype=torch.bool)
        rot[torch.arange(B)[:, None], eff.joint] = eff.type == 1
        for j, p in enumerate(PARENTS):
            if p >= 0:
                fixed[:, j] |= rot[:, p]
        p = torch.where(fixed[..., None], self.target, self.target + torch.tensor([0.3, 0.0, 0.0]))
        eye = torch.eye(3).expand(B, NUM_JOINTS, 3, 3)
        return IKOutput(eye, eye, p, p, torch.zeros(B, 3))


@pytest.fixture(scope="session")
def oracle_solver():
    """``oracle_solver(target_joints)``: a new :class:`OracleSolver` (its ``calls`` counts solves)."""
    return OracleSolver


def _synthetic_pose(seed: int = 0):
    from smplik.pose import Pose

    rng = np.random.default_rng(seed)
    body = rng.normal(0, 0.25, (23, 3))
    return Pose(rng.normal(0, 0.3, 3), body, np.array([0.1, 0.05, -0.2]), rng.normal(0, 0.8, 10))


@pytest.fixture(scope="session")
def synthetic_pose():
    """``synthetic_pose(seed)``: a plausible random pose (small local rotations) on a random body."""
    return _synthetic_pose
