"""The configuration dataclasses of training and of the network, in one torch-free module.

Each component imports its config from here (``smplik.network.NetworkConfig``,
``smplik.losses.LossConfig``, ``smplik.data.effector_sampling.EffectorSamplingConfig``,
``smplik.train.TrainConfig`` are these classes), so that ``smplik train --help`` can show their
defaults without importing torch.
"""

from __future__ import annotations

import numbers
import typing
from collections.abc import Mapping
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

NETWORK_RANGES = {"width": (1, 8192), "encoder_blocks": (1, 32), "decoder_blocks": (1, 32),
                  "layers_per_block": (1, 16), "embedding_dim": (1, 1024)}
"""Accepted range of each size (the paper's model: width 1024, 3 blocks of 3 layers, embeddings 32); a model
file's config is checked against them before any layer is allocated."""

TRAIN_RANGES = {"steps": (0, 10**9), "batch_size": (1, 1 << 20), "lr": (0.0, 10.0), "lr_final_fraction": (0.0, 1.0),
                "val_every": (1, 10**9), "ckpt_every": (1, 10**9), "val_size": (0, 10**7), "val_fraction": (0.0, 0.99),
                "beta_noise": (0.0, 100.0), "part_swap": (0.0, 1.0), "distill_weight": (0.0, 1e6)}
"""Accepted range of each number of a training config (a config file's or a checkpoint's)."""

LOSS_RANGE = (0.0, 1e9)
"""Accepted range of every loss weight (:class:`LossConfig`)."""

EFFECTOR_SAMPLING_RANGES = {"min_effectors": (1, 1024), "max_effectors": (1, 1024), "sigma_max": (0.0, 100.0),
                            "eta": (0.0, 1000.0), "weight_max": (1e-9, 1e12), "lookat_distance_std": (0.0, 1000.0),
                            "limb_first": (0.0, 1.0)}
"""Accepted range of each number of :class:`EffectorSamplingConfig`."""

PRECISIONS = ("fp32", "bf16")


class ConfigError(ValueError):
    """A config value out of its documented range or of the wrong type (a flag, a config file, a checkpoint):
    the CLI reports it as one ``error:`` line."""


def _check_ranges(obj: Any, ranges: Mapping[str, tuple[float, float]], *, integers: bool = False) -> None:
    """Raise :class:`ConfigError` naming ``Class.field`` when a field of ``obj`` is not a number (an integer
    with ``integers``) in its closed range; NaN and infinities fail."""
    cls = type(obj).__name__
    for name, (low, high) in ranges.items():
        value = getattr(obj, name)
        kinds = numbers.Integral if integers else (numbers.Integral, numbers.Real)
        if isinstance(value, bool) or not isinstance(value, kinds) or not low <= value <= high:  # NaN fails too
            bounds = f"[{low}, {high}]" if integers else f"[{low:g}, {high:g}]"
            raise ConfigError(f"{cls}.{name} must be {'an integer' if integers else 'a number'} in {bounds}, "
                              f"got {value!r:.40}.")


@dataclass(frozen=True)
class NetworkConfig:
    """ProtoRes sizes. Defaults are a small CPU model; :meth:`paper` gives the published sizes."""

    width: int = 128
    """d: width of every fully connected layer (paper: 1024)."""
    encoder_blocks: int = 3
    """R: residual blocks in the encoder (paper: 3)."""
    decoder_blocks: int = 3
    """Residual blocks in each of GPD and IKD (paper: 3)."""
    layers_per_block: int = 2
    """L: fully connected layers per block (paper: 3)."""
    embedding_dim: int = 32
    """Size of the joint-id and effector-type embeddings (paper: 32)."""
    dropout: float = 0.0
    """Dropout after each hidden layer (paper: 0.01)."""
    effector_slots: bool = False
    """Extension: also feed both decoders the effectors scattered into per-joint slots (by joint id,
    duplicates averaged; permutation and translation invariant), so a narrow model can read exact
    effector values. False is the paper's architecture."""

    def __post_init__(self) -> None:
        _check_ranges(self, NETWORK_RANGES, integers=True)
        if isinstance(self.dropout, bool) or not isinstance(self.dropout, (int, float)) or not 0 <= self.dropout < 1:
            raise ConfigError(f"NetworkConfig.dropout must be a number in [0, 1), got {self.dropout!r:.40}.")
        if not isinstance(self.effector_slots, bool):
            raise ConfigError(f"NetworkConfig.effector_slots must be true or false, got {self.effector_slots!r:.40}.")

    @classmethod
    def paper(cls) -> NetworkConfig:
        return cls(width=1024, encoder_blocks=3, decoder_blocks=3, layers_per_block=3, embedding_dim=32, dropout=0.01)

    def to_dict(self) -> dict:
        return asdict(self)


