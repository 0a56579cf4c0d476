"""SMPL-SI estimator: skeleton features -> (beta, scale) by Gaussian kernel regression (smpl-ik.txt eq. 3).

``beta_hat = sum_i w_i beta_i / sum_j w_j`` with ``w_i = exp(-|f - f_i|^2 / (2 h^2))`` over the
sample bank (:mod:`shape_inversion.bank`), and the same for the scale.

Choices, documented because the paper leaves them open:

* **Feature space and h.** The paper applies the kernel to ``(f - f_i) / h`` with ``h = 0.02`` and
  does not normalise the features, so features stay raw distances in **metres** and ``h = 0.02 m``.
  The kernel is isotropic over the six features.
* **Neighbour query.** A scikit-learn ``KDTree`` returns the ``max_neighbours`` nearest bank
  samples (cost ``O(log N + k)``, independent of the bank size for a fixed k); samples whose weight
  relative to the nearest one is below ``min_relative_weight`` are dropped. Weights are computed
  relative to the nearest sample (``exp(-(d^2 - d_min^2) / 2h^2)``), so they never underflow.
* **Out of range.** When the nearest sample is farther than ``max_nearest_distance`` (default
  ``0.15 m = 7.5 h``: every kernel weight is below ``exp(-28)``), the proportions are outside the
  human range the bank covers: up to ``max_stylised_distance`` (``0.30 m``; a stylised character,
  e.g. legs 0.6 x a human's) the estimate is the nearest human body with a warning saying so; beyond
  it :class:`ShapeInversionError` is raised, naming the features whose scale-free ratio (feature /
  head-ankle distance) falls outside the bank's range. For
  scale: held-out in-range bodies have their nearest sample within ~2.5 h (99 %); real CMU
  skeletons reach 6 h (subject 05: long shins, and forearms shortened by the cgspeed layout);
  a forearm twice the human length is ~30 h away.
* **Refinement (off by default: the default is the paper's plain estimate).** The
  kernel mean averages neighbours up to ~h away, so its features miss the query's by ~2 cm.
  Refinement is a regularised least-squares polish: it minimises
  ``|F(x) - f|^2 / tol^2 + (x - x_kernel)^T S^-1 (x - x_kernel)`` over ``x = (beta, scale)`` inside
  the bank's box, where ``S`` is the kernel-weighted posterior covariance and ``tol = 1 mm``. A
  human-range skeleton is matched to ~1 mm while staying within a few posterior standard
  deviations of the kernel mean; a skeleton SMPL cannot match exactly (e.g. CMU's shortened
  forearms) keeps a residual. It is off by default because the six features leave most of beta
  unobserved: on real skeletons (MakeHuman, CMU) the polish trades a few mm of feature residual
  for extreme values of unobserved components (hip width, mass -> +-5), a worse-looking body than
  the kernel mean's. Use it when matching the six distances matters more than the mesh. The paper's
  estimate is kept in :attr:`ShapeEstimate.kernel_betas` / :attr:`ShapeEstimate.kernel_scale`.
* **Joint fit (second stage, on by default when the mapped rest joints are given).** SMPL's rest joints are
  linear in beta, so ``(beta, scale)`` is fitted to every mapped joint of the skeleton's rest pose, each bone
  laid along SMPL's direction as retargeting lays it (:mod:`shape_inversion.joint_fit`), after a rigid
  alignment: ``sum_m w_m |scale J_m(beta) - (R q_m + t)|^2 / tol^2 + (x - x_0)^T S^-1 (x - x_0) +
  |beta|^2 / std^2`` with the first stage's estimate ``x_0`` and covariance ``S`` as the prior (``tol = 1 cm``,
  ``std = 2``, convention-dependent joints weighing 0.5), inside the bank's box short of its edge. It is kept
  only when it lowers the mapped joints' mean rest residual (:attr:`ShapeEstimate.rest_joint_residual_m`);
  the features alone decide whether the skeleton is a human and whether the fit is weak.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from shape_inversion.bank import BankConfig, SampleBank, load_or_build_bank
from shape_inversion.features import FEATURE_NAMES, FEATURE_PAIRS, NUM_FEATURES
from shape_inversion.joint_fit import MappedRest, reposed_rest
from smplik.body_model import BodyModel
from smplik.conventions import JOINT_INDEX, JOINT_NAMES, NUM_BETAS, Gender
from smplik.metrics import rigid_align

if TYPE_CHECKING:  # scikit-learn and scipy.optimize are imported where used: a second of every start
    from sklearn.neighbors import KDTree


class ShapeInversionError(ValueError):
    """The skeleton cannot be mapped to SMPL (proportions outside the human range, bad features)."""


@dataclass(frozen=True)
class EstimatorConfig:
    """Kernel regression settings (defaults: the paper's h plus our refinement)."""

    bandwidth: float = 0.02
    """Gaussian kernel width h, metres of feature distance (paper: 0.02)."""
    max_neighbours: int = 1024
    """How many nearest bank samples the KD-tree returns."""
    min_relative_weight: float = 1e-6
    """Neighbours whose weight relative to the nearest one is below this are ignored."""
    max_nearest_distance: float = 0.15
    """Beyond this distance of the nearest sample (metres; 7.5 h) the proportions are outside the human range:
    the estimate is the nearest human body, reported as approximate in ``warnings`` (a stylised character)."""
    max_stylised_distance: float = 0.30
    """Raise :class:`ShapeInversionError` when the nearest sample is farther than this (metres; 15 h): not a
    human, or wrong units."""
    max_proportion_factor: float = 2.0
    """Raise :class:`ShapeInversionError` when a proportion (a feature over head-ankle) lies more than this factor
    outside the bank's range (below its minimum / factor or above its maximum x factor): not a human at any
    size. Scale-free, unlike the distances above, which shrink with the skeleton's size (a small robot whose
    upper arm is a quarter of the shortest human's would pass them)."""
    refine: bool = False
    """Polish the kernel mean so that its features match the query to ~tol (see module docstring)."""
    refine_tolerance_m: float = 0.001
    """Feature residual (metres) that costs as much as moving one posterior standard deviation."""
    refine_max_evaluations: int = 100
    """Cap on the refinement's least-squares iterations."""
    weak_residual_m: float = 0.04
    """A fit whose largest feature residual (of the first stage, before the joint fit) exceeds this (metres) is
    reported as weak in ``warnings``."""
    weak_effective_samples: float = 5.0
    """A fit resting on fewer effective bank samples than this is reported as weak in ``warnings``."""
    edge_fraction: float = 0.05
    """An estimate within this fraction of the bank's range from its edge is at the edge: a scale there is
    refused (wrong units, or a body the bank does not cover), a beta there is reported in ``warnings``."""
    joint_fit: bool = True
    """Second stage, when the skeleton's mapped rest joints are given: fit SMPL's rest joints to them (see the
    module docstring); kept only when it lowers their residual after a rigid alignment."""
    joint_fit_tolerance_m: float = 0.01
    """Joint residual (metres, per coordinate of a joint of weight 1) that costs as much as moving one posterior
    standard deviation away from the first stage's estimate."""
    joint_fit_weights: tuple[tuple[str, float], ...] = (
        ("spine1", 0.5), ("spine2", 0.5), ("spine3", 0.5), ("left_collar", 0.5), ("right_collar", 0.5),
        ("left_foot", 0.5), ("right_foot", 0.5), ("left_hand", 0.5), ("right_hand", 0.5))
    """Joints whose placement depends on the rig's conventions (spine, collars, hand and foot ends) and their
    weight in the joint fit; every other mapped joint weighs 1."""
    joint_fit_beta_std: float = 2.0
    """Population prior of the joint fit: ``|beta|^2 / std^2`` is added (SMPL's betas are whitened shape
    components, ~N(0, 1) over its training bodies); 0: none."""
    joint_fit_max_evaluations: int = 200
    """Cap on the joint fit's least-squares iterations."""


HUMAN_SIZE_SCALE = (0.5, 1.5)
"""Mean-body scales fitted as they are; a skeleton outside is fitted at the bank's middle scale and scaled back
(:meth:`ShapeEstimator._size_factor`): scale has no bank range."""

ANY_SIZE_SCALE = (0.03, 18.0)
"""Mean-body scales read at their own size (about 5 cm to 30 m tall: a figurine to a giant); beyond, a skeleton
is a unit error (a human in centimetres read as metres) and refused as one ("its units look wrong ... --units")."""


@dataclass(frozen=True, eq=False)
class ShapeEstimate:
    """Result of :meth:`ShapeEstimator.estimate`.

    Attributes:
        betas: (10,) estimated shape.
        scale: global scale of the SMPL body (joints = scale * J(betas)).
        gender: body model gender.
        betas_std: (10,) posterior standard deviation of beta (kernel-weighted spread).
        scale_std: posterior standard deviation of the scale.
        effective_samples: Kish effective sample size ``(sum w)^2 / sum w^2``.
        neighbours_used: bank samples with a non-negligible weight.
        nearest_distance_m: feature distance to the nearest bank sample.
        query_features_m: (6,) the query's features.
        feature_residual_m: (6,) features of ``scale * J(betas)`` minus the query's.
        max_feature_residual_m: ``max |feature_residual_m|``.
        kernel_betas: (10,) the paper's plain kernel-regression estimate (eq. 3).
        kernel_scale: its scale.
        refined: whether ``betas``/``scale`` were refined from the kernel estimate.
        joint_fit: whether ``betas``/``scale`` come from the joint fit (second stage).
        rest_joint_residual_m: mean distance (metres) of the skeleton's mapped rest joints from
            ``scale * J(betas)`` after a rigid alignment; NaN when the joints were not given.
        first_stage_rest_joint_residual_m: the same for the first stage's estimate (kernel mean, or refined).
        warnings: betas at the edge of the bank's range, with the numbers (also sent to :mod:`warnings`).
    """

    betas: np.ndarray
    scale: float
    gender: Gender
    betas_std: np.ndarray
    scale_std: float
    effective_samples: float
    neighbours_used: int
    nearest_distance_m: float
    query_features_m: np.ndarray
    feature_residual_m: np.ndarray
    max_feature_residual_m: float
    kernel_betas: np.ndarray = field(repr=False)
    kernel_scale: float = field(repr=False)
    refined: bool = False
    warnings: tuple[str, ...] = ()
    joint_fit: bool = False
    rest_joint_residual_m: float = float("nan")
    first_stage_rest_joint_residual_m: float = float("nan")

    def to_dict(self) -> dict:
        """JSON-ready dictionary (lists and floats)."""
        return {
            "betas": [float(b) for b in self.betas],
            "scale": float(self.scale),
            "gender": self.gender.value,
            "diagnostics": {
                "betas_std": [float(b) for b in self.betas_std],
                "scale_std": float(self.scale_std),
                "effective_samples": float(self.effective_samples),
                "neighbours_used": int(self.neighbours_used),
                "nearest_distance_m": float(self.nearest_distance_m),
                "feature_names": list(FEATURE_NAMES),
                "query_features_m": [float(x) for x in self.query_features_m],
                "feature_residual_m": [float(x) for x in self.feature_residual_m],
                "max_feature_residual_m": float(self.max_feature_residual_m),
                "kernel_betas": [float(b) for b in self.kernel_betas],
                "kernel_scale": float(self.kernel_scale),
                "refined": bool(self.refined),
                "joint_fit": bool(self.joint_fit),
                "rest_joint_residual_m": _json_float(self.rest_joint_residual_m),
                "first_stage_rest_joint_residual_m": _json_float(self.first_stage_rest_joint_residual_m),
                "warnings": list(self.warnings),
            },
        }


def _json_float(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _pair_dirs(J_template: np.ndarray, J_dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per feature pair: (6, 3) template difference and (6, 3, 10) shape-direction difference."""
    ia = [JOINT_INDEX[a] for a, _ in FEATURE_PAIRS]
    ib = [JOINT_INDEX[b] for _, b in FEATURE_PAIRS]
    return J_template[ia] - J_template[ib], J_dirs[ia] - J_dirs[ib]


def features_and_jacobian(T: np.ndarray, D: np.ndarray, betas: np.ndarray, scale: float) -> tuple[np.ndarray,
                                                                                                       np.ndarray]:
    """Features of ``scale * J(betas)`` and their Jacobian w.r.t. ``(betas, scale)``.

    Args: T (6, 3), D (6, 3, 10) from :func:`_pair_dirs`; betas (10,); scale.
    Returns: features (6,), jacobian (6, 11).
    """
    d = T + D @ betas  # (6, 3)
    length = np.linalg.norm(d, axis=-1)
    unit = d / np.maximum(length, 1e-12)[:, None]
    jac = np.empty((NUM_FEATURES, NUM_BETAS + 1))
    jac[:, :NUM_BETAS] = scale * np.einsum("fc,fcb->fb", unit, D)
    jac[:, NUM_BETAS] = length
    return scale * length, jac


@dataclass(frozen=True, eq=False)
class ShapeEstimator:
    """Kernel regression over one gender's bank. Build with :meth:`build`; query with :meth:`estimate`.

    Attributes:
        bank: the samples.
        tree: KD-tree over ``bank.features``.
        pair_template: (6, 3), pair_dirs: (6, 3, 10): the features' linear parts (float64).
        config: estimator settings.
        joint_template: (24, 3), joint_dirs: (24, 3, 10): SMPL's rest joints ``J(beta) = joint_template +
            joint_dirs @ beta`` (float64) for the joint fit; None (no joint fit) when built without them.
    """

    bank: SampleBank
    tree: KDTree = field(repr=False)
    pair_template: np.ndarray = field(repr=False)
    pair_dirs: np.ndarray = field(repr=False)
    config: EstimatorConfig = EstimatorConfig()
    joint_template: np.ndarray | None = field(default=None, repr=False)
    joint_dirs: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def build(cls, model: BodyModel, bank_config: BankConfig | None = None, config: EstimatorConfig | None = None,
              *, cache_root: str | Path | None = None, use_cache: bool = True) -> ShapeEstimator:
        """Load (or sample and cache) the bank of ``model`` (default :class:`BankConfig`) and index it."""
        bank_config = BankConfig() if bank_config is None else bank_config
        config = EstimatorConfig() if config is None else config
        bank = load_or_build_bank(model, bank_config, root=cache_root, use_cache=use_cache)
        J_template, J_dirs = model.J_template.double().numpy(), model.J_dirs.double().numpy()
        T, D = _pair_dirs(J_template, J_dirs)
        from sklearn.neighbors import KDTree

        return cls(bank, KDTree(bank.features), T, D, config, J_template, J_dirs)

    @property
    def gender(self) -> Gender:
        return self.bank.gender

    def features_of(self, betas: np.ndarray, scale: float) -> np.ndarray:
        """Features (6,) of ``scale * J(betas)``, metres."""
        return features_and_jacobian(self.pair_template, self.pair_dirs, np.asarray(betas, float), scale)[0]

    def _proportions_human(self, query: np.ndarray) -> bool:
        """Whether every proportion of ``query`` (6,) (feature / head-ankle) lies within ``max_proportion_factor``
        of the bank's range of that proportion."""
        ratio_bank = self.bank.features / self.bank.features[:, 2:3]  # (N, 6)
        ratio_q = query / query[2]
        f = self.config.max_proportion_factor
        return bool(np.all((ratio_q >= ratio_bank.min(0) / f) & (ratio_q <= ratio_bank.max(0) * f)))

    def _out_of_range_message(self, query: np.ndarray, nearest: float) -> str:
        bank_f = self.bank.features
        ratio_bank = bank_f / bank_f[:, 2:3]
        lo, hi = ratio_bank.min(0), ratio_bank.max(0)
        ratio_q = query / max(query[2], 1e-12)
        off = [f"{FEATURE_NAMES[k]} = {query[k]:.3f} m ({ratio_q[k]:.2f} x head-ankle; human range "
               f"{lo[k]:.2f}-{hi[k]:.2f})" for k in range(NUM_FEATURES) if k != 2 and not lo[k] <= ratio_q[k] <= hi[k]]
        size_lo, size_hi = bank_f[:, 2].min(), bank_f[:, 2].max()
        if not off and not size_lo <= query[2] <= size_hi:  # human proportions, inhuman size: the units
            return (f"The skeleton has human proportions but its units look wrong: head to ankle is {query[2]:.3f} m "
                    f"(about {query[2] / 0.84:.2f} m tall; SMPL-SI covers {size_lo:.2f}-{size_hi:.2f} m head to "
                    "ankle). Try --units (m, cm, mm, in, ft, cmu or metres per unit).")
        if not size_lo <= query[2] <= size_hi:
            off.append(f"{FEATURE_NAMES[2]} = {query[2]:.3f} m (overall size; bank covers {size_lo:.2f}-{size_hi:.2f} "
                       "m: check the units)")
        if not off:  # each ratio is plausible but not together: name the worst offenders
            _, idx = self.tree.query(query[None], k=1)
            diff = np.abs(query - bank_f[idx[0, 0]])
            off = [f"{FEATURE_NAMES[k]} = {query[k]:.3f} m (nearest human sample: {bank_f[idx[0, 0], k]:.3f} m)"
                   for k in np.argsort(-diff)[:2]]
        limit = max(self.config.max_stylised_distance, self.config.max_nearest_distance)
        why = (f"nearest bank sample {nearest * 1000:.0f} mm away in feature space, limit {limit * 1000:.0f} mm"
               if nearest > limit else
               f"a proportion more than {self.config.max_proportion_factor:g}x outside the human range, at any size")
        return (f"Not a human: the skeleton's proportions are outside the human range covered by SMPL-SI ({why}). "
                "Features off: " + "; ".join(off) + ".")

    def estimate(self, features: np.ndarray, rest: MappedRest | None = None) -> ShapeEstimate:
        """Estimate (beta, scale) from a skeleton's features (6,) in metres.

        ``rest``: the skeleton's mapped rest joints (:class:`shape_inversion.joint_fit.MappedRest`, metres, smplik's
        frame; :meth:`shape_inversion.skeleton_io.Character.mapped_rest`), for
        the joint fit (second stage, ``config.joint_fit``); the features alone decide whether it is a human.

        Raises:
            ShapeInversionError: non-finite/non-positive features, or proportions outside the bank.
        """
        query = np.asarray(features, dtype=np.float64).reshape(-1)
        if query.shape != (NUM_FEATURES,):
            raise ShapeInversionError(f"Expected {NUM_FEATURES} features, got shape {np.shape(features)}.")
        if not np.all(np.isfinite(query)) or np.any(query <= 0):
            bad = [FEATURE_NAMES[k] for k in range(NUM_FEATURES) if not (np.isfinite(query[k]) and query[k] > 0)]
            raise ShapeInversionError(f"Degenerate skeleton: zero or invalid bone features {', '.join(bad)}.")
        size = self._size_factor(query)
        if size != 1.0:  # any size: fit the shape at human size, then scale the body by the same factor
            import dataclasses
            import warnings

            normal = self.estimate(query / size, None if rest is None else
                                   dataclasses.replace(rest, positions=np.asarray(rest.positions) / size))
            note = (f"read at its own size: about {query[2] / 0.84:.2f} m tall, {size:.3g} x a human of the sample "
                    f"bank's middle scale; its shape is fitted at human size and the SMPL body scaled by {size:.3g}")
            warnings.warn(note, stacklevel=2)
            return dataclasses.replace(
                normal, scale=normal.scale * size, scale_std=normal.scale_std * size,
                nearest_distance_m=normal.nearest_distance_m * size, query_features_m=query,
                feature_residual_m=normal.feature_residual_m * size,
                max_feature_residual_m=normal.max_feature_residual_m * size,
                kernel_scale=normal.kernel_scale * size, warnings=(note, *normal.warnings),
                rest_joint_residual_m=normal.rest_joint_residual_m * size,
                first_stage_rest_joint_residual_m=normal.first_stage_rest_joint_residual_m * size)
        cfg = self.config
        k = min(cfg.max_neighbours, len(self.bank))
        dist, idx = self.tree.query(query[None], k=k)
        dist, idx = dist[0], idx[0]
        if dist[0] > max(cfg.max_stylised_distance, cfg.max_nearest_distance) \
                or not self._proportions_human(query):
            raise ShapeInversionError(self._out_of_range_message(query, float(dist[0])))
        stylised = ()
        if dist[0] > cfg.max_nearest_distance:  # a stylised human: the nearest human body, said to be approximate
            import warnings

            note = (f"stylised proportions outside SMPL's human range (nearest human sample {dist[0] * 1000:.0f} mm "
                    f"away in feature space, human range {cfg.max_nearest_distance * 1000:.0f} mm): the shape is the "
                    "nearest human body, so bone lengths will differ from the character's")
            warnings.warn(note, stacklevel=2)
            stylised = (note,)
        w = np.exp(-0.5 * (dist**2 - dist[0] ** 2) / cfg.bandwidth**2)
        keep = w >= cfg.min_relative_weight
        w, idx = w[keep], idx[keep]
        wn = w / w.sum()
        params = np.concatenate([self.bank.betas[idx], self.bank.scales[idx, None]], axis=1)  # (k, 11)
        mean = wn @ params
        centred = params - mean
        cov = (wn[:, None] * centred).T @ centred
        kernel_mean = mean.copy()
        if cfg.refine:
            mean = self._refine(query, mean, cov)
        fitted, rest_residual, first_residual, first = False, float("nan"), float("nan"), mean
        if rest is not None and self.joint_template is not None and len(rest) >= 3 \
                and np.all(np.isfinite(rest.positions)):
            first_residual = rest_residual = self.rest_joint_residual(mean, rest)
            if cfg.joint_fit:
                candidate = self._fit_joints(rest, mean, cov)
                candidate_residual = self.rest_joint_residual(candidate, rest)
                if candidate_residual < first_residual:  # never worse than the first stage
                    mean, rest_residual, fitted = candidate, candidate_residual, True
        betas, scale = mean[:NUM_BETAS], float(mean[NUM_BETAS])
        residual = self.features_of(betas, scale) - query
        std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        notes = (*stylised, *self._edge_check(betas, scale, query))
        # a weak fit is judged on the first stage: the joint fit trades feature residual for the rest joints
        judged = self.features_of(first[:NUM_BETAS], float(first[NUM_BETAS])) - query if fitted else residual
        max_residual, n_eff = float(np.abs(judged).max()), float(w.sum() ** 2 / (w**2).sum())
        if max_residual > cfg.weak_residual_m or n_eff < cfg.weak_effective_samples:
            import warnings

            worst = FEATURE_NAMES[int(np.argmax(np.abs(judged)))]
            note = (f"weak shape inversion: largest feature residual {max_residual * 1000:.0f} mm ({worst}; limit "
                    f"{cfg.weak_residual_m * 1000:.0f} mm), {n_eff:.1f} effective samples (limit "
                    f"{cfg.weak_effective_samples:g}): check the joint map and the rest pose (--rest, --map)")
            warnings.warn(note, stacklevel=2)
            notes = (*notes, note)
        return ShapeEstimate(
            betas=betas, scale=scale, gender=self.gender, betas_std=std[:NUM_BETAS], scale_std=float(std[NUM_BETAS]),
            effective_samples=float(w.sum() ** 2 / (w**2).sum()), neighbours_used=int(w.size),
            nearest_distance_m=float(dist[0]), query_features_m=query, feature_residual_m=residual,
            max_feature_residual_m=float(np.abs(residual).max()), kernel_betas=kernel_mean[:NUM_BETAS],
            kernel_scale=float(kernel_mean[NUM_BETAS]), refined=cfg.refine, warnings=notes, joint_fit=fitted,
            rest_joint_residual_m=rest_residual, first_stage_rest_joint_residual_m=first_residual,
        )

    def _size_factor(self, query: np.ndarray) -> float:
        """1, or the factor taking a skeleton outside human size to the middle of the bank's scale range.

        Scale is one global factor: a 0.2 m figurine or a 20 m giant is fitted at human size (``query / factor``,
        whose head-ankle height is the bank's middle scale's) and its scale multiplied back. Human size: a
        mean-body scale within :data:`HUMAN_SIZE_SCALE` (children to very tall adults, inside the bank's range).
        """
        lo, hi = self.bank.config.scale_range
        unit = float(self.features_of(np.zeros(NUM_BETAS), 1.0)[2])  # head-ankle of the mean body at scale 1
        approx = query[2] / unit  # the scale a mean body of this head-ankle height would have
        if HUMAN_SIZE_SCALE[0] <= approx <= HUMAN_SIZE_SCALE[1] or not ANY_SIZE_SCALE[0] <= approx <= ANY_SIZE_SCALE[1]:
            return 1.0  # human size, or so far beyond any character's that the units are wrong (said as such)
        return float(approx / (0.5 * (lo + hi)))

    def _edge_check(self, betas: np.ndarray, scale: float, query: np.ndarray) -> tuple[str, ...]:
        """Refuse a scale at the edge of the bank's range; warn (and return the notes) for betas there."""
        import warnings

        bank_cfg, frac = self.bank.config, self.config.edge_fraction
        lo, hi = bank_cfg.scale_range
        margin = frac * (hi - lo)
        if not lo + margin <= scale <= hi - margin:
            stature = query[2] / 0.84
            raise ShapeInversionError(
                f"SMPL-SI scale {scale:.3f} is at the edge of the sample bank's range {lo:g}-{hi:g} (head-ankle "
                f"{query[2]:.3f} m, about {stature:.2f} m tall): check the character's units (--units) or rig.")
        limit = (1 - frac) * bank_cfg.beta_range
        notes = tuple(f"beta[{k}] = {b:+.2f} is at the edge of the sample bank's range +-{bank_cfg.beta_range:g}: "
                      "the skeleton's proportions are extreme for SMPL" for k, b in enumerate(betas) if abs(b) > limit)
        for note in notes:
            warnings.warn(note, stacklevel=3)
        return notes

    def rest_joints_of(self, x: np.ndarray) -> np.ndarray:
        """SMPL's rest joints ``J(beta)`` (24, 3) at unit scale for ``x = (beta, scale)`` (11,)."""
        assert self.joint_template is not None and self.joint_dirs is not None
        return self.joint_template + self.joint_dirs @ x[:NUM_BETAS]

    def _rest_distances(self, x: np.ndarray, rest: MappedRest, weights: np.ndarray | None = None) -> np.ndarray:
        """(M, 3) differences ``scale * J(beta)`` minus the mapped joints reposed on SMPL's bone directions
        (:func:`shape_inversion.joint_fit.reposed_rest`), rigidly aligned (weights (M,), default all 1)."""
        J = self.rest_joints_of(x)
        target = x[NUM_BETAS] * J[rest.smpl]
        q = torch.as_tensor(reposed_rest(rest, J))
        w = None if weights is None else torch.as_tensor(weights)
        return target - rigid_align(q, torch.as_tensor(target), w, scale=False).apply(q).numpy()

    def rest_joint_residual(self, x: np.ndarray, rest: MappedRest) -> float:
        """Mean distance (metres) of the mapped rest joints, reposed on SMPL's bone directions, from
        ``scale * J(beta)`` after a rigid alignment, for ``x = (beta, scale)`` (11,)."""
        return float(np.linalg.norm(self._rest_distances(x, rest), axis=1).mean())

    def _fit_joints(self, rest: MappedRest, x0: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """(beta, scale) (11,) whose rest joints best match the skeleton's mapped rest joints.

        Minimises ``sum_m w_m |scale J_m(beta) - (R q_m(beta) + t)|^2 / tol^2 + (x - x0)^T S^-1 (x - x0)`` over
        ``x = (beta, scale)`` inside the bank's box (betas short of its edge), where ``q(beta)`` are the mapped
        joints reposed on SMPL's bone directions and ``(R, t)`` their weighted Kabsch alignment for each ``x``
        (variable projection), ``S = cov`` (plus a small ridge), ``w`` from ``config.joint_fit_weights`` and
        ``tol = config.joint_fit_tolerance_m``.
        """
        cfg, bank = self.config, self.bank
        weights = dict(cfg.joint_fit_weights)
        w = np.array([weights.get(JOINT_NAMES[j], 1.0) for j in rest.smpl])
        sqrt_w = np.sqrt(w)[:, None] / cfg.joint_fit_tolerance_m
        beta_edge = (1 - cfg.edge_fraction) * bank.config.beta_range
        lo = np.append(np.full(NUM_BETAS, -beta_edge), bank.config.scale_range[0])
        hi = np.append(np.full(NUM_BETAS, beta_edge), bank.config.scale_range[1])
        S = cov + 1e-4 * np.diag((hi - lo) ** 2 / 12.0)
        L_inv = np.linalg.inv(np.linalg.cholesky(S))

        population = 1.0 / cfg.joint_fit_beta_std if cfg.joint_fit_beta_std > 0 else 0.0

        def fun(x: np.ndarray) -> np.ndarray:
            return np.concatenate([(self._rest_distances(x, rest, w) * sqrt_w).ravel(), L_inv @ (x - x0),
                                   population * x[:NUM_BETAS]])

        from scipy.optimize import least_squares

        start = np.clip(x0, lo + 1e-9, hi - 1e-9)
        sol = least_squares(fun, start, bounds=(lo, hi), method="trf", max_nfev=cfg.joint_fit_max_evaluations)
        return sol.x

    def _refine(self, query: np.ndarray, x0: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """Refined (beta, scale) (11,) from the kernel mean ``x0`` (11,), posterior ``cov`` (11, 11), query (6,).

        Minimises ``|F(x) - query|^2 / tol^2 + (x - x0)^T S^-1 (x - x0)`` inside the bank's box, with
        ``S = cov`` (plus a small ridge) and ``tol = refine_tolerance_m``.
        """
        cfg, bank = self.config, self.bank
        lo = np.append(np.full(NUM_BETAS, -bank.config.beta_range), bank.config.scale_range[0])
        hi = np.append(np.full(NUM_BETAS, bank.config.beta_range), bank.config.scale_range[1])
        S = cov + 1e-4 * np.diag((hi - lo) ** 2 / 12.0)  # a few neighbours only: keep S full rank
        L_inv = np.linalg.inv(np.linalg.cholesky(S))
        T, D, tol = self.pair_template, self.pair_dirs, cfg.refine_tolerance_m

        def fun(x: np.ndarray) -> np.ndarray:
            f = features_and_jacobian(T, D, x[:NUM_BETAS], x[NUM_BETAS])[0]
            return np.concatenate([(f - query) / tol, L_inv @ (x - x0)])

        def jac(x: np.ndarray) -> np.ndarray:
            return np.concatenate([features_and_jacobian(T, D, x[:NUM_BETAS], x[NUM_BETAS])[1] / tol, L_inv])

        from scipy.optimize import least_squares

        start = np.clip(x0, lo + 1e-9, hi - 1e-9)
        sol = least_squares(fun, start, jac=jac, bounds=(lo, hi), method="trf", max_nfev=cfg.refine_max_evaluations)
        return sol.x
