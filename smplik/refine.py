"""Effector refinement: a few Levenberg-Marquardt steps from the network's pose.

The network's pose is close to the effectors but does not meet them exactly (the shipped
0.5 M-parameter model misses position effectors by about 4-6 cm). :func:`refine_output` moves it
onto them while staying near it: each step solves, per pose, the linear least-squares problem

``min_delta  sum_i w_i |r_i + J_i delta|^2  +  |e + delta|^2 / sigma_prior^2  +  lambda |delta|^2``

over ``delta``: one world-frame rotation increment per joint (3 J) plus a translation increment (3).
A world-frame increment ``delta_j`` rotates joint ``j``'s subtree about the joint, so it changes only
joint ``j``'s local rotation (by ``exp(R_world_parent^T delta_j)``); ``e`` is the current deviation of
each local rotation from the network's, in the same frame, so the prior keeps the learned pose and
the network still decides everything the effectors leave open. A step is kept only where it lowers
the objective (effector terms plus prior) and its normal equations factorise with finite numbers (a
failed Cholesky factorisation keeps that pose's previous iterate; it never raises); ``lambda`` starts
at ``damping / sigma_prior^2`` and, per pose, grows 10x after a rejected step and shrinks 0.3x after an accepted one.

Residuals ``r_i`` (3 per effector) and their analytic Jacobians (first order):

* position: ``p_k - target``; ``d p_k / d delta_j = -[p_k - p_j]_x`` for strict ancestors ``j`` of
  ``k``, identity for the translation;
* rotation: ``vee(skew(R_k R_target^T))`` (``sin(angle) * axis``, world frame);
  ``d / d delta_j = I`` for ``j = k`` and its ancestors;
* look-at: ``f - u`` with ``f = R_k direction`` and ``u`` the unit ray from the joint to the target
  (``|f - u|`` is about the angle); ``d f / d delta_j = -[f]_x``, ``d u / d p_k = -(I - u u^T) / dist``.

Weights ``w_i = W(tolerance) / sigma_type^2`` with ``W`` the training sampler's tolerance weight
relative to its cap (1 at tolerance 0, about 0.01 at tolerance 1), so loose effectors pull less,
as they do for the network.

Two backends compute this (:data:`RefineBackend`): :func:`refine_output_reference` here (torch) and the
numba kernels of :mod:`smplik.refine_fast` (CPU, no autograd; the normal equations solved through the tree
sparsity), which :func:`refine_output` runs by default where it can.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import PARENTS, EffectorType
from smplik.data.effector_sampling import EffectorSamplingConfig, tolerance_loss_weight
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput
from smplik.rotations import axis_angle_to_matrix, rot6d_to_matrix, skew_matrix

MAX_REFINE_ITERATIONS = 100
"""Most Levenberg-Marquardt steps a config (a model file's included) may ask for; 3 is the default."""
REFINE_RANGES = {"sigma_pos": (0.0, 100.0), "sigma_rot": (0.0, 100.0), "sigma_lookat": (0.0, 100.0),
                 "sigma_prior": (0.0, 100.0), "damping": (0.0, 1e9), "tolerance_eta": (0.0, 100.0)}
"""Accepted range of each float setting (sigmas > 0): a model file's saved config is checked against them."""


@dataclass(frozen=True)
class RefineConfig:
    """Settings of :func:`refine_output` (chosen on validation-split benchmark files)."""

    iterations: int = 3
    """Levenberg-Marquardt steps; 0 returns the network's pose unchanged."""
    sigma_pos: float = 0.01
    """Position residual scale (metres)."""
    sigma_rot: float = 0.1
    """Rotation residual scale (about radians)."""
    sigma_lookat: float = 0.1
    """Look-at residual scale (about radians)."""
    sigma_prior: float = 0.5
    """Prior scale (radians per joint) around the network's local rotations."""
    damping: float = 30.0
    """Initial Levenberg-Marquardt damping, in units of 1 / sigma_prior^2; per pose it grows 10x after a
    step that would raise the objective (that step is not taken) and shrinks 0.3x after one that lowers it."""
    tolerance_eta: float = 4.0
    """Exponent of the tolerance weight ``min(1, 1 / (100 tolerance^eta))`` (the sampler's
    ``W / W_M`` with sigma_M = 0.1 m and W_M = 1000)."""
    joint_prior: tuple[float, ...] | None = None
    """Relative prior weight of each joint (one per joint, > 0), multiplying ``1 / sigma_prior^2``: joints the
    network gets right more often are held closer to its answer. None: 1 for every joint. A model file's
    calibrated values (``smplik benchmark calibrate``) are its solver's default."""

    def __post_init__(self) -> None:
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, numbers.Integral) \
                or not 0 <= self.iterations <= MAX_REFINE_ITERATIONS:
            raise ValueError(f"RefineConfig.iterations must be an integer in [0, {MAX_REFINE_ITERATIONS}], got "
                             f"{self.iterations!r:.40}.")
        for name, (low, high) in REFINE_RANGES.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high \
                    or (name != "damping" and not value > 0):
                raise ValueError(f"RefineConfig.{name} must be a number in {'[' if name == 'damping' else '('}{low:g}, "
                                 f"{high:g}], got {value!r:.40}.")
        if self.joint_prior is not None and (not isinstance(self.joint_prior, (list, tuple))
                                             or len(self.joint_prior) > 1024):
            raise ValueError("RefineConfig.joint_prior must be a list of at most 1024 numbers.")
        if self.joint_prior is not None:
            values = tuple(self.joint_prior)
            if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                     and 0 < v <= 1e6 for v in values):
                raise ValueError("RefineConfig.joint_prior must be a list of finite numbers > 0 (one per joint), "
                                 f"got {str(self.joint_prior)[:80]}.")
            object.__setattr__(self, "joint_prior", tuple(float(v) for v in values))

    def to_dict(self) -> dict:
        out = asdict(self)
        if self.joint_prior is not None:
            out["joint_prior"] = list(self.joint_prior)
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "refine") -> RefineConfig:
        """The config of :meth:`to_dict` (as stored in a model file); unknown keys or bad values raise
        ``ValueError`` naming ``where`` and the key."""
        if not isinstance(data, dict):
            raise ValueError(f"{where}: expected a dict of RefineConfig fields, got {type(data).__name__}.")
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {unknown}; valid keys: {', '.join(sorted(names))}.")
        try:
            return cls(**data)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None

    def joint_prior_array(self, num_joints: int) -> np.ndarray:
        """(J,) float64 relative prior weights (ones when ``joint_prior`` is None).

        Raises:
            ValueError: ``joint_prior`` has another length than the skeleton's joints.
        """
        if self.joint_prior is None:
            return np.ones(num_joints)
        if len(self.joint_prior) != num_joints:
            raise ValueError(f"RefineConfig.joint_prior has {len(self.joint_prior)} values for a skeleton of "
                             f"{num_joints} joints.")
        return np.asarray(self.joint_prior, dtype=np.float64)


