"""The edit benchmark: single-limb edits from real motion, solved the way a scene edit is solved.

For each edit pair (:mod:`workflows.edit_benchmark.pairs`: frames ``t0 -> t1`` in which one wrist or ankle moved at
least 15 cm relative to the pelvis while the other limb ends and the head stayed within 3 cm):

1. recover frame ``t0``'s effectors with the workflow's recovery at its default settings
   (:func:`workflows.scene.recovery.recover_many`, :class:`~workflows.scene.recovery.RecoveryConfig`): the scene a user
   would hold, with its solved pose;
2. drag the limb end: its position effector (added when the recovery chose none) moves to the end's
   position in frame ``t1`` (expressed in frame ``t0``'s pelvis frame);
3. solve with each method (:data:`METHODS`) and compare with frame ``t1`` (same alignment).

Methods: ``smplik`` (the editor's drag today, :func:`workflows.scene.edits.drag_effector`: the dragged chain's stale
effectors relaxed to tolerance 1, then :func:`workflows.scene.edits.solve_edit`: the limb's two-bone IK with the
prior's elbow/knee swivel), ``smplik_chain`` (``solve_edit(analytic=False)``: the previous release's solve of
the same drag), ``smplik_drop`` (stale effectors deleted instead),
``smplik_before`` (the drag before this mechanism: every recovered effector kept exact), ``smplik_net``
(the network alone on that same set), ``optim`` (200 Adam steps of :class:`~smplik.benchmark.OptimizationIK`
started from the scene's pose, on the relaxed set of ``smplik``) and ``two_bone`` (the scene's pose with the
limb's two-bone analytic IK, :func:`smplik.limb_ik.two_bone_ik_pose`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX, NUM_BETAS, PARENTS, Gender
from smplik.effectors import Effector, pack_effectors
from smplik.kinematics import forward_kinematics
from smplik.pose import Pose
from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from workflows.edit_benchmark import pairs as pair_defs
from workflows.edit_benchmark.pairs import EditPair, JointRanges, edit_metrics, summarize
from workflows.scene.edits import RELAXED_TOLERANCE, SWIVEL_SHARE, drag_effector, solve_edit
from workflows.scene.recovery import RecoveryConfig, TargetPose, recover_many

RESULTS_FORMAT = "smplik-edit-benchmark"
RESULTS_VERSION = 1
METHOD_DESCRIPTIONS: dict[str, str] = {
    "smplik": f"smplik's drag (workflows.scene.edits): stale effectors of the dragged chain relaxed to tolerance "
              f"{RELAXED_TOLERANCE:g}; the limb posed on the scene's pose by two-bone IK with {SWIVEL_SHARE:g} of the "
              "learned prior's elbow/knee swivel; refined only where an exact effector is missed",
    "smplik_chain": "the previous release's drag solve (same relaxed effectors): the network's pose of the dragged "
                    "chain on the scene's pose, refined (the rest held 100x)",
    "smplik_relax": "the relaxed effectors solved afresh (network + refinement; the scene's pose not used)",
    "smplik_drop": "as smplik_relax, the stale effectors deleted instead of relaxed",
    "smplik_before": "the drag before workflows.scene.edits: every recovered effector kept exact, then the solver",
    "smplik_net": "the network alone (no refinement) on smplik_before's effectors",
    "optim": "Adam IK on SMPL + Gaussian pose prior, started from the scene's pose, on smplik's effectors",
    "two_bone": "the scene's pose with the limb's analytic two-bone IK (Unity TwoBoneIK, Blender chain 2)",
}
METHODS: tuple[str, ...] = tuple(METHOD_DESCRIPTIONS)
"""Every method, in the results' order."""
EDIT_FPS = 30.0
"""Frame rate the clips are resampled to before pairs are searched."""


@dataclass(frozen=True)
class EditClip:
    """One clip of real motion on the neutral beta = 0 body: pose (T, 24, 3) axis-angle, transl (T, 3)."""

    name: str
    subject: str
    fps: float
    pose: Tensor
    transl: Tensor


