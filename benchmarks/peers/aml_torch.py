"""The PyTorch AML reference's training step, restated (not copied) from docs/reference/aml.md
§1–§3.

One step = fresh numpy batches (ellipse on-manifold rows, uniform box off-manifold rows, as the
reference draws them), g_k forward, per-row input gradients of the batch mean via
autograd.grad(create_graph=True), the hinged selfgrad + on-distance terms, the transversality
term against frozen earlier relations, and one Adam step. Used only to time the peer.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn


def relation_net(dim: int, width: int, depth: int = 3) -> nn.Module:
    layers, fan_in = [], dim
    for _ in range(depth):
        layers += [nn.Linear(fan_in, width), nn.Tanh()]
        fan_in = width
    return nn.Sequential(*layers, nn.Linear(fan_in, 1), nn.Tanh())


def ellipse_batch(rng: np.random.Generator, n: int) -> np.ndarray:
    t = rng.uniform(0, 2 * math.pi, n)
    return np.stack([math.sqrt(2) * np.cos(t), 2 * np.sin(t) - 1, np.sin(t) - 1], -1)


class ReferenceStep:
    """Callable running `steps` reference optimizer steps for relation g_{len(earlier)+1}."""

    def __init__(self, num_earlier: int, batch_size: int = 1024, device: str = "cpu", seed=0):
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        self.device, self.batch = torch.device(device), batch_size
        self.earlier = [relation_net(3, 4 * 2**j).to(self.device) for j in range(num_earlier)]
        for g in self.earlier:
            g.requires_grad_(False)
        self.g = relation_net(3, 4 * 2**num_earlier).to(self.device)
        self.opt = torch.optim.Adam(self.g.parameters(), lr=1e-4)

    def _grads(self, g, x, create_graph):
        y = g(x)
        (v,) = torch.autograd.grad(y.mean(), x, create_graph=create_graph)
        return y.squeeze(-1), v  # v: 1/B-scaled per-row input gradient (reference convention)

    def step(self):
        on_np = ellipse_batch(self.rng, self.batch)
        lo, hi = on_np.min(0), on_np.max(0)
        off_np = self.rng.uniform(lo, hi, on_np.shape)
        on = torch.tensor(on_np, dtype=torch.float32, device=self.device, requires_grad=True)
        off = torch.tensor(off_np, dtype=torch.float32, device=self.device)
        y_on, v = self._grads(self.g, on, True)
        y_off = self.g(off)
        norm = v.norm(dim=-1)
        loss = (1 - 100 * torch.clamp(norm, max=1e-4)).mean()
        loss = loss + torch.clamp(1e-3 * y_on.abs() / torch.clamp(norm, min=1e-15), min=0.05).mean()
        if self.earlier:
            prod = torch.ones_like(norm)
            for gj in self.earlier:
                _, u = self._grads(gj, on, False)
                cos = nn.functional.cosine_similarity(u, v, dim=-1, eps=1e-15)
                prod = prod * torch.sqrt(torch.clamp(1 - cos**2, min=1e-15))
            loss = loss + (1 - prod).mean()
        # The reference's stopping statistics, computed every step.
        top = torch.topk(y_on.abs(), self.batch // 5).values.mean()
        _ = bool(5 * top < y_off.abs().mean())
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()
        return loss.detach()

    def __call__(self, steps: int):
        for _ in range(steps):
            loss = self.step()
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        return loss
