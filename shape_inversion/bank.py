"""The SMPL-SI sample bank: random (beta, scale) bodies and their skeleton features.

Per gender (smpl-ik.txt section 4): ``num_samples`` draws of ``beta ~ U(-5, 5)^10`` and
``scale ~ U(0.2, 2)``; joints at zero pose ``scale * J(beta)``; the six features of
:mod:`shape_inversion.features`. Sampling uses a ``numpy.random.Generator`` seeded from
``seed`` only, so a bank is a pure function of (body model, gender, num_samples, seed).

Banks are cached as ``.npz`` under ``<smplik.paths.cache_dir()>/shape_inversion`` (``$SMPLIK_CACHE_DIR``,
default ``~/.cache/smplik``), written atomically. The file name holds
:data:`BANK_VERSION`, the body model's fingerprint, the gender, the sample count and the seed,
so a different model (or a change to the sampling code, with a version bump) never reuses a bank.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from shape_inversion.features import joints_to_features
from smplik.atomic import savez_atomic
from smplik.body_model import BodyModel
from smplik.conventions import NUM_BETAS, Gender
from smplik.paths import cache_dir

BANK_VERSION = "1"
"""Bump whenever the sampling or the features change; it is part of the cache key."""


@dataclass(frozen=True)
class BankConfig:
    """How a bank is sampled (defaults: the paper's)."""

    num_samples: int = 20_000
    """Number of (beta, scale) samples per gender."""
    seed: int = 0
    """Seed of the numpy generator that draws them."""
    beta_range: float = 5.0
    """beta ~ U(-beta_range, beta_range)^10."""
    scale_range: tuple[float, float] = (0.2, 2.0)
    """scale ~ U(*scale_range)."""


@dataclass(frozen=True)
class SampleBank:
    """One gender's samples.

    Attributes:
        gender: the body model's gender.
        fingerprint: the body model's fingerprint (:attr:`smplik.body_model.BodyModel.fingerprint`).
        config: how it was sampled.
        betas: (N, 10) float64.
        scales: (N,) float64.
        features: (N, 6) float64, metres.
    """

    gender: Gender
    fingerprint: str
    config: BankConfig
    betas: np.ndarray
    scales: np.ndarray
    features: np.ndarray

    def __len__(self) -> int:
        return int(self.betas.shape[0])


def sample_bank(model: BodyModel, config: BankConfig = BankConfig()) -> SampleBank:
    """Draw a bank for ``model`` (pure: no cache). Cost: one batched linear map, milliseconds."""
    if config.num_samples < 1:
        raise ValueError(f"num_samples must be positive, got {config.num_samples}.")
    rng = np.random.default_rng(config.seed)
    betas = rng.uniform(-config.beta_range, config.beta_range, size=(config.num_samples, NUM_BETAS))
    scales = rng.uniform(config.scale_range[0], config.scale_range[1], size=config.num_samples)
    joints = model.rest_joints(torch.from_numpy(betas)) * torch.from_numpy(scales)[:, None, None]
    features = joints_to_features(joints).numpy()
    return SampleBank(model.gender, model.fingerprint, config, betas, scales, features)


def bank_cache_path(fingerprint: str, gender: Gender, config: BankConfig, root: str | Path | None = None) -> Path:
    """Cache file of a bank; every input that changes the bank is in the name."""
    lo, hi = config.scale_range
    name = (f"bank-v{BANK_VERSION}-{fingerprint}-{Gender.parse(gender).value}-n{config.num_samples}"
            f"-seed{config.seed}-b{config.beta_range:g}-s{lo:g}_{hi:g}.npz")
    return cache_dir(root) / "shape_inversion" / name


def load_or_build_bank(model: BodyModel, config: BankConfig = BankConfig(), *,
                       root: str | Path | None = None, use_cache: bool = True) -> SampleBank:
    """The bank for ``model`` and ``config``, read from the cache or sampled and cached (atomically).

    A cache file that is unreadable or whose stored key does not match is rebuilt.
    """
    if not use_cache:
        return sample_bank(model, config)
    path = bank_cache_path(model.fingerprint, model.gender, config, root)
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as npz:
                key_ok = (str(npz["fingerprint"]) == model.fingerprint and str(npz["gender"]) == model.gender.value
                          and str(npz["version"]) == BANK_VERSION)
                if key_ok and npz["betas"].shape == (config.num_samples, NUM_BETAS):
                    return SampleBank(model.gender, model.fingerprint, config, npz["betas"], npz["scales"],
                                      npz["features"])
        except (OSError, ValueError, KeyError):
            pass  # corrupt or foreign file: rebuild below
    bank = sample_bank(model, config)
    savez_atomic(path, compressed=False, betas=bank.betas, scales=bank.scales, features=bank.features,
                 fingerprint=np.asarray(model.fingerprint), gender=np.asarray(model.gender.value),
                 version=np.asarray(BANK_VERSION))
    return bank
