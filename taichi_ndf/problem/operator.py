"""The displacement operator: a field composed with the boundary conditions.

    u(ξ) = compose(ξ, N(evaluation_points(ξ), c), t)      (u_k = φ_k N_k + g_k, Leibniz on jets)

`DisplacementOperator` is the one place that evaluates the chain field → boundary composition
and its reverse (boundary adjoint → field backward), and the one place that refuses what the
composition cannot do (a free pin with a conditioned field: the pin's value would differ per
sample). Any field of a registered field type (`taichi_ndf.problem.field_types`: what its
configuration asks of the composition, even ends or a pseudo-time factor, is a capability of
its entry) with `jets(points, conditioning)` / `backward(grad_jets)` /
`evaluate(points, conditioning)` works; the Jacobian with respect to a linear block of the
field's parameters is served for a dense block (the SIREN output layer: the same p functions at
every point) and for a local basis (k functions per point, e.g. a spline's nearby
coefficients), see `jacobian` and `local_jacobian`. They are per component: u_k depends on the
raw component k only, u_k along the boundary frame's axis k (the world axes unless the
boundary has a `frame`; `to_world`, `to_frame`, `blocks_to_frame` convert).

Shapes: ξ (N, 2); jets (N, 6, 3) [m]; with a free pin the raw field is evaluated at N + 1
points (the pin ξ₀ appended) and u = N(ξ) − N(ξ₀).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.problem.field_types import of_field


@dataclass
class LocalJacobian:
    """Jacobian of u (N, 6, 3) with respect to coefficients that multiply a per-point basis.

    own: (3, N, 6, k): own[c, n, :, j] = ∂u_c(ξ_n)/∂(coefficient of basis function j of point
        n) — the rows `index[n]` of the field's local basis at ξ_n.
    pin: (3, 6, k) or None: with a free pin, ∂u_c(ξ_n)/∂(coefficient of the pin's basis
        function j) — the same for every n; the pin's rows are `index[N]`.
    """

    own: torch.Tensor
    pin: torch.Tensor | None


def _even_ends(field) -> tuple:
    """The ends across which `field` is even by itself, per direction (its field type's
    capability, `FieldType.even_ends`: a spline's `config.even_ends`); none for no field."""
    if field is None or not of_field(field).even_ends:
        return ((), ())
    return field.config.even_ends


def _unfolded_for(field, boundary: BoundaryConditions | None) -> BoundaryConditions | None:
    even = _even_ends(field)
    if not any(even):
        return boundary
    planes = ((), ()) if boundary is None else boundary.fold.edge_ends
    if tuple(even) != planes:
        raise ValueError(f"the field is even across the ends {even} but the boundary's "
                         f"symmetry planes are at {planes} (per direction)")
    return boundary.unfolded()


class DisplacementOperator:
    """Displacement jets of `field` under `boundary` (None: u = the raw field, no conditions).

    field may be None for the composition alone (`raw_gradient`, `jacobian`, the refusals).
    A field even across the boundary's symmetry planes by itself (a spline whose
    `config.even_ends` are the planes' edges) is composed without folded coordinates; a field
    even across other edges is refused."""

    def __init__(self, field, boundary: BoundaryConditions | None):
        self.field = field
        self.boundary = _unfolded_for(field, boundary)
        self._last: tuple | None = None   # ξ, t and the pseudo-time factor of the last jets

    @property
    def frame(self) -> bool:
        """Whether the boundary's components refer to a frame other than the world axes: then
        the Jacobians (`jacobian`, `local_jacobian`) are per component along the frame's
        axes, and `to_world` / `to_frame` / `blocks_to_frame` turn them to world components."""
        return self.boundary is not None and self.boundary.frame is not None

    def to_world(self, local: torch.Tensor) -> torch.Tensor:
        """Vectors (…, 3) along the boundary frame's axes in world components."""
        return local if self.boundary is None else self.boundary.axes.to_world(local)

    def to_frame(self, world: torch.Tensor) -> torch.Tensor:
        """World vectors (…, 3), or gradients with respect to world components, along the
        boundary frame's axes."""
        return world if self.boundary is None else self.boundary.axes.to_frame(world)

    def blocks_to_frame(self, blocks: torch.Tensor) -> torch.Tensor:
        """Per-point Hessian blocks (n, 18, 18) with respect to world components, with respect
        to the boundary frame's (`ComponentFrame.blocks_to_frame`)."""
        return blocks if self.boundary is None else self.boundary.axes.blocks_to_frame(blocks)

    @property
    def free_pin(self) -> bool:
        return self.boundary is not None and self.boundary.free_pin is not None

    def refuse_free_pin(self, what: str, hint: str = "") -> None:
        """Raise ValueError if the boundary has a free pin, which `what` does not support."""
        if self.free_pin:
            raise ValueError(f"{what} does not support a free pin (pinned point, rotation = "
                             f"'free'){hint}")

    def evaluation_points(self, xi: torch.Tensor) -> torch.Tensor:
        """Where the raw field is evaluated for displacements at ξ (N, 2): (N, 2) or, with a
        free pin, (N + 1, 2)."""
        return xi if self.boundary is None else self.boundary.evaluation_points(xi)

    def _points(self, xi: torch.Tensor, conditioning: torch.Tensor | None) -> torch.Tensor:
        if conditioning is not None and self.free_pin:
            raise ValueError("a free pin (pinned point, rotation='free') does not support a "
                             "conditioned field (pseudo-time or material inputs)")
        return self.evaluation_points(xi)

    def _time_factor(self, conditioning: torch.Tensor | None) -> torch.Tensor | None:
        """A pseudo-time field's factor t (M, 1, 1) on its raw output (`FieldConfig.pseudo_time`:
        u(ξ, 0) = 0, the path starts at rest exactly); None for any other field."""
        if (conditioning is None or not of_field(self.field).pseudo_time
                or not self.field.config.pseudo_time):
            return None
        return conditioning[:, :1].reshape(-1, 1, 1)

    def _compose(self, xi: torch.Tensor, raw: torch.Tensor, t) -> torch.Tensor:
        return raw if self.boundary is None else self.boundary.compose(xi, raw, t=t)

    # -- jets and their reverse ------------------------------------------------------------
    def jets(self, xi: torch.Tensor, *, t: float | torch.Tensor = 1.0,
             conditioning: torch.Tensor | None = None) -> torch.Tensor:
        """Displacement jets u (N, 6, 3) [m] at ξ (N, 2); t: load factor of prescribed
        motions (one number or one per sample); conditioning: the field's extra inputs (N, k).
        Keeps what `backward` needs (the field's tape, ξ and t) until the next call."""
        raw = self.field.jets(self._points(xi, conditioning), conditioning)
        factor = self._time_factor(conditioning)
        if factor is not None:
            raw = raw * factor.to(raw.dtype)
        self._last = (xi, t, factor)
        return self._compose(xi, raw, t)

    def backward(self, grad_u_jets: torch.Tensor) -> None:
        """Fill the field's gradients from dL/du_jets (N, 6, 3) of the last `jets` call."""
        if self._last is None:
            raise RuntimeError("backward needs a preceding jets call")
        xi, t, factor = self._last
        grad = self.raw_gradient(xi, grad_u_jets, t=t)
        if factor is not None:
            grad = grad * factor.to(grad.dtype)
        self.field.backward(grad.to(self.field.parameters[0].dtype))

    def raw_gradient(self, xi: torch.Tensor, grad_u_jets: torch.Tensor,
                     t: float | torch.Tensor = 1.0) -> torch.Tensor:
        """dL/d(raw jets) at `evaluation_points(ξ)` (M, 6, 3) from dL/du_jets (N, 6, 3): the
        adjoint of the composition alone (e.g. virtual displacements of a raw basis)."""
        if self.boundary is None:
            return grad_u_jets
        return self.boundary.compose_adjoint(xi, grad_u_jets, t=t)

    def displacement(self, xi: torch.Tensor, *, t: float | torch.Tensor = 1.0,
                     conditioning: torch.Tensor | None = None) -> torch.Tensor:
        """Displacement u (N, 3) [m] at ξ (no tape kept: for outputs and probes)."""
        values = self.field.evaluate(self._points(xi, conditioning), conditioning)
        factor = self._time_factor(conditioning)
        if factor is not None:
            values = values * factor[:, 0].to(values.dtype)
        return self._compose(xi, jets.constant(values), t)[:, jets.VALUE]

    def prescribed(self, xi: torch.Tensor, *, t: float | torch.Tensor = 1.0,
                   dtype: torch.dtype | None = None) -> torch.Tensor:
        """Displacement jets (N, 6, 3) [m] at ξ of a zero raw field: the prescribed part g of
        u = φ N + g (zero without boundary conditions). u is affine in a linear field's
        parameters, so u = prescribed + jacobian · θ."""
        dtype = dtype or xi.dtype
        points = self.evaluation_points(xi)
        raw = torch.zeros(points.shape[0], jets.CHANNELS, 3, dtype=dtype, device=xi.device)
        return self._compose(xi.to(dtype), raw, t)

    # -- Jacobians with respect to a linear block of parameters ------------------------------
    def jacobian(self, xi: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
        """Jacobian (3, N, 6, p) of u at ξ with respect to θ_k when each raw component is
        N_k = basis · θ_k + (terms free of θ): basis (M, 6, p) are the jets of the same p
        functions at `evaluation_points(ξ)` (M = N, or N + 1 with a free pin)."""
        if self.boundary is None:
            return basis[None].expand(3, -1, -1, -1).clone()
        return self.boundary.compose_jacobian(xi.to(basis.dtype), basis)

    def local_jacobian(self, xi: torch.Tensor, basis: torch.Tensor) -> LocalJacobian:
        """Like `jacobian` for a local basis: basis (M, 6, k) are the jets at
        `evaluation_points(ξ)` of each point's own k basis functions (different coefficient
        rows per point), so the free pin's part is kept apart (`LocalJacobian`)."""
        n = xi.shape[0]
        own_basis = basis
        if self.free_pin:  # the pin's row set to zero: `own` then has no pin part
            own_basis = torch.cat((basis[:n], torch.zeros_like(basis[n:])))
        own = self.jacobian(xi, own_basis)
        if not self.free_pin:
            return LocalJacobian(own=own, pin=None)
        # u_c = ... − N_c(ξ₀) on the pin's free components: the pin part is the same at every
        # point, so evaluate it at one point with a zero own basis.
        only_pin = torch.cat((torch.zeros_like(basis[:1]), basis[n:]))
        pin = self.jacobian(xi[:1], only_pin)[:, 0]
        return LocalJacobian(own=own, pin=pin)

    def output_layer_jacobian(self, xi: torch.Tensor, *, t: float = 1.0,
                              conditioning: torch.Tensor | None = None
                              ) -> tuple[torch.Tensor, torch.Tensor]:
        """Displacement jets u (N, 6, 3) [m] of the current field and their Jacobian with
        respect to the field's output layer, shape (3, N, 6, width + 1): J[k, :, :, a] =
        ∂u_k/∂θ_k[a] with θ_k = (W_out[k, :], b_out[k]) (`field.output_layer()`); u_k does not
        depend on θ_l for l ≠ k. Needs a field with `last_features()` (the SIREN) and the
        world axes as the boundary's frame (in a tilted frame u_k depends on every θ_l)."""
        if self.frame:
            raise ValueError("the last-layer Newton solve does not support a boundary frame "
                             "(components along tilted axes mix the world components); use "
                             "Adam or the spline field (--field spline)")
        u = self.jets(xi, t=t, conditioning=conditioning)
        features = self.field.last_features()  # (6, M, width)
        m, width = features.shape[1], features.shape[2]
        basis = features.new_zeros(m, jets.CHANNELS, width + 1)
        basis[:, :, :width] = features.permute(1, 0, 2)
        basis[:, jets.VALUE, width] = 1.0  # the bias enters the value channel only
        basis *= self.field.config.output_scale
        factor = self._time_factor(conditioning)
        if factor is not None:
            basis *= factor.to(basis.dtype)
        return u, self.jacobian(xi.to(u.dtype), basis)
