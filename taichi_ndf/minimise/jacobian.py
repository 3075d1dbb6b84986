"""The Jacobian of a local-support field's displacement jets at fixed points over the
coefficients acting there, stored once per distinct component.

J[c, q, :, a] = ∂u_c(ξ_q)/∂C[index[q, a], c], shape (3, N, ch, k) (`ComponentJacobian`): u_c =
φ_c N_c + g_c is the raw field times component c's boundary factor, so the components differ
only where their boundary factors do. Each distinct component is stored once, (N, ch, k), with
a map component → array: one array where every constraint holds all components alike (or
none), two for a cylinder whose diaphragms hold x and y only; and a component equal to the
basis jets themselves (φ_c = 1 everywhere: a free component) is the basis array, not a copy.
Consumers go through its methods (`apply`, `apply_transpose`, `component`, `rows`,
`channels`, `dense`), never a dense (3, …) tensor of all points.

`component_jacobian` builds it in chunks of points (`DisplacementOperator.local_jacobian` per
chunk: every entry is a pointwise product, so the chunks give the same numbers), never holding
the three components of all points at once.
"""

from __future__ import annotations

import torch

from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.shell.hessian import COMPONENTS

# Points per chunk of the build (bounds its (3, chunk, 6, k) temporaries: 38 MB at k = 16, f64).
BUILD_CHUNK = 16384


class ComponentJacobian:
    """J (3, N, ch, k) as `arrays` (each (N, ch, k)) and `slots` (3 ints): component c is
    arrays[slots[c]] (module docstring)."""

    def __init__(self, arrays: list[torch.Tensor], slots: tuple[int, int, int]):
        if len(slots) != COMPONENTS or sorted(set(slots)) != list(range(len(arrays))):
            raise ValueError(f"slots {slots} do not map 3 components onto {len(arrays)} arrays")
        shapes = {tuple(a.shape) for a in arrays}
        if len(shapes) != 1 or len(next(iter(shapes))) != 3:
            raise ValueError(f"arrays must share one shape (N, ch, k), got {shapes}")
        self.arrays, self.slots = list(arrays), tuple(slots)

    @classmethod
    def of(cls, jacobian: torch.Tensor) -> ComponentJacobian:
        """From a dense J (3, N, ch, k): components with equal entries stored once."""
        arrays: list[torch.Tensor] = []
        slots = []
        for c in range(COMPONENTS):
            same = next((s for s, a in enumerate(arrays) if torch.equal(a, jacobian[c])), None)
            if same is None:
                arrays.append(jacobian[c])
                same = len(arrays) - 1
            slots.append(same)
        return cls(arrays, tuple(slots))

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(3, N, ch, k) of the J it stands for."""
        return (COMPONENTS, *self.arrays[0].shape)

    @property
    def dtype(self) -> torch.dtype:
        return self.arrays[0].dtype

    @property
    def device(self) -> torch.device:
        return self.arrays[0].device

    def component(self, c: int) -> torch.Tensor:
        """J of component c, (N, ch, k) (the stored array: not to be written)."""
        return self.arrays[self.slots[c]]

    def rows(self, rows) -> ComponentJacobian:
        """J at a subset of the points (a slice, or indices: copies)."""
        return ComponentJacobian([a[rows] for a in self.arrays], self.slots)

    def channels(self, channels) -> ComponentJacobian:
        """J on a subset of the jet channels (a slice: views; a list or tensor: copies)."""
        return ComponentJacobian([a[:, channels] for a in self.arrays], self.slots)

    def dense(self) -> torch.Tensor:
        """J as one tensor (3, N, ch, k): a broadcast view where one array serves all three
        components, else a copy (for few points: pairs of coupled points, tests)."""
        if len(self.arrays) == 1:
            return self.arrays[0][None].expand(COMPONENTS, -1, -1, -1)
        return torch.stack([self.component(c) for c in range(COMPONENTS)])

    def apply(self, local: torch.Tensor) -> torch.Tensor:
        """U[n, j, c] = Σ_a J[c, n, j, a] C[n, a, c] of per-point coefficients C (N, k, 3);
        shape (N, ch, 3). A batched GEMV per component."""
        return torch.stack([torch.bmm(self.component(c), local[:, :, c, None])[..., 0]
                            for c in range(COMPONENTS)], dim=2)

    def apply_transpose(self, grad: torch.Tensor) -> torch.Tensor:
        """G[n, a, c] = Σ_j J[c, n, j, a] g[n, j, c] of g (N, ch, 3); shape (N, k, 3)."""
        return torch.stack([torch.bmm(grad[:, None, :, c], self.component(c))[:, 0]
                            for c in range(COMPONENTS)], dim=2)


def component_jacobian(operator: DisplacementOperator, xi: torch.Tensor, basis: torch.Tensor,
                       pin_basis: torch.Tensor | None = None, *, chunk: int = BUILD_CHUNK
                       ) -> tuple[ComponentJacobian, torch.Tensor | None]:
    """J (`ComponentJacobian`) of the operator's composition at ξ (N, 2) for a local basis
    whose jets at the points are `basis` (N, 6, k) (and at a free pin `pin_basis` (6, k)),
    and the pin's Jacobian (3, 6, k) (None without a free pin), from
    `operator.local_jacobian` in chunks of `chunk` points. Components are grouped by
    equality as the chunks come: a group whose members stop agreeing is split, the rows
    before the chunk copied from the group's array; a group that holds the basis jets stores
    nothing of its own."""
    count = xi.shape[0]
    # groups of {"basis", 0, 1, 2} equal on every row so far, each with its array
    groups: list[tuple[list, torch.Tensor]] = [(["basis", 0, 1, 2], basis)]
    pin = None
    for start in range(0, max(count, 1), chunk):
        stop = min(count, start + chunk)
        full = basis[start:stop]
        if pin_basis is not None:
            full = torch.cat((full, pin_basis[None]))
        local = operator.local_jacobian(xi[start:stop], full)
        if start == 0:
            pin = local.pin
        values = {"basis": basis[start:stop], **{c: local.own[c] for c in range(COMPONENTS)}}
        refined = []
        for members, array in groups:
            parts: list[list] = []
            for m in members:
                part = next((p for p in parts if torch.equal(values[p[0]], values[m])), None)
                if part is None:
                    parts.append([m])
                else:
                    part.append(m)
            # the part with the basis keeps the basis array; else the first keeps the array
            parts.sort(key=lambda p: "basis" not in p)
            for i, part in enumerate(parts):
                own = array
                if i > 0:  # a new array: the rows before this chunk were the group's
                    own = array.new_empty(array.shape)
                    own[:start] = array[:start]
                if "basis" not in part:
                    own[start:stop] = values[part[0]]
                refined.append((part, own))
        groups = refined
    arrays, slots = [], [0] * COMPONENTS
    for members, array in groups:
        components = [m for m in members if m != "basis"]
        if components:
            for c in components:
                slots[c] = len(arrays)
            arrays.append(array)
    return ComponentJacobian(arrays, tuple(slots)), pin