@dataclass(frozen=True)
class EditBenchmarkConfig:
    """Settings of :func:`run_edit_benchmark`."""

    pairs: pair_defs.EditPairConfig = pair_defs.EditPairConfig()
    """What counts as a single-limb edit."""
    max_pairs: int = 150
    """At most this many pairs (a seeded draw when more are found), so the default run takes minutes."""
    seed: int = 0
    """Seed of that draw."""
    optim_iterations: int = 200
    """Adam steps of the ``optim`` method."""
    recovery: RecoveryConfig = field(default_factory=RecoveryConfig)
    """Recovery of frame ``t0``'s effectors (the workflow's defaults)."""


def clips_from_dataset(dataset: Any, split: str) -> list[EditClip]:
    """The clips of one split of a pose cache (:class:`smplik.data.dataset.PoseDataset`)."""
    sub = dataset.subset(split)
    clips = []
    for cid in torch.unique(sub.clip_id).tolist():
        rows = torch.nonzero(sub.clip_id == cid)[:, 0]
        rows = rows[torch.argsort(sub.frame[rows])]
        subject = sub.subject_names[int(sub.subject_id[rows[0]])]
        clips.append(EditClip(sub.clip_names[cid], subject, sub.fps, sub.pose[rows], sub.transl[rows]))
    return clips


def clips_from_folder(folder: str | Path, *, preset: str = "cmu", fps: float = EDIT_FPS) -> list[EditClip]:
    """Every BVH clip under ``folder`` (held-out motion), retargeted to SMPL and resampled to ``fps``."""
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.dataset import find_sources, read_source, subsample_indices

    clips = []
    for src in find_sources(folder, "bvh"):
        seq = read_source(src, preset=preset, rig_mapper=auto_preset)
        idx = subsample_indices(len(seq.transl), seq.fps, min(fps, seq.fps))
        pose = np.concatenate([seq.global_orient[:, None], seq.body_pose], 1)[idx]
        clips.append(EditClip(src.name, src.subject, min(fps, seq.fps), torch.from_numpy(pose).float(),
                              torch.from_numpy(np.asarray(seq.transl)[idx]).float()))
    return clips


def clip_fk(clip: EditClip, J_rest: Tensor) -> tuple[Tensor, Tensor]:
    """(R_world (T, 24, 3, 3), p_world (T, 24, 3)) of a clip on rest joints J_rest (24, 3)."""
    return forward_kinematics(axis_angle_to_matrix(clip.pose.double()), J_rest.double(), clip.transl.double())


def select_pairs(clips: Sequence[EditClip], J_rest: Tensor, cfg: EditBenchmarkConfig) -> list[EditPair]:
    """All single-limb edit pairs of the clips, or a seeded draw of ``cfg.max_pairs`` (in clip order)."""
    pairs: list[EditPair] = []
    for c, clip in enumerate(clips):
        R_world, p_world = clip_fk(clip, J_rest)
        p_pelvis = pair_defs.pelvis_relative(p_world, R_world[:, 0])
        pairs += pair_defs.find_edit_pairs(p_pelvis, clip.fps, cfg.pairs, clip=c)
    if len(pairs) > cfg.max_pairs:
        rng = np.random.default_rng(cfg.seed)
        keep = np.sort(rng.choice(len(pairs), cfg.max_pairs, replace=False))
        pairs = [pairs[i] for i in keep]
    return pairs


