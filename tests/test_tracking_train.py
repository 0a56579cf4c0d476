"""The tracker trainer's batch plumbing (smplik.tracking.train): batches drawn inline or by background worker
processes, moved whole to the network's device, and the network's deterministic pass following its input's
device (what lets ``--device cuda`` train on a GPU machine)."""

from __future__ import annotations

import dataclasses

import torch

from smplik.tracking.config import TrackingNetConfig
from smplik.tracking.data import WindowBatch
from smplik.tracking.network import TrackingNet, input_dim
from smplik.tracking.train import batch_stream, to_device


class _CountingSampler:
    """A stand-in WindowSampler: each batch's x holds one number drawn from its generator."""

    def __init__(self, generator: torch.Generator) -> None:
        self.generator = generator

    def sample(self) -> WindowBatch:
        v = torch.rand(1, generator=self.generator)
        fields = {f.name: v.clone() for f in dataclasses.fields(WindowBatch)}
        return WindowBatch(**fields)


def _first(stream, n: int) -> list[float]:
    return [float(next(stream).x) for _ in range(n)]


def test_inline_batches_follow_the_seed():
    a, b = _first(batch_stream(_CountingSampler, 5, 0), 4), _first(batch_stream(_CountingSampler, 5, 0), 4)
    assert a == b and len(set(a)) == 4
    assert a != _first(batch_stream(_CountingSampler, 6, 0), 4)


def test_worker_batches_are_distinct_streams_and_reproducible():
    a = sorted(_first(batch_stream(_CountingSampler, 5, 2), 6))
    b = sorted(_first(batch_stream(_CountingSampler, 5, 2), 6))
    assert a == b  # the same seed and worker count give the same batches (in some order)
    assert len(set(a)) == 6  # the two workers do not repeat each other's draws


def test_to_device_moves_every_field():
    batch = _CountingSampler(torch.Generator().manual_seed(0)).sample()
    moved = to_device(batch, torch.device("meta"))
    assert all(getattr(moved, f.name).device.type == "meta" for f in dataclasses.fields(WindowBatch))


def test_deterministic_pass_runs_on_the_inputs_device():
    """The meta device stands in for a GPU: a zero latent made on the CPU cannot meet it."""
    cfg = TrackingNetConfig(hidden=16, decoder=16, latent=4)
    net = TrackingNet(cfg).to("meta")
    x = torch.zeros(2, 5, input_dim(cfg), device="meta")
    out = net(x, torch.zeros(2, 13, device="meta"))
    assert out.device.type == "meta" and out.shape[:2] == (2, 5)