DEFAULT_REFINEMENT = RefineConfig()
"""What :class:`~smplik.solver.IKSolver` applies unless told otherwise."""
NO_REFINEMENT = RefineConfig(iterations=0)
"""The network's pose as it is."""


@lru_cache(maxsize=4)
def _ancestor_masks(parents: tuple[int, ...]) -> tuple[Tensor, Tensor]:
    """(J, J) masks: ``strict[k, j]`` = j is a strict ancestor of k; ``inclusive`` adds j = k.

    Built outside inference mode (like the FK level cache) so later autograd users can save them.
    """
    with torch.inference_mode(False):
        J = len(parents)
        strict = torch.zeros(J, J)
        for k in range(J):
            j = parents[k]
            while j >= 0:
                strict[k, j] = 1.0
                j = parents[j]
        return strict, strict + torch.eye(J)


def _vee_skew(M: Tensor) -> Tensor:
    """``vee((M - M^T) / 2)``: ``sin(angle) * axis`` of a rotation matrix. (..., 3, 3) -> (..., 3)."""
    return 0.5 * torch.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0],
                              M[..., 1, 0] - M[..., 0, 1]], -1)


def tolerance_weight(tolerance: Tensor, eta: float = 4.0) -> Tensor:
    """The training sampler's loss weight relative to its cap, ``W / W_M`` (sigma_M = 0.1 m, W_M = 1000):
    ``min(1, 1 / (100 tolerance^eta))`` in (0, 1], 1 up to tolerance ~0.3, 0.01 at 1. (...) -> (...)."""
    cfg = EffectorSamplingConfig(eta=eta)
    return tolerance_loss_weight(tolerance, cfg) / cfg.weight_max


RefineBackend = Literal["auto", "fast", "reference"]
"""``"reference"``: :func:`refine_output_reference` (torch, any device, autograd); ``"fast"``: the numba
kernels of :mod:`smplik.refine_fast` (CPU, no autograd, same results within 1e-5 rad); ``"auto"``: fast
where numba is installed and the inputs allow it, else the reference."""