@dataclass(frozen=True)
class EditProblems:
    """P edit problems (SMPL space, neutral beta = 0 body) ready for the methods.

    Attributes:
        pairs: the edit pairs; J_rest: (24, 3) rest joints.
        R_world_start: (P, 24, 3, 3) real frame t0; p_true, R_world_true, aa_true: the real frame t1 aligned to
            t0's pelvis: joints (P, 24, 3), global rotations, local axis-angle (P, 24, 3).
        targets: (P, 3) the dragged joint's target (its aligned t1 position).
        scene_effectors: per pair the recovered effectors of frame t0 (tolerance 0).
        scene_aa, scene_transl: (P, 24, 3), (P, 3) the recovered scene pose (what the user starts from).
        recovery_error_mm: (P,) the scene pose's mean joint error to the real frame t0.
        reachable: (P,) bool, the target is within the limb's two-bone reach from the scene pose's
            shoulder / hip.
    """

    pairs: tuple[EditPair, ...]
    clip_names: tuple[str, ...]
    J_rest: Tensor
    R_world_start: Tensor
    p_true: Tensor
    R_world_true: Tensor
    aa_true: Tensor
    targets: Tensor
    scene_effectors: tuple[tuple[Effector, ...], ...]
    scene_aa: Tensor
    scene_transl: Tensor
    recovery_error_mm: Tensor
    reachable: Tensor

    @property
    def ends(self) -> list[str]:
        return [p.end for p in self.pairs]

    def drag(self, *, tolerance: float | None = RELAXED_TOLERANCE, relax: bool = True) -> list[list[Effector]]:
        """Each pair's effector list after the drag (:func:`workflows.scene.edits.drag_effector`); ``relax=False``:
        the stale effectors stay as recovered."""
        out = []
        for effs, pair, target in zip(self.scene_effectors, self.pairs, self.targets, strict=True):
            new = Effector.position(pair.end, target.numpy())
            if relax:
                dragged, _, _ = drag_effector(effs, new, tolerance=tolerance)
            else:
                k = next((i for i, e in enumerate(effs) if e.joint == new.joint and e.type == new.type), None)
                dragged = effs + (new,) if k is None else effs[:k] + (new,) + effs[k + 1:]
            out.append(list(dragged))
        return out


def make_problems(clips: Sequence[EditClip], pairs: Sequence[EditPair], solver: Any,
                  recovery: RecoveryConfig | None = None, *,
                  progress: Callable[[int, int], None] | None = None) -> EditProblems:
    """Recover frame t0 of every pair and set up its drag (see the module docstring)."""
    if not pairs:
        raise ValueError("No single-limb edit pairs: nothing to benchmark.")
    betas = torch.zeros(NUM_BETAS)
    J_rest = solver.bodies.rest_joints(betas, torch.tensor(Gender.NEUTRAL.index)).double()
    aa0 = torch.stack([clips[p.clip].pose[p.t0] for p in pairs]).double()
    tr0 = torch.stack([clips[p.clip].transl[p.t0] for p in pairs]).double()
    aa1 = torch.stack([clips[p.clip].pose[p.t1] for p in pairs]).double()
    tr1 = torch.stack([clips[p.clip].transl[p.t1] for p in pairs]).double()
    R0, p0 = forward_kinematics(axis_angle_to_matrix(aa0), J_rest, tr0)
    R1, p1 = forward_kinematics(axis_angle_to_matrix(aa1), J_rest, tr1)
    R_true, p_true = pair_defs.align_to_pelvis(R1, p1, R0[:, 0], p0[:, 0])
    aa_true = aa1.clone()
    aa_true[:, 0] = matrix_to_axis_angle(R_true[:, 0])
    end_idx = torch.tensor([JOINT_INDEX[p.end] for p in pairs])
    rows = torch.arange(len(pairs))
    targets = p_true[rows, end_idx]
    targets_pose = [TargetPose(p0[i].float(), R0[i].float(), betas, Gender.NEUTRAL) for i in range(len(pairs))]
    results = recover_many(solver, targets_pose, recovery or RecoveryConfig(), progress=progress)
    scene_aa = torch.stack([torch.from_numpy(np.concatenate([r.pose.global_orient[None], r.pose.body_pose]))
                            for r in results]).double()
    scene_transl = torch.stack([torch.from_numpy(np.asarray(r.pose.transl)) for r in results]).double()
    _, p_scene = forward_kinematics(axis_angle_to_matrix(scene_aa), J_rest, scene_transl)
    root = torch.tensor([JOINT_INDEX[pair_defs.LIMB_ROOT[p.end]] for p in pairs])
    mid = torch.tensor(PARENTS)[end_idx]
    bones = (J_rest[mid] - J_rest[root]).norm(dim=-1) + (J_rest[end_idx] - J_rest[mid]).norm(dim=-1)
    reachable = (targets - p_scene[rows, root]).norm(dim=-1) <= bones - 1e-3
    return EditProblems(tuple(pairs), tuple(c.name for c in clips), J_rest, R0, p_true, R_true, aa_true,
                        targets, tuple(r.effectors for r in results), scene_aa, scene_transl,
                        (p_scene - p0).norm(dim=-1).mean(-1) * 1000.0, reachable)