INFERENCE_BATCH = 4096
"""Rows one solve may run at once (effector recovery tries every candidate of a step in one batch; a test-time
ensemble multiplies the rows): the batch at which a model file's inference memory is estimated."""
INFERENCE_TOKENS = 16
"""Effectors per row at which a model file's inference memory is estimated."""
_NUM_JOINTS, _COND, _SLOT_FEATURES = 24, 13, 21  # joints, beta (10) + gender one-hot (3), per-joint slot features


def network_parameter_count(cfg: NetworkConfig) -> int:
    """The number of weights :class:`smplik.network.ProtoResIK` allocates for ``cfg`` (computed, nothing built)."""
    w, L, E, J = cfg.width, cfg.layers_per_block, cfg.embedding_dim, _NUM_JOINTS

    def block(in_dim: int, out_dim: int, last: bool) -> int:
        mlp = in_dim * w + w + (L - 1) * (w * w + w)
        return mlp + (0 if last else in_dim * w + w) + w * out_dim + out_dim

    def stack(in_dim: int, out_dim: int, blocks: int) -> int:
        return sum(block(in_dim if r == 0 else w, out_dim, r == blocks - 1) for r in range(blocks))

    token = 6 + 1 + 2 * E + _COND
    slots = J * _SLOT_FEATURES if cfg.effector_slots else 0
    context = w + _COND + slots
    return ((J + 3) * E + stack(token, w, cfg.encoder_blocks) + stack(context, 3 * J, cfg.decoder_blocks)
            + stack(context + 3 * J, 6 * J, cfg.decoder_blocks))


def network_memory_bytes(cfg: NetworkConfig, *, batch: int, tokens: int, training: bool) -> int:
    """Bytes a network of ``cfg`` takes at ``batch`` rows of ``tokens`` effectors, float32: the weights (times 4
    when ``training``: gradients and Adam's two moments), plus the activations: every layer's output of the
    encoder (``batch * tokens`` rows) and of both decoders (``batch`` rows), all of them kept for the backward
    pass when ``training`` (and their gradients), else the few alive at once."""
    w, L = cfg.width, cfg.layers_per_block
    per_block = 2 * L + 4  # linear + relu outputs of each layer, skip, residual sum, block output, prototype step
    encoder = batch * tokens * w * per_block * cfg.encoder_blocks
    decoders = 2 * batch * w * per_block * cfg.decoder_blocks
    if training:
        activations = 2 * (encoder + decoders)
    else:
        activations = 4 * max(batch * tokens * w, batch * w)
    return 4 * (network_parameter_count(cfg) * (4 if training else 1) + activations)


def check_network_memory(cfg: NetworkConfig, source: str, *, batch: int = INFERENCE_BATCH,
                         tokens: int = INFERENCE_TOKENS, training: bool = False) -> None:
    """Refuse a network whose :func:`network_memory_bytes` is over :data:`smplik.limits.MEMORY_BYTES`, before
    any layer is allocated (every size may be inside :data:`NETWORK_RANGES` while their product is not).

    Raises:
        smplik.limits.LimitError: naming ``source``, the sizes and ``SMPLIK_MAX_MEMORY_BYTES``.
    """
    from smplik.limits import MEMORY_BYTES

    kind = f"training at batch {batch} x {tokens} effectors" if training else f"inference at batch {batch}"
    MEMORY_BYTES.check(network_memory_bytes(cfg, batch=batch, tokens=tokens, training=training),
                       f"{source}: a network of width {cfg.width}, {cfg.encoder_blocks}+{cfg.decoder_blocks}x2 "
                       f"blocks of {cfg.layers_per_block} layers ({network_parameter_count(cfg)} weights), {kind}")