_default_backend: RefineBackend = "auto"


@lru_cache(maxsize=1)
def numba_available() -> bool:
    """Whether numba imports (``pip install 'smplik[fast]'``), i.e. the ``"fast"`` backend can run."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def _check_backend(backend: str) -> None:
    if backend not in ("auto", "fast", "reference"):
        raise ValueError(f"Unknown refinement backend {backend!r}; expected 'auto', 'fast' or 'reference'.")


@contextmanager
def refine_backend(backend: RefineBackend) -> Iterator[None]:
    """Within the block, :func:`refine_output` calls without an explicit ``backend`` use this one."""
    global _default_backend
    _check_backend(backend)
    previous, _default_backend = _default_backend, backend
    try:
        yield
    finally:
        _default_backend = previous


def fast_backend_default() -> bool:
    """Whether :func:`refine_output` calls without a ``backend`` run the fast kernels on CPU inputs (numba is
    installed and no :func:`refine_backend` block asks for the reference)."""
    return _default_backend != "reference" and numba_available()


def resolve_backend(out: IKOutput, J_rest: Tensor, backend: RefineBackend | None = None) -> str:
    """The backend :func:`refine_output` runs for these inputs: ``"fast"`` or ``"reference"``.

    Raises:
        ValueError: ``backend="fast"`` when numba is missing, a tensor is not on the CPU or needs gradients.
    """
    backend = _default_backend if backend is None else backend
    _check_backend(backend)
    if backend == "reference":
        return "reference"
    problem = None
    if not numba_available():
        problem = "numba is not installed (pip install -e \".[fast]\" in the smplik checkout)"
    elif out.R_local.device.type != "cpu" or J_rest.device.type != "cpu":
        problem = "its inputs are not on the CPU"
    elif torch.is_grad_enabled() and any(t.requires_grad for t in (out.R_local, out.R_world, out.p_world, out.transl,
                                                                    J_rest)):
        problem = "its inputs need gradients"
    if problem is None:
        return "fast"
    if backend == "fast":
        raise ValueError(f"The fast refinement backend cannot run: {problem}.")
    return "reference"


def refine_output(out: IKOutput, J_rest: Tensor, eff: EffectorBatch, cfg: RefineConfig = DEFAULT_REFINEMENT,
                  parents: tuple[int, ...] = PARENTS, *, backend: RefineBackend | None = None) -> IKOutput:
    """Refine network poses towards their effectors (module docstring).

    Args:
        out: the network's output for B poses (its local rotations are also the prior's centre).
        J_rest: (B, J, 3) rest joints of each body (``ProtoResIK.rest_joints``).
        eff: the B rows of N effectors the network was given.
        cfg: steps, residual scales, prior and damping.
        backend: :data:`RefineBackend` (None: ``"auto"``, or the one set by :func:`refine_backend`);
            :func:`resolve_backend` tells which one runs.

    Returns:
        An :class:`IKOutput` with refined ``R_local``, ``R_world``, ``p_world`` and ``transl``
        (``draft`` is the network's) in the network's dtype; ``out`` itself when ``cfg.iterations == 0``.
    """
    if cfg.iterations == 0:
        return out
    if resolve_backend(out, J_rest, backend) == "fast":
        return _refine_output_fast(out, J_rest, eff, cfg, parents)
    return refine_output_reference(out, J_rest, eff, cfg, parents)


def _as_f64(t: Tensor) -> np.ndarray:
    """A float64 C-contiguous numpy copy of a CPU tensor."""
    return t.detach().numpy().astype(np.float64, order="C")


def _refine_output_fast(out: IKOutput, J_rest: Tensor, eff: EffectorBatch, cfg: RefineConfig,
                        parents: tuple[int, ...]) -> IKOutput:
    """:func:`refine_output` through :func:`smplik.refine_fast.refine_arrays` (few conversions: one pose's
    call is mostly Python overhead)."""
    from smplik.refine_fast import refine_arrays

    B, N = eff.joint.shape
    J = len(parents)
    if J_rest.shape != (B, J, 3):
        J_rest = J_rest.expand(B, J, 3)
    R_local, R_world, p_world, transl = refine_arrays(
        _as_f64(out.R_local), _as_f64(out.R_world), _as_f64(out.p_world), _as_f64(out.transl), _as_f64(J_rest),
        eff.joint.numpy().astype(np.int64, order="C"), eff.type.numpy().astype(np.int64, order="C"),
        _as_f64(eff.data), _as_f64(eff.tolerance), eff.mask.numpy().astype(np.bool_, order="C"), tuple(parents), cfg)
    dt = out.R_local.dtype
    return IKOutput(_as_tensor(R_local, dt), _as_tensor(R_world, dt), _as_tensor(p_world, dt), out.draft,
                    _as_tensor(transl, dt))


_NUMPY_FLOAT = {torch.float32: np.float32, torch.float64: np.float64}


def _as_tensor(a: np.ndarray, dtype: torch.dtype) -> Tensor:
    """A float64 kernel result as a tensor of ``dtype`` (converted by numpy where it can: cheaper)."""
    np_dtype = _NUMPY_FLOAT.get(dtype)
    return torch.from_numpy(a.astype(np_dtype, copy=False)) if np_dtype else torch.from_numpy(a).to(dtype)


def refine_output_reference(out: IKOutput, J_rest: Tensor, eff: EffectorBatch,
                            cfg: RefineConfig = DEFAULT_REFINEMENT, parents: tuple[int, ...] = PARENTS) -> IKOutput:
    """The torch implementation of :func:`refine_output` (any device, differentiable); the ``"fast"``
    backend is tested against it."""
    if cfg.iterations == 0:
        return out
    B, N = eff.joint.shape
    J = len(parents)
    dt = torch.float64  # the normal equations are stiff (1 / sigma_pos^2 against the prior)
    out_dtype = out.R_local.dtype
    strict, inclusive = (m.to(dt) for m in _ancestor_masks(tuple(parents)))
    rows = torch.arange(B)[:, None]
    k = eff.joint
    is_pos = ((eff.type == int(EffectorType.POSITION)) & eff.mask).to(dt)
    is_rot = ((eff.type == int(EffectorType.ROTATION)) & eff.mask).to(dt)
    is_look = ((eff.type == int(EffectorType.LOOK_AT)) & eff.mask).to(dt)
    w = tolerance_weight(eff.tolerance.to(dt), cfg.tolerance_eta) * (
        is_pos / cfg.sigma_pos ** 2 + is_rot / cfg.sigma_rot ** 2 + is_look / cfg.sigma_lookat ** 2)
    w3 = w.repeat_interleave(3, dim=1)  # (B, 3N)
    target = eff.data[..., :3].to(dt)
    R_target_T = rot6d_to_matrix(eff.data.to(dt) * is_rot[..., None]
                                 + torch.tensor([1.0, 0, 0, 0, 1.0, 0], dtype=dt) * (1 - is_rot[..., None]))
    R_target_T = R_target_T.transpose(-1, -2)
    look_dir = eff.data[..., 3:].to(dt)
    A_strict, A_incl = strict[k][..., None, None], inclusive[k][..., None, None]  # (B, N, J, 1, 1)
    eye = torch.eye(3, dtype=dt)
    parent_idx = torch.tensor([max(p, 0) for p in parents])
    root_frame = torch.zeros(J, 1, 1, dtype=dt)
    root_frame[0] = 1.0
    prior = 1.0 / cfg.sigma_prior ** 2
    prior_j = torch.from_numpy(cfg.joint_prior_array(J)).to(dt) * prior  # (J,)
    H_prior = torch.diag(torch.cat([prior_j.repeat_interleave(3), torch.zeros(3, dtype=dt)]))
    p_type, r_type, l_type = is_pos[..., None], is_rot[..., None], is_look[..., None]
    look = is_look.bool()

    def state_terms(R_local: Tensor, R_world: Tensor, p_world: Tensor) -> tuple[Tensor, ...]:
        """Per pose: effector joints' p_k (B, N, 3), R_k (B, N, 3, 3), facing f, unit ray u, distance,
        residual r (B, N, 3), and each local rotation's deviation from the network's, dev (B, J, 3)."""
        p_k, R_k = p_world[rows, k], R_world[rows, k]
        f = (R_k @ look_dir[..., None])[..., 0]
        ray = target - p_k
        dist = ray.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        u = ray / dist
        r = p_type * (p_k - target) + r_type * _vee_skew(R_k @ R_target_T) + l_type * (f - u)
        dev = _vee_skew(R_local @ R_net.transpose(-1, -2))  # parent frame
        return p_k, R_k, f, u, dist, r, dev

    def cost(terms: tuple[Tensor, ...]) -> Tensor:
        """The objective per pose (B,): weighted effector residuals plus the prior."""
        r, dev = terms[-2], terms[-1]
        return (w[..., None] * r.square()).sum((1, 2)) + (prior_j[:, None] * dev.square()).sum((1, 2))

    R_net = R_local = out.R_local.to(dt)
    transl, R_world, p_world, J_rest = out.transl.to(dt), out.R_world.to(dt), out.p_world.to(dt), J_rest.to(dt)
    terms = state_terms(R_local, R_world, p_world)
    current = cost(terms)
    lam = torch.full((B, 1, 1), prior * cfg.damping, dtype=dt)
    eye_n = torch.eye(3 * J + 3, dtype=dt)
    for _ in range(cfg.iterations):
        p_k, R_k, f, u, dist, r, dev = terms
        J_lever = -skew_matrix(p_k[:, :, None, :] - p_world[:, None, :, :]) * A_strict  # (B, N, J, 3, 3)
        proj = (eye - u[..., :, None] * u[..., None, :]) / dist[..., None]  # (B, N, 3, 3)
        s_pos, s_rot, s_look = (t[..., None, None, None] for t in (is_pos, is_rot, is_look))  # (B, N, 1, 1, 1)
        J_rotations = J_lever * s_pos + (s_rot * eye - s_look * skew_matrix(f)[:, :, None]) * A_incl
        # look-at rows also move with the joint's position: d u / d p_k = -proj.
        if look.any():
            J_rotations[look] += proj[look][:, None] @ J_lever[look]
        J_transl = p_type[..., None] * eye + l_type[..., None] * proj  # (B, N, 3, 3)
        Jac = torch.cat([J_rotations.permute(0, 1, 3, 2, 4).reshape(B, N, 3, 3 * J), J_transl], -1)
        Jac = Jac.reshape(B, 3 * N, 3 * J + 3)
        JtW = Jac.transpose(1, 2) * w3[:, None, :]
        # prior: deviation of each local rotation from the network's, as a world-frame increment
        R_world_parent = R_world[:, parent_idx] * (1 - root_frame) + eye * root_frame
        e = (R_world_parent @ dev[..., None])[..., 0]
        g = (JtW @ r.reshape(B, 3 * N, 1))[..., 0]
        g = g + torch.cat([(prior_j[:, None] * e).reshape(B, 3 * J), torch.zeros(B, 3, dtype=dt)], -1)
        A = JtW @ Jac + H_prior + lam * eye_n  # symmetric positive definite, unless the numbers overflow
        A = torch.where(torch.isfinite(A).all(-1, keepdim=True).all(-2, keepdim=True), A, eye_n)
        L, info = torch.linalg.cholesky_ex(A)
        factored = info == 0
        if not bool(factored.all()):  # a failed factorisation: that pose keeps its current iterate
            L = torch.where(factored[:, None, None], L, eye_n)
        delta = -torch.cholesky_solve(g[..., None], L)[..., 0]  # (B, 3J + 3)
        factored = factored & torch.isfinite(delta).all(-1)
        delta = torch.where(factored[:, None], delta, 0.0)
        d_local = (R_world_parent.transpose(-1, -2) @ delta[:, :3 * J].reshape(B, J, 3, 1))[..., 0]
        R_local_new = axis_angle_to_matrix(d_local) @ R_local
        transl_new = transl + delta[:, 3 * J:]
        R_world_new, p_world_new = forward_kinematics(R_local_new, J_rest, transl_new, parents)
        terms_new = state_terms(R_local_new, R_world_new, p_world_new)
        new = cost(terms_new)
        # Levenberg-Marquardt: keep a step only where it lowers the objective; otherwise damp harder.
        ok = (new < current) & factored & torch.isfinite(new)
        if bool(ok.all()):
            R_local, R_world, p_world, transl, terms = R_local_new, R_world_new, p_world_new, transl_new, terms_new
        elif bool(ok.any()):
            a1, a3 = ok[:, None], ok[:, None, None, None]
            R_local = torch.where(a3, R_local_new, R_local)
            R_world = torch.where(a3, R_world_new, R_world)
            p_world = torch.where(ok[:, None, None], p_world_new, p_world)
            transl = torch.where(a1, transl_new, transl)
            terms = tuple(torch.where(ok.view(B, *([1] * (t.dim() - 1))), t_new, t)
                          for t, t_new in zip(terms, terms_new, strict=True))
        current = torch.where(ok, new, current)
        lam = torch.where(ok[:, None, None], lam * 0.3, lam * 10.0)
    return IKOutput(R_local.to(out_dtype), R_world.to(out_dtype), p_world.to(out_dtype), out.draft,
                    transl.to(out_dtype))
