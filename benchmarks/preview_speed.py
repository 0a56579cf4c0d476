"""Cost of ``scene animate --preview`` against the animation's own, on a GVHMR-layout clip of 537 frames.

The clip (``--frames``, default 537, the length of the GVHMR run of issue 32) is a walk written in GVHMR's
``hmr4d_results.pt`` layout (``smpl_params_global`` / ``smpl_params_incam`` dicts of (L, ...) tensors,
``K_fullimg``; GVHMR ``tools/demo/demo.py``). Timed, in one process with the shipped model loaded once:

* ``animate_s``: :func:`workflows.animation.animate_file` (read, clean, keyframes, effectors; BVH export), the
  animation's own time;
* ``gif_s`` / ``mp4_s``: :func:`workflows.animation_preview.write_preview` of the whole clip (3D view with floor);
* ``old_per_frame_s``: the previous preview's way (a new renderer per frame: :func:`workflows.previews.render_scene`
  at 480 x 360, the view refitted per frame) on ``--old-sample`` frames, per frame, and extrapolated to the clip
  (``old_extrapolated_s``; it also stopped at 300 frames).

Also CPU seconds of the process (``*_cpu_s``), which depend less on other load of a shared machine. Prints a
table and writes ``benchmarks/results/preview_speed.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _common import save  # noqa: E402


def write_walk(path: Path, frames: int, fps: float = 30.0) -> Path:
    """A walk (legs and arms swinging, 1.2 m/s along the body's facing, a slow turn) in GVHMR's layout."""
    from scipy.spatial.transform import Rotation

    t = np.arange(frames) / fps
    phase = 2 * np.pi * 0.9 * t
    aa = np.zeros((frames, 22, 3))
    heading = 0.4 * np.sin(2 * np.pi * t / (frames / fps))  # turns a little left and right
    aa[:, 0] = Rotation.from_euler("y", heading[:, None]).as_rotvec()
    aa[:, 1, 0], aa[:, 2, 0] = 0.5 * np.sin(phase), -0.5 * np.sin(phase)  # hips
    aa[:, 4, 0], aa[:, 5, 0] = 0.5 * (1 + np.sin(phase)), 0.5 * (1 - np.sin(phase))  # knees
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2  # arms down
    aa[:, 16, 0], aa[:, 17, 0] = 0.3 * np.sin(phase), -0.3 * np.sin(phase)
    speed = 1.2 * np.stack([np.sin(heading), np.zeros(frames), np.cos(heading)], 1)
    transl = np.cumsum(speed / fps, 0) + np.array([0.0, 0.9, 0.0])
    M = np.diag([1.0, -1.0, -1.0])
    cam_aa = aa.copy()
    cam_aa[:, 0] = Rotation.from_matrix(M @ Rotation.from_rotvec(aa[:, 0]).as_matrix()).as_rotvec()
    cam_t = transl @ M.T + np.array([0.0, 0.0, 6.0])

    def params(a: np.ndarray, tr: np.ndarray) -> dict:
        return {"body_pose": torch.tensor(a[:, 1:22].reshape(frames, 63), dtype=torch.float32),
                "global_orient": torch.tensor(a[:, 0], dtype=torch.float32),
                "transl": torch.tensor(tr, dtype=torch.float32), "betas": torch.zeros(frames, 10)}

    f = float(np.hypot(1280, 720))
    torch.save({"smpl_params_global": params(aa, transl), "smpl_params_incam": params(cam_aa, cam_t),
                "K_fullimg": torch.tensor([[f, 0, 640.0], [0, f, 360.0], [0, 0, 1.0]]).expand(frames, 3, 3).clone()},
               path)
    return path


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=537)
    parser.add_argument("--old-sample", type=int, default=20, help="frames drawn the previous way (per frame cost)")
    parser.add_argument("--name", default="preview_speed", help="results file benchmarks/results/NAME.json")
    args = parser.parse_args()
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    torch.set_num_threads(1)
    from smplik.solver import IKSolver
    from workflows.animation import AnimateConfig, animate_file
    from workflows.animation_io import scene_of
    from workflows.animation_preview import write_preview
    from workflows.previews import render_scene
    from workflows.recovery import RecoveryConfig

    solver = IKSolver.load()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        clip = write_walk(tmp / "hmr4d_results.pt", args.frames)
        config = AnimateConfig(recovery=RecoveryConfig(max_effectors=6, threshold=0.03))
        outputs, animate_s, animate_cpu = timed(lambda: animate_file(clip, tmp / "out", solver, fps=30.0,
                                                                     config=config))
        anim = outputs.animation
        gif, gif_s, gif_cpu = timed(lambda: write_preview(anim, tmp / "p.gif"))
        mp4, mp4_s, mp4_cpu = timed(lambda: write_preview(anim, tmp / "p.mp4"))
        sample = list(range(0, args.frames, max(1, args.frames // args.old_sample)))[:args.old_sample]
        _, old_s, old_cpu = timed(lambda: [render_scene(scene_of(anim, f), size=(480, 360),
                                                        directions=((0.0, 0.2, 1.0),), labels=False) for f in sample])
        gif_mb = (tmp / "p.gif").stat().st_size / 2**20
    old_per = old_s / len(sample)
    result = {"frames": args.frames, "keyframes": sum(len(t.keyframes) for t in anim.tracks),
              "animate_s": animate_s, "animate_cpu_s": animate_cpu, "gif_s": gif_s, "gif_cpu_s": gif_cpu,
              "gif_frames": len(gif.frames), "gif_mb": gif_mb, "mp4_s": mp4_s, "mp4_cpu_s": mp4_cpu,
              "mp4_frames": len(mp4.frames), "gif_over_animate": gif_s / animate_s,
              "gif_over_animate_cpu": gif_cpu / animate_cpu, "mp4_over_animate": mp4_s / animate_s,
              "old_sample_frames": len(sample), "old_per_frame_s": old_per, "old_per_frame_cpu_s": old_cpu / len(sample),
              "old_extrapolated_s": old_per * args.frames, "new_gif_per_frame_s": gif_s / args.frames,
              "load_average": os.getloadavg()}
    print(f"{args.frames} frames: animation {animate_s:.1f} s (cpu {animate_cpu:.1f}); GIF {gif_s:.1f} s "
          f"(cpu {gif_cpu:.1f}, {len(gif.frames)} frames, {gif_mb:.1f} MiB, x{gif_s / animate_s:.2f} the animation); "
          f"MP4 {mp4_s:.1f} s (x{mp4_s / animate_s:.2f}); previous way {old_per:.3f} s per frame "
          f"(~{old_per * args.frames:.0f} s for the clip) vs {gif_s / args.frames:.3f} s now; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"wrote {save(args.name, result)}")


if __name__ == "__main__":
    main()
