"""Pseudo-time fields: one field u(ξ, t) for the whole quasistatic path.

The load factor t becomes an extra input of the network (one conditioning input of
`NeuralField`, range `TIME_RANGE`). Each training sample draws its own t (stratified in
[t_start, t_end]); its loads and the prescribed boundary motions are scaled by that t
(`ShellEnergy.evaluate(..., load_factor=t)`, `BoundaryConditions.compose(..., t=t)`). Π is a sum
over samples, so the training objective is the mean over t of Π(u(·, t); t), whose minimiser is
the equilibrium u*(·, t) at every t of the range: the quasistatic path, evaluable at any t.

The weighting over t is uniform: for a linear response the energy error of a displacement error
e is ½ eᵀKe at every t, so uniform weights ask for the same absolute accuracy along the path.
"""

from __future__ import annotations

import torch

from taichi_ndf.problem.sampling import SurfaceSamples, stratified_uniform

# Range of the pseudo-time input: the network sees 2t − 1 ∈ [−1, 1].
TIME_RANGE = (0.0, 1.0)
DEFAULT_FRAMES = 16  # trajectory frames of a pseudo-time field ([output] frames)
# Each point load enters the training samples this many times, with its own stratified t and
# 1/POINT_REPEATS of its force, so that its work is averaged over t like the area samples'.
POINT_REPEATS = 16


def conditioning(t: float | torch.Tensor, n: int, *, dtype: torch.dtype,
                 device: torch.device | str | None = None) -> torch.Tensor:
    """The field's conditioning input (n, 1) for one pseudo-time t or one per sample (n,)."""
    if isinstance(t, torch.Tensor):
        if t.shape != (n,):
            raise ValueError(f"pseudo-time per sample must have shape ({n},), got "
                             f"{tuple(t.shape)}")
        return t.to(dtype=dtype, device=device).reshape(n, 1)
    return torch.full((n, 1), float(t), dtype=dtype, device=device)


def samples_over_time(samples: SurfaceSamples, start: float, end: float,
                      generator: torch.Generator) -> tuple[SurfaceSamples, torch.Tensor]:
    """Samples of (ξ, t): the area samples each get a t in [start, end]; each point-load
    sample (weight 0, unscaled force) is repeated POINT_REPEATS times with its own t and
    1/POINT_REPEATS of its force. Returns the samples and t (N,)."""
    dtype, device = samples.xi.dtype, samples.xi.device
    area = samples.weight != 0
    points = ~area
    n_area, n_points = int(area.sum()), int(points.sum())
    t_area = stratified_uniform(n_area, start, end, generator, dtype=dtype, device=device)
    if n_points == 0:
        return samples, t_area
    r = POINT_REPEATS
    t_points = torch.stack([
        stratified_uniform(r, start, end, generator, dtype=dtype, device=device)
        for _ in range(n_points)]).reshape(-1)

    def expand(a: torch.Tensor) -> torch.Tensor:
        return torch.cat((a[area], a[points].repeat_interleave(r, dim=0)))

    out = SurfaceSamples(xi=expand(samples.xi), r_jets=expand(samples.r_jets),
                         weight=expand(samples.weight),
                         point_force=torch.cat((samples.point_force[area],
                                                samples.point_force[points]
                                                .repeat_interleave(r, dim=0) / r)))
    return out, torch.cat((t_area, t_points))


def frame_times(start: float, frames: int) -> list[float]:
    """`frames` evenly spaced pseudo-times from `start` to 1 (both included)."""
    if frames < 2:
        raise ValueError(f"a trajectory needs at least 2 frames, got {frames}")
    return [start + (1.0 - start) * k / (frames - 1) for k in range(frames)]
