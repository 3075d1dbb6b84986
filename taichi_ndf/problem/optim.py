"""Adam with learning-rate schedules and optional gradient clipping.

Operates on lists of parameter and gradient tensors (e.g. ``NeuralField.parameters`` and
``.gradients``) that the caller fills; the update follows torch.optim.Adam exactly (bias
corrections, ε added to the corrected √v). Plain in-place torch ops, chosen by measurement on
the 2-core CPU: 0.15 / 0.4 / 0.9 ms per step for fields of 34 k / 265 k / 1.05 M parameters,
against 0.07 / 0.14 / 0.3 ms for torch.optim.Adam(fused=True) — both under 1 % of a field step
(40 / 250 / 800 ms), while this one needs no autograd leaves and clips without touching the
caller's gradients.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

SCHEDULES = ("constant", "exponential", "cosine")


@dataclass(frozen=True)
class AdamConfig:
    """lr: initial learning rate (1e-3 is Kingma & Ba's default).
    betas, eps: Adam's moment decay rates and denominator offset.
    schedule: "constant"; "exponential": lr · decay_rate^(step / decay_steps);
        "cosine": from lr down to min_lr over total_steps, then min_lr.
    grad_clip: if set, gradients are scaled so their global L2 norm is at most this.
    """

    lr: float = 1e-3
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8
    schedule: str = "constant"
    decay_rate: float = 0.1
    decay_steps: int = 1000
    total_steps: int = 1000
    min_lr: float = 0.0
    grad_clip: float | None = None

    def __post_init__(self):
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be a positive number, got {self.lr!r}")
        if len(self.betas) != 2 or not all(0 <= b < 1 for b in self.betas):
            raise ValueError(f"betas must be two numbers in [0, 1), got {self.betas!r}")
        object.__setattr__(self, "betas", tuple(float(b) for b in self.betas))
        if not self.eps > 0:
            raise ValueError(f"eps must be positive, got {self.eps!r}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if not 0 < self.decay_rate <= 1:
            raise ValueError(f"decay_rate must be in (0, 1], got {self.decay_rate!r}")
        for name in ("decay_steps", "total_steps"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not 0 <= self.min_lr <= self.lr:
            raise ValueError(f"min_lr must be in [0, lr], got {self.min_lr!r}")
        if self.grad_clip is not None and not self.grad_clip > 0:
            raise ValueError(f"grad_clip must be positive or None, got {self.grad_clip!r}")

    def learning_rate(self, step: int) -> float:
        """Learning rate of the update after ``step`` completed steps."""
        if self.schedule == "exponential":
            return self.lr * self.decay_rate ** (step / self.decay_steps)
        if self.schedule == "cosine":
            progress = min(step, self.total_steps) / self.total_steps
            return self.min_lr + 0.5 * (self.lr - self.min_lr) * (1 + math.cos(math.pi * progress))
        return self.lr


class Adam:
    """Adam on ``parameters`` (updated in place) driven by ``gradients`` (read only)."""

    def __init__(
        self,
        parameters: list[torch.Tensor],
        gradients: list[torch.Tensor],
        *,
        config: AdamConfig = AdamConfig(),
    ):
        if len(parameters) != len(gradients) or any(
            p.shape != g.shape for p, g in zip(parameters, gradients, strict=True)
        ):
            raise ValueError("parameters and gradients must be lists of tensors of equal shapes")
        self.parameters = parameters
        self.gradients = gradients
        self.config = config
        self.step_count = 0
        self.lr_scale = 1.0  # multiplies the schedule's rate; halved by a backoff (`backoff`)
        self.exp_avg = [torch.zeros_like(p) for p in parameters]
        self.exp_avg_sq = [torch.zeros_like(p) for p in parameters]

    @property
    def learning_rate(self) -> float:
        """Learning rate the next ``step`` will use: the schedule's, times ``lr_scale``."""
        return self.lr_scale * self.config.learning_rate(self.step_count)

    def gradient_norm(self) -> float:
        """Global L2 norm of the gradients."""
        return math.sqrt(sum(float(g.square().sum()) for g in self.gradients))

    def step(self) -> float:
        """One Adam update from the current gradients; returns the learning rate used."""
        lr = self.learning_rate
        beta1, beta2 = self.config.betas
        scale = 1.0
        if self.config.grad_clip is not None:
            norm = self.gradient_norm()
            if norm > self.config.grad_clip:
                scale = self.config.grad_clip / norm
        self.step_count += 1
        step_size = lr / (1 - beta1**self.step_count)
        root_correction = math.sqrt(1 - beta2**self.step_count)
        for p, g, m, v in zip(
            self.parameters, self.gradients, self.exp_avg, self.exp_avg_sq, strict=True
        ):
            m.mul_(beta1).add_(g, alpha=(1 - beta1) * scale)
            v.mul_(beta2).addcmul_(g, g, value=(1 - beta2) * scale * scale)
            denom = (v.sqrt() / root_correction).add_(self.config.eps)
            p.addcdiv_(m, denom, value=-step_size)
        return lr

    def state_dict(self) -> dict:
        """Step count, learning-rate scale and moment estimates (tensors, numbers only: safe
        for weights_only loads)."""
        return {
            "step": self.step_count,
            "lr_scale": self.lr_scale,
            "exp_avg": [m.detach().clone() for m in self.exp_avg],
            "exp_avg_sq": [v.detach().clone() for v in self.exp_avg_sq],
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict``; raises ValueError if the tensor shapes differ."""
        for key in ("exp_avg", "exp_avg_sq"):
            shapes = [tuple(t.shape) for t in state[key]]
            expected = [tuple(p.shape) for p in self.parameters]
            if shapes != expected:
                raise ValueError(f"optimiser state {key}: shapes {shapes} differ from {expected}")
        for ours, theirs in zip(
            self.exp_avg + self.exp_avg_sq, state["exp_avg"] + state["exp_avg_sq"], strict=True
        ):
            ours.copy_(theirs)
        self.step_count = int(state["step"])
        self.lr_scale = float(state.get("lr_scale", 1.0))  # absent in older checkpoints
