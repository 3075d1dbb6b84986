"""Prescribed motions of the boundary: the displacement a prescribing constraint imposes on
its set at a pseudo-time (load factor) t, in world components, and the check of t."""

from __future__ import annotations

import math

import torch

from taichi_ndf import jets
from taichi_ndf.boundary.constraints import Constraint, RimRotation
from taichi_ndf.boundary.segments import rotations
from taichi_ndf.geometry import ReferenceSurface


def prescribed_motion(con: Constraint, surface: ReferenceSurface | None, xi: torch.Tensor,
                      t: float | torch.Tensor) -> torch.Tensor:
    """Jets (N, 6, 3) [m], world components, of the displacement `con` imposes at ξ (N, 2) at
    pseudo-time t (a float, or a tensor (N,) of one t per sample): a rim rotation's
    R(tθ)(r − p) + p − r (needs the surface), else t × its displacement, plus a turning
    handle's (R(t·turn) − I)(r − r_h) (`Handle.turn`; needs the surface)."""
    if isinstance(con, RimRotation):
        return rotation_motion(con.axis, con.angle, con.axis_point, surface, xi, t)
    d = torch.tensor(con.displacement, dtype=xi.dtype, device=xi.device)
    if isinstance(t, torch.Tensor):
        motion = jets.constant(t[:, None] * d)
    else:
        motion = jets.constant((t * d).expand(xi.shape[0], 3))
    turn = getattr(con, "turn", (0.0, 0.0, 0.0))
    if any(turn):
        held = torch.tensor([con.xi], dtype=torch.float64)
        point = surface.jets(held)[0, jets.VALUE].to(torch.float64).tolist()
        motion = motion + rotation_motion(turn, math.hypot(*turn), point, surface, xi, t)
    return motion


def rotation_motion(axis, angle: float, point, surface: ReferenceSurface, xi: torch.Tensor,
                    t: float | torch.Tensor) -> torch.Tensor:
    """Jets (N, 6, 3) [m] of (R(tθ) − I)(r − p) at ξ (N, 2): the displacement of the surface
    r(ξ) turned rigidly by θ = `angle` [rad] × t about the axis `axis` (3,) through `point`
    (3,) [m] (world components; t a float or one per sample (N,))."""
    p = torch.tensor(point, dtype=xi.dtype, device=xi.device)
    r = surface.jets(xi).to(xi.dtype)
    if isinstance(t, torch.Tensor):  # one rotation per sample: M_i = R(t_i θ) − I
        m = rotations(axis, t * angle) - torch.eye(3, dtype=xi.dtype, device=xi.device)
        motion = torch.einsum("nkj,nij->nki", r, m)
        motion[:, jets.VALUE] -= m @ p
        return motion
    turned = torch.tensor([t * angle], dtype=torch.float64)
    m = (rotations(axis, turned)[0] - torch.eye(3, dtype=torch.float64)).to(
        dtype=xi.dtype, device=xi.device)
    motion = r @ m.T
    motion[:, jets.VALUE] -= m @ p
    return motion


def pseudo_time(t: float | torch.Tensor, xi: torch.Tensor) -> float | torch.Tensor:
    """t checked: a finite float, or a finite tensor (N,) of xi's dtype (one t per sample)."""
    if isinstance(t, torch.Tensor):
        if t.shape != (xi.shape[0],):
            raise ValueError(f"pseudo-time t per sample must have shape ({xi.shape[0]},), got "
                             f"{tuple(t.shape)}")
        if not bool(torch.isfinite(t).all()):
            raise ValueError("pseudo-time t must be finite at every sample")
        return t.detach().to(dtype=xi.dtype, device=xi.device)
    t = float(t)
    if not math.isfinite(t):
        raise ValueError(f"pseudo-time t must be a finite number, got {t!r}")
    return t
