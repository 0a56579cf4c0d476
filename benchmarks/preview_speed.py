"""Cost of ``scene animate --preview`` against the animation's own, on a GVHMR-layout clip of 537 frames.

The clip (``--frames``, default 537, the length of the GVHMR run of issue 32) is a walk with estimator-like jitter
written in GVHMR's ``hmr4d_results.pt`` layout (``smpl_params_global`` / ``smpl_params_incam`` dicts of (L, ...)
tensors, ``K_fullimg``; GVHMR ``tools/demo/demo.py``). Three runs of the ``smplik`` command, as a user runs it:

* ``animate``: ``smplik scene animate CLIP --out DIR`` (GVHMR: 30 frames/s assumed), the animation's own time
  (start-up, reading, cleaning, keyframe effectors, BVH export);
* ``gif`` / ``mp4``: the same with ``--preview x.gif`` / ``--preview x.mp4`` (3D view with floor; the GIF every
  2nd frame, at 15 frames/s, the MP4 every frame). The preview's cost is the difference to ``animate``.

Wall-clock seconds and CPU seconds of the child process (``*_cpu_s``: user + system, all its threads, among them
llvmpipe's, less dependent on the other load of a shared machine); ratios ``*_over_animate`` of both. Also the
previous preview's way (a new renderer per frame, :func:`workflows.scene.previews.render_scene` at 480 x 360, the
view refitted per frame), per frame on ``--old-sample`` frames, in this process. Prints a line and writes
``benchmarks/results/preview_speed.json``.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
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
    """A walk (legs and arms swinging, 1.2 m/s along the body's facing, a slow turn, jitter) in GVHMR's layout."""
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
    aa[:, 1:] += np.random.default_rng(0).normal(0.0, 0.02, (frames, 21, 3))  # estimator-like jitter
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


def run(args: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system of the child) of one ``smplik`` run."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "smplik.cli", *args], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    wall = time.perf_counter() - wall
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"smplik {' '.join(args)} failed:\n{done.stdout}{done.stderr}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=537)
    parser.add_argument("--old-sample", type=int, default=10, help="frames drawn the previous way (per frame cost)")
    parser.add_argument("--name", default="preview_speed", help="results file benchmarks/results/NAME.json")
    args = parser.parse_args()
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        clip = str(write_walk(tmp / "hmr4d_results.pt", args.frames))
        animate = run(["scene", "animate", clip, "--out", str(tmp / "a")])
        gif = run(["scene", "animate", clip, "--out", str(tmp / "g"), "--preview", str(tmp / "p.gif")])
        mp4 = run(["scene", "animate", clip, "--out", str(tmp / "m"), "--preview", str(tmp / "p.mp4")])
        import imageio.v2 as imageio

        gif_frames = len(imageio.mimread(tmp / "p.gif", memtest=False))
        mp4_frames = imageio.get_reader(tmp / "p.mp4").count_frames()
        gif_mb = (tmp / "p.gif").stat().st_size / 2**20
        from workflows.animation.files import load_animation, scene_of
        from workflows.scene.previews import render_scene

        anim = load_animation(tmp / "a" / "animation.json")
        sample = list(range(0, args.frames, max(1, args.frames // args.old_sample)))[:args.old_sample]
        render_scene(scene_of(anim, 0), size=(480, 360), directions=((0.0, 0.2, 1.0),), labels=False)  # warm
        wall, cpu = time.perf_counter(), time.process_time()
        for f in sample:
            render_scene(scene_of(anim, f), size=(480, 360), directions=((0.0, 0.2, 1.0),), labels=False)
        old_wall, old_cpu = (time.perf_counter() - wall) / len(sample), (time.process_time() - cpu) / len(sample)
    result = {"frames": args.frames, "keyframes": sum(len(t.keyframes) for t in anim.tracks),
              "animate_s": animate[0], "animate_cpu_s": animate[1],
              "gif_run_s": gif[0], "gif_run_cpu_s": gif[1], "gif_s": gif[0] - animate[0],
              "gif_cpu_s": gif[1] - animate[1], "gif_frames": gif_frames, "gif_mb": gif_mb,
              "mp4_run_s": mp4[0], "mp4_run_cpu_s": mp4[1], "mp4_s": mp4[0] - animate[0],
              "mp4_cpu_s": mp4[1] - animate[1], "mp4_frames": mp4_frames,
              "gif_over_animate": (gif[0] - animate[0]) / animate[0],
              "gif_over_animate_cpu": (gif[1] - animate[1]) / animate[1],
              "mp4_over_animate": (mp4[0] - animate[0]) / animate[0],
              "mp4_over_animate_cpu": (mp4[1] - animate[1]) / animate[1],
              "old_sample_frames": len(sample), "old_per_frame_s": old_wall, "old_per_frame_cpu_s": old_cpu,
              "old_extrapolated_300_frames_s": old_wall * min(300, args.frames),
              "load_average": os.getloadavg()}
    r = result
    print(f"{args.frames} frames, {r['keyframes']} keyframes: animate {r['animate_s']:.1f} s (cpu "
          f"{r['animate_cpu_s']:.1f}); GIF +{r['gif_s']:.1f} s (cpu +{r['gif_cpu_s']:.1f}; "
          f"x{r['gif_over_animate']:.2f} wall, x{r['gif_over_animate_cpu']:.2f} cpu; {gif_frames} frames, "
          f"{gif_mb:.1f} MiB); MP4 +{r['mp4_s']:.1f} s"
          f" (x{r['mp4_over_animate']:.2f} wall, x{r['mp4_over_animate_cpu']:.2f} cpu; {mp4_frames} frames); previous "
          f"way {old_wall:.2f} s per frame (cpu {old_cpu:.2f}); load average {os.getloadavg()[0]:.1f}")
    print(f"wrote {save(args.name, result)}")


if __name__ == "__main__":
    main()