@dataclass(frozen=True)
class LossConfig:
    """Weights of the total loss (Algorithm 1):
    ``w_pos_rnd / J (L_gpd_rnd + L_ikd_rnd) + w_pos_det (L_gpd_det + L_ikd_det)
    + (w_lookat L_lat + w_rot_global L_glob_rnd + w_rot_local L_loc_det) / J``."""

    w_pos_rnd: float = 100.0
    """W_pos: weight of the tolerance-weighted position-effector terms."""
    w_pos_det: float = 1.0
    """Weight of the all-joint position terms (sum of squared errors in m^2)."""
    w_rot_local: float = 1.0
    """Weight of the all-joint local geodesic term (sum over joints, radians)."""
    w_rot_global: float = 1.0
    """Weight of the tolerance-weighted global geodesic term on rotation effectors."""
    w_lookat: float = 1.0
    """Weight of the look-at angle term."""

    def __post_init__(self) -> None:
        _check_ranges(self, {f.name: LOSS_RANGE for f in fields(self)})


@dataclass(frozen=True)
class EffectorSamplingConfig:
    """Randomised effector sampling of ProtoRes Algorithm 1 / App. B (defaults = the paper's)."""

    min_effectors: int = 3
    """Smallest effector count per batch (N ~ U{min..max}, one N per batch)."""
    max_effectors: int = 16
    """Largest effector count per batch."""
    sigma_max: float = 0.1
    """sigma_M: noise std at tolerance 1 (metres for positions, radians for rotations)."""
    eta: float = 13.0
    """Tolerance-to-noise exponent: sigma = sigma_M * tolerance**eta."""
    weight_max: float = 1000.0
    """W_M: cap of the per-effector loss weight W = min(W_M, 1 / sigma)."""
    lookat_distance_std: float = 2.0
    """Std (metres) of the folded normal giving the look-at target distance (plus 0.1 m minimum)."""
    limb_first: float = 0.0
    """Fraction of samples whose first four effectors (all of them when N < 4) are position
    effectors on a random joint of each limb zone (:data:`~smplik.conventions.LIMB_ZONES`: hands
    and feet pinned first, as animators do and as the benchmark's random sets start); the rest
    follow the paper's sampling. 0 is the paper's sampling (and draws no extra random numbers)."""

    def __post_init__(self) -> None:
        _check_ranges(self, {k: v for k, v in EFFECTOR_SAMPLING_RANGES.items() if k.endswith("_effectors")},
                      integers=True)
        _check_ranges(self, {k: v for k, v in EFFECTOR_SAMPLING_RANGES.items() if not k.endswith("_effectors")})
        if self.min_effectors > self.max_effectors:
            raise ConfigError(f"EffectorSamplingConfig.min_effectors ({self.min_effectors}) must not exceed "
                              f"max_effectors ({self.max_effectors}).")