def _poses_to_aa(poses: Sequence[Pose]) -> tuple[Tensor, Tensor]:
    aa = torch.stack([torch.from_numpy(np.concatenate([p.global_orient[None], p.body_pose])) for p in poses])
    return aa.double(), torch.stack([torch.from_numpy(np.asarray(p.transl)) for p in poses]).double()


def solve_method(name: str, problems: EditProblems, solver: Any, *, optim: Any = None) -> tuple[Tensor, Tensor]:
    """One method's poses: local axis-angle (P, 24, 3) and transl (P, 3), float64."""
    from smplik.refine import RefineConfig

    P = len(problems.pairs)
    betas = np.zeros((P, NUM_BETAS))
    if name in ("smplik", "smplik_chain"):
        previous = [Pose(aa[0], aa[1:], tr, np.zeros(NUM_BETAS), Gender.NEUTRAL)
                    for aa, tr in zip(problems.scene_aa.numpy(), problems.scene_transl.numpy(), strict=True)]
        moved = [JOINT_INDEX[e] for e in problems.ends]
        return _poses_to_aa(solve_edit(solver, problems.drag(), previous, moved, analytic=name == "smplik"))
    if name in ("smplik_relax", "smplik_drop", "smplik_before", "smplik_net"):
        lists = problems.drag(tolerance=None if name == "smplik_drop" else RELAXED_TOLERANCE,
                              relax=name in ("smplik_relax", "smplik_drop"))
        use = dataclasses.replace(solver, refine=RefineConfig(iterations=0)) if name == "smplik_net" else solver
        return _poses_to_aa(use.solve_batch(lists, betas=betas, gender=Gender.NEUTRAL))
    if name == "two_bone":
        from smplik.limb_ik import two_bone_ik_pose

        end_idx = torch.tensor([JOINT_INDEX[e] for e in problems.ends])
        J = problems.J_rest.expand(P, -1, -1)
        R_local = two_bone_ik_pose(axis_angle_to_matrix(problems.scene_aa), problems.scene_transl, J, end_idx,
                              problems.targets)
        return matrix_to_axis_angle(R_local), problems.scene_transl.clone()
    if name == "optim":
        from smplik.benchmark.evaluate import Prediction

        if optim is None:
            raise ValueError("The optim method needs an OptimizationIK (train poses for its prior).")
        eff = pack_effectors(problems.drag())
        init = Prediction(axis_angle_to_matrix(problems.scene_aa).float(), problems.scene_transl.float())
        pred = optim.solve(eff, torch.zeros(P, NUM_BETAS), torch.full((P,), Gender.NEUTRAL.index), init=init)
        return matrix_to_axis_angle(pred.R_local.double()), pred.transl.double()
    raise ValueError(f"Unknown edit method {name!r}; expected one of: {', '.join(METHODS)}.")


