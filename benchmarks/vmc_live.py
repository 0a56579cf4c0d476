"""Live tracking over VMC (``smplik track --live``): latency per frame and dropped frames at 60 and 90 Hz.

Setup, all on this machine over UDP on 127.0.0.1: a *peer* process (python-osc's builders) sends the trackers of a
synthetic walk (headset on the head, two controllers, a waist tracker; VMC ``/VMC/Ext/{Hmd,Con,Tra}/Pos`` in one
bundle per frame, Unity's frame) at a fixed rate, paced by the clock, without waiting for answers, and receives
the body bundles on its own socket; the live loop (:func:`workflows.tracking.live.run_vmc`, the 4-tracker model,
deterministic, causal foot locks) runs in this process on one thread (torch, OpenMP and numba at 1 thread).

Measured per rate (``--frames`` frames each):

* ``loop_ms``: receive -> send inside the loop: from the ``recv`` return of the datagram that completes a frame to
  the ``sendto`` return of its bundle (parse, convert, tracker step, bones, encode, send); p50 / p95 / max;
* ``end_to_end_ms``: the peer's send of frame i to its receipt of the i-th bundle (both UDP hops and the two
  processes' scheduling included); p50 / p95 / max;
* ``dropped``: frames sent minus bundles received by the peer (and the loop's own count of frames received).

Usage: ``python benchmarks/vmc_live.py [--frames 900] [--rates 60,90]`` -> ``benchmarks/results/vmc_live.json``.
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import threading
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _peer(frames: list[bytes], rate: float, to_main, from_main) -> None:  # noqa: ANN001 - multiprocessing queues
    """The VMC performer and marionette: send ``frames`` at ``rate`` to the loop, receive its bundles."""
    recv = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    recv.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    recv.bind(("127.0.0.1", 0))
    recv.settimeout(3.0)
    to_main.put(recv.getsockname()[1])
    live_addr = tuple(from_main.get(timeout=600))
    got: list[float] = []

    def receive() -> None:
        while True:
            try:
                recv.recv(65536)
            except TimeoutError:
                return
            got.append(time.perf_counter())

    thread = threading.Thread(target=receive, daemon=True)
    thread.start()
    send = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent: list[float] = []
    t0 = time.perf_counter() + 0.2
    for i, dgram in enumerate(frames):
        target = t0 + i / rate
        while (wait := target - time.perf_counter()) > 0:
            time.sleep(wait - 0.001 if wait > 0.002 else 0)
        send.sendto(dgram, live_addr)
        sent.append(time.perf_counter())
    thread.join(600)
    send.close()
    recv.close()
    to_main.put((sent, got))


def _walk_frames(n: int) -> list[bytes]:
    """The datagrams of ``n`` frames of a synthetic walk (a loop of 2 s), as a VMC performer sends them."""
    import torch
    from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
    from pythonosc.osc_message_builder import OscMessageBuilder

    from smplik.body_model import BodyModelSet
    from smplik.rotations import axis_angle_to_matrix_np, quat_wxyz_to_matrix
    from smplik.tracking import vmc
    from smplik.tracking.config import TRACKER_SETS
    from smplik.tracking.io import signals_from_motion

    T = 120
    t = np.arange(T) / 60.0
    aa = np.zeros((T, 24, 3))
    swing = 0.4 * np.sin(2 * np.pi * t)
    aa[:, 1, 0], aa[:, 2, 0] = swing, -swing
    aa[:, 4, 0], aa[:, 5, 0] = np.maximum(0, -swing), np.maximum(0, swing)
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2
    aa[:, 18, 1], aa[:, 19, 1] = -0.8, 0.8
    R = axis_angle_to_matrix_np(aa.reshape(-1, 3)).reshape(T, 24, 3, 3)
    transl = np.stack([0.3 * np.sin(np.pi * t), np.zeros(T), 0.3 * np.cos(np.pi * t)], -1)
    J = BodyModelSet.load().rest_joints(torch.zeros(10), torch.tensor(0)).double().numpy()
    sig = signals_from_motion(R, transl, J, TRACKER_SETS["4"], 60.0)
    out = []
    for i in range(n):
        k = i % T
        R_head = quat_wxyz_to_matrix(sig.rotations[k, 0])
        p_hmd, _ = vmc.head_to_hmd(sig.positions[k, 0], R_head)
        q_hmd = vmc.smpl_matrix_to_unity_quat(R_head)
        bundle = OscBundleBuilder(IMMEDIATELY)
        for address, serial, p, q in (("/VMC/Ext/Hmd/Pos", "HMD", p_hmd, q_hmd),
                                      ("/VMC/Ext/Con/Pos", "LEFT", sig.positions[k, 1], [0, 0, 0, 1.0]),
                                      ("/VMC/Ext/Con/Pos", "RIGHT", sig.positions[k, 2], [0, 0, 0, 1.0]),
                                      ("/VMC/Ext/Tra/Pos", "WAIST", sig.positions[k, 3], [0, 0, 0, 1.0])):
            m = OscMessageBuilder(address)
            m.add_arg(serial)
            for v in (*vmc.mirror_points(p), *q):
                m.add_arg(float(v))
            bundle.add_content(m.build())
        out.append(bundle.build().dgram)
    return out


def _ms(values: list[float] | np.ndarray) -> dict[str, float]:
    a = np.asarray(values) * 1e3
    if a.size == 0:
        return {}
    return {"p50": round(float(np.median(a)), 3), "p95": round(float(np.percentile(a, 95)), 3),
            "max": round(float(a.max()), 3), "mean": round(float(a.mean()), 3)}


def main() -> None:
    import multiprocessing as mp

    import torch

    sys.path.insert(0, str(REPO))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import save

    from smplik.tracking.config import TRACKER_SETS
    from workflows.tracking.live import LiveConfig, LiveStats, LiveTracker, open_tracker, run_vmc

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=900)
    parser.add_argument("--rates", default="60,90")
    args = parser.parse_args()
    torch.set_num_threads(1)
    frames = _walk_frames(args.frames)
    tracker = open_tracker(TRACKER_SETS["4"], betas=np.zeros(10), gender="neutral")
    ctx = mp.get_context("spawn")
    results = {}
    for rate in [float(r) for r in args.rates.split(",")]:
        to_main, from_main = ctx.Queue(), ctx.Queue()
        peer = ctx.Process(target=_peer, args=(frames, rate, to_main, from_main), daemon=True)
        peer.start()
        out_port = to_main.get(timeout=600)
        config = LiveConfig(vmc_out=("127.0.0.1", out_port), vmc_in=("127.0.0.1", 0), waist_serial="WAIST",
                            left_serial="LEFT", right_serial="RIGHT", max_frames=len(frames), idle_timeout_s=3.0)
        stats = LiveStats()
        run_vmc(LiveTracker(tracker), config, on_ready=lambda addr, q=from_main: q.put(addr), stats=stats)
        sent, got = to_main.get(timeout=600)
        peer.join(60)
        n = min(len(sent), len(got))
        e2e = np.asarray(got[:n]) - np.asarray(sent[:n])
        row = {"frames_sent": len(sent), "frames_received_by_loop": stats.frames_in, "bundles_sent": stats.bundles_out,
               "bundles_received": len(got), "dropped": len(sent) - len(got), "malformed": stats.ignored,
               "loop_ms": _ms(stats.latency_s), "end_to_end_ms": _ms(e2e if len(got) == len(sent) else []),
               "loop_ms_over_frame_period": round(float(np.mean(np.asarray(stats.latency_s) > 1.0 / rate)), 4)}
        results[f"{rate:g}hz"] = row
        print(f"{rate:g} Hz: {row}")
    path = save("vmc_live", {"setup": "peer process sends a synthetic walk's 4 VMC devices per frame (one bundle) at "
                                      "the rate, paced by the clock; the loop (4-tracker model, deterministic, "
                                      "causal foot locks) in one thread; UDP on 127.0.0.1",
                             "numba": tracker.kernels is not None, "load_average": list(os.getloadavg()),
                             "rates": results})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