@dataclass(frozen=True)
class TrainConfig:
    """One training run."""

    data: str
    """Dataset cache written by ``smplik data build``."""
    out: str
    """Run folder: checkpoint, config, metrics.csv, loss_curve.png."""
    steps: int = 20_000
    """Optimizer steps in total (across resumes)."""
    batch_size: int = 512
    """Global batch size (split across torchrun processes)."""
    lr: float = 1e-3
    """Adam learning rate (paper: 2e-4 at batch 2048 on GPU; larger here for short CPU runs)."""
    lr_final_fraction: float = 0.05
    """Cosine decay from lr to lr * this fraction over ``steps``."""
    val_every: int = 500
    """Validate (and log) every this many steps."""
    ckpt_every: int = 500
    """Write the checkpoint every this many steps (and at the end or on Ctrl-C)."""
    val_size: int = 2048
    """Validation poses (fixed set, fixed effectors)."""
    val_fraction: float = 0.0
    """For a cache without validation frames: hold out this fraction of the train clips (seeded by
    ``seed``) for validation. 0: train on all clips and skip validation (with a notice)."""
    seed: int = 0
    augment: bool = True
    """Random rotation about the vertical axis and left/right mirroring."""
    beta_noise: float = 1.0
    """Std of the Gaussian added to dataset betas (or of betas when the source has none)."""
    part_swap: float = 0.0
    """Probability per limb and sample that the limb's local rotations come from another random
    train frame (:class:`~smplik.data.sampler.PoseSampler`); 0: off (the paper's sampling)."""
    model_dir: str | None = None
    """Folder with real SMPL files (default: built-in model)."""
    init_from: str | None = None
    """Start a new run from this model's weights (a checkpoint or exported model; same network sizes)."""
    precision: str = "fp32"
    """"fp32", or "bf16": the network's layers run under CPU/CUDA autocast in bfloat16 (Intel AMX and
    recent GPUs run these several times faster); rotations, FK and the loss stay float32."""
    distill_from: str | None = None
    """Teacher model file: the loss also pulls the network towards the teacher's test-time ensemble
    answer (``distill_ensemble``) on the same noisy effectors (self-distillation of the ensemble)."""
    distill_weight: float = 1.0
    """Weight of the distillation term (:func:`smplik.losses.distillation_loss`)."""
    distill_ensemble: str = "mirror+yaw4"
    """The teacher's ensemble (:meth:`smplik.ensemble.EnsembleConfig.parse`)."""
    distill_refine: bool = False
    """The teacher's answer also goes through the solver's effector refinement (the teacher file's
    calibrated ``refine`` settings, else the default): the target is the teacher solver's pose."""
    network: NetworkConfig = field(default_factory=NetworkConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    effectors: EffectorSamplingConfig = field(default_factory=EffectorSamplingConfig)

    def __post_init__(self) -> None:
        _check_ranges(self, TRAIN_RANGES)
        _check_ranges(self, {"seed": (0, 2**31 - 1)}, integers=True)
        if self.precision not in PRECISIONS:
            raise ConfigError(f"TrainConfig.precision must be one of {', '.join(PRECISIONS)}, got "
                              f"{self.precision!r:.40}.")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "config") -> TrainConfig:
        """Build from a (possibly partial) dict such as ``config.json``; unknown keys and values of
        the wrong type raise ``ValueError`` naming ``source`` and the key (``network.width``)."""
        return _dataclass_from_dict(cls, d, source, "")

    @classmethod
    def from_file(cls, path: str | Path, **required: str) -> TrainConfig:
        """Read a JSON config file (partial: missing fields keep their defaults).

        ``required`` fills ``data``/``out`` when the file lacks them (e.g. ``data="", out=""``).
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"Config file not found: {path}")
        from smplik.validation import read_json

        obj = read_json(path, ConfigError, what="config file")  # bounded read (smplik.limits.JSON_BYTES)
        if not isinstance(obj, dict):
            raise ConfigError(f"{path}: a config file must hold a JSON object, got {type(obj).__name__}.")
        return cls.from_dict({**required, **obj}, str(path))


def _dataclass_from_dict(cls: type, d: Any, source: str, prefix: str) -> Any:
    """A (nested, frozen) config dataclass from a dict, strictly: every key known, every value typed."""
    where = prefix.rstrip(".") or "the top level"
    if not isinstance(d, Mapping):
        raise ConfigError(f"{source}: '{where}' must be an object, got {type(d).__name__}.")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    unknown = [k for k in d if k not in names]
    if unknown:
        raise ConfigError(f"{source}: unknown key '{prefix}{unknown[0]}'; expected one of: {', '.join(names)}.")
    kwargs = {}
    for key, value in d.items():
        typ = hints[key]
        if is_dataclass(typ):
            kwargs[key] = _dataclass_from_dict(typ, value, source, f"{prefix}{key}.")
            continue
        allowed = typing.get_args(typ) or (typ,)
        ok = any((t is type(None) and value is None) or (t is bool and type(value) is bool)
                 or (t is int and type(value) is int) or (t is float and type(value) in (int, float))
                 or (t is str and type(value) is str) for t in allowed)
        if not ok:
            expected = " or ".join("null" if t is type(None) else t.__name__ for t in allowed)
            raise ConfigError(f"{source}: key '{prefix}{key}' must be {expected}, got {value!r:.60}.")
        kwargs[key] = float(value) if float in allowed and type(value) is int else value
    required = [f.name for f in fields(cls) if f.name not in kwargs and f.default is f.default_factory is MISSING]
    if required:
        raise ConfigError(f"{source}: missing key '{prefix}{required[0]}'.")
    try:
        return cls(**kwargs)
    except ValueError as exc:  # a value out of its documented range (the config's __post_init__)
        raise ConfigError(f"{source}: {exc}") from None