def evaluate_method(aa: Tensor, transl: Tensor, problems: EditProblems, ranges: JointRanges) -> Any:
    """:func:`workflows.edit_benchmark.pairs.edit_metrics` of one method's poses."""
    R_pred, p_pred = forward_kinematics(axis_angle_to_matrix(aa), problems.J_rest, transl)
    R_before, _ = forward_kinematics(axis_angle_to_matrix(problems.scene_aa), problems.J_rest, problems.scene_transl)
    return edit_metrics(p_pred=p_pred, R_world_pred=R_pred, aa_local_pred=aa, p_true=problems.p_true,
                        R_world_true=problems.R_world_true, aa_local_true=problems.aa_true,
                        R_world_before=R_before, aa_local_before=problems.scene_aa,
                        R_world_start=problems.R_world_start, ends=problems.ends,
                        targets=problems.targets, ranges=ranges)


def run_edit_benchmark(clips: Sequence[EditClip], solver: Any, ranges: JointRanges, *,
                       methods: Sequence[str] = METHODS, optim: Any = None,
                       cfg: EditBenchmarkConfig = EditBenchmarkConfig(),
                       progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Select pairs, recover, drag and solve with every method; the results document (JSON-ready).

    Results: ``methods[name]`` pooled figures (:func:`workflows.edit_benchmark.pairs.summarize`) plus ``by_limb``
    (arms / legs); ``pairs``: per pair its clip, frames, end, move and each method's MPJPE, collateral error,
    reach and contortions.
    """
    say = progress or (lambda _msg: None)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"Unknown edit method(s) {unknown}; expected some of: {', '.join(METHODS)}.")
    J_rest = solver.bodies.rest_joints(torch.zeros(NUM_BETAS), torch.tensor(Gender.NEUTRAL.index))
    pairs = select_pairs(clips, J_rest, cfg)
    say(f"{len(pairs)} single-limb edit pairs from {len(clips)} clips")
    problems = make_problems(clips, pairs, solver, cfg.recovery,
                             progress=lambda k, n: say(f"recovery step {k}/{n}"))
    arms = torch.tensor([p.end.endswith("wrist") for p in problems.pairs])
    out: dict[str, Any] = {"methods": {}, "by_limb": {}}
    per_pair: dict[str, Any] = {}
    for name in methods:
        aa, transl = solve_method(name, problems, solver, optim=optim)
        m = evaluate_method(aa, transl, problems, ranges)
        out["methods"][name] = summarize(m, problems.reachable)
        out["by_limb"][name] = {limb: summarize(dataclasses.replace(m, **{
            f.name: getattr(m, f.name)[sel] for f in dataclasses.fields(m)}), problems.reachable[sel])
            for limb, sel in (("arms", arms), ("legs", ~arms)) if bool(sel.any())}
        per_pair[name] = m
        s = out["methods"][name]
        say(f"{name:14s} MPJPE {s['mpjpe_mm']:6.1f} mm  collateral {s['collateral_mm']:6.1f} mm  reach "
            f"{s['reach_mm_median']:6.1f} mm (median)  contorted pairs {s['contorted_pairs']}")
    out["pairs"] = [{
        "clip": problems.clip_names[p.clip], "t0": p.t0, "t1": p.t1, "end": p.end, "move_m": round(p.move_m, 4),
        "reachable": bool(problems.reachable[i]), "recovered": [f"{e.joint_name}:{e.type.name.lower()}"
                                                                 for e in problems.scene_effectors[i]],
        "recovery_error_mm": round(float(problems.recovery_error_mm[i]), 2),
        **{name: {"mpjpe_mm": round(float(m.mpjpe_mm[i]), 2), "collateral_mm": round(float(m.collateral_mm[i]), 2),
                  "reach_mm": round(float(m.reach_mm[i]), 2), "contortions": int(m.contortions[i])}
           for name, m in per_pair.items()}} for i, p in enumerate(problems.pairs)]
    out["counts"] = {end: sum(p.end == end for p in problems.pairs) for end in pair_defs.LIMB_ENDS}
    out["recovery_error_mm"] = float(problems.recovery_error_mm.mean())
    return out


def save_figure(results: dict[str, Any], path: str | Path) -> Path:
    """Bar charts (MPJPE, collateral error, contorted pairs per method) as a PNG, written atomically."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from smplik.atomic import write_bytes_atomic

    names = list(results["methods"])
    figs = [("mpjpe_mm", "MPJPE (mm)"), ("collateral_mm", "collateral error (mm)"),
            ("reach_mm_median", "dragged joint off target (mm, median)"), ("contorted_pairs", "contorted pairs")]
    fig, axes = plt.subplots(1, len(figs), figsize=(4.2 * len(figs), 3.6))
    for ax, (key, title) in zip(axes, figs, strict=True):
        values = [results["methods"][n][key] for n in names]
        colors = ["tab:green" if n == "smplik" else "tab:gray" for n in names]
        ax.bar(range(len(names)), values, color=colors)
        ax.set_xticks(range(len(names)), names, rotation=40, ha="right", fontsize=8)
        ax.set_title(title, fontsize=10)
        for i, v in enumerate(values):
            ax.text(i, v, f"{v:.0f}" if key == "contorted_pairs" else f"{v:.1f}", ha="center", va="bottom",
                    fontsize=7)
    n = results["methods"][names[0]]["pairs"]
    fig.suptitle(f"Single-limb edits from real motion ({n} pairs, {results.get('split', '')})", fontsize=11)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_bytes_atomic(path, buf.getvalue())


def edit_benchmark(data: str | Path, solver: Any, *, split: str = "test", clips_folder: str | Path | None = None,
                   clips_preset: str = "auto", methods: Sequence[str] = METHODS,
                   cfg: EditBenchmarkConfig = EditBenchmarkConfig(),
                   progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The whole benchmark from a pose cache (``smplik data build``): ``split``'s clips, and the BVH clips of
    ``clips_folder`` (held-out motion, read with the retarget preset ``clips_preset``) as a second part
    ``held_out``; training ranges and the ``optim``
    prior from the cache's train split. Returns the results document (:func:`run_edit_benchmark` per part).

    Raises: FileNotFoundError / ValueError naming the cache or folder.
    """
    from smplik.benchmark.optimization import OptimizationIK, PosePrior
    from smplik.data.dataset import load_cache

    say = progress or (lambda _msg: None)
    dataset = load_cache(data)
    train = dataset.subset("train").pose
    if not len(train):
        raise ValueError(f"{data}: the cache has no train-split frames (needed for the joint ranges).")
    ranges = JointRanges.fit(train)
    optim = OptimizationIK(solver.bodies, PosePrior.fit(train), iterations=cfg.optim_iterations) \
        if "optim" in methods else None
    clips = clips_from_dataset(dataset, split)
    if not clips:
        raise ValueError(f"{data}: the cache has no {split}-split clips.")
    say(f"{split} split: {len(clips)} clips")
    doc: dict[str, Any] = {
        "format": RESULTS_FORMAT, "version": RESULTS_VERSION, "data": str(data), "split": split,
        "settings": {"pairs": dataclasses.asdict(cfg.pairs), "max_pairs": cfg.max_pairs, "seed": cfg.seed,
                     "optim_iterations": cfg.optim_iterations, "recovery": dataclasses.asdict(cfg.recovery),
                     "relaxed_tolerance": RELAXED_TOLERANCE, "solver": str(solver.source)},
        "method_descriptions": {m: METHOD_DESCRIPTIONS[m] for m in methods},
    }
    doc |= run_edit_benchmark(clips, solver, ranges, methods=methods, optim=optim, cfg=cfg, progress=say)
    if clips_folder is not None:
        held = clips_from_folder(clips_folder, preset=clips_preset)
        say(f"held-out folder {clips_folder}: {len(held)} clips")
        doc["held_out"] = {"folder": str(clips_folder), "preset": clips_preset} | run_edit_benchmark(
            held, solver, ranges, methods=methods, optim=optim, cfg=cfg, progress=say)
    return doc
