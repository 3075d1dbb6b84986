"""Boundary conditions that hold exactly by construction: u_c = φ_c N_c + g_c.

N is the raw network output, c = x, y, z. For each component, φ_c is the product of the
vanishing factors of the constraints acting on c (`taichi_ndf.boundary.vanishing`), so any N
satisfies the homogeneous conditions; g_c carries the prescribed displacements (handles,
moved edges, rotating rims). With several constraints on c, g_c blends the prescribed values
with weights that are 1 on one constraint's set and 0 on every other one:

    g_c = Σ_i g_i W_i / Σ_k W_k,    W_k = Π_{m ≠ k} Φ_m,

where the groups Φ are each prescribing constraint's factor and (if any) the product of the
factors of the constraints that hold their set at zero (linearly vanishing factors enter
squared, so every weight is positive off the sets). Because quadratically vanishing factors
also have zero gradient on their sets, g inherits the slope of each prescription there (a
rotating rim gets exactly the rigid rotation of its tangent plane). The blend is singular
only where the sets of two groups meet, so a prescribing constraint touching any other
constraint on the same component is refused as contradictory.

Free pin. A `PinnedPoint` with rotation="free" holds the position of one point ξ₀ but not the
slope there: u_c = N_c(ξ) − N_c(ξ₀) for its components (φ_c = 1, no band). A sheet hanging
from one point turns about it; with the slope held (φ ~ d², the default) the field can only
approach that rotation with an ever sharper layer around the pin (a point condition on the
slope is not a bounded functional on H² in 2-D, so it does not change the infimum of Π). The
field is then evaluated at the pin too: `evaluation_points(ξ)` appends ξ₀ to ξ, `compose`
takes the raw jets at those N + 1 points and `compose_adjoint` returns gradients for all of
them (the pin's row collects −Σ_i ∂/∂u_i). A free pin must be the only constraint.

Length scale. Every factor rises from 0 on its set to exactly 1 at distance ℓ and is 1 beyond,
with ℓ measured in normalised coordinates η = (ξ − lo)/(hi − lo) ∈ [0, 1]² (so a plate and a
cylinder's angle get comparable bands). The default ℓ = 0.1 is chosen because
- outside the band the field is not damped at all; the original Gaussian masks
  1 − exp(−d²/0.01) are below 0.98 up to 0.2 of the domain;
- inside the band N must follow u/φ, which varies on the scale ℓ: 0.1 of the extent is about
  one period of the first SIREN layer (ω₀ = 30 on inputs in [−1, 1]), so it is resolvable,
  while a smaller ℓ would make φ'' ~ 6/ℓ² amplify network noise in the bending strain;
- a pinned point or handle also holds the slope, over a patch of radius ℓ; 0.1 keeps that
  patch small. A handle with a `radius` holds a whole patch (a grip): its level is the
  squared distance to the patch's rim, so φ = 0 on the patch and the band starts at the rim.
  Pass `length` (globally or per constraint) to change it. Points and lines
  take ℓ in (0, 0.5) (their distance wraps on periodic domains); edges take any ℓ > 0, and
  ℓ ≥ 1 makes an edge's φ one polynomial over the whole domain, which suits solutions that
  vary on the domain's scale: the cutoff at distance ℓ leaves u/φ with a jump in its third
  derivative that smooth features fit poorly (docs/validation.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from taichi_ndf import jets
from taichi_ndf.boundary import vanishing
from taichi_ndf.boundary.constraints import (
    COMPONENTS,
    ClampedEdge,
    Constraint,
    Handle,
    HingedEdge,
    InteriorLine,
    PinnedPoint,
    RimRotation,
    SymmetryPlane,
)
from taichi_ndf.boundary.fold import Fold
from taichi_ndf.boundary.frame import ComponentFrame
from taichi_ndf.boundary.motions import prescribed_motion, pseudo_time
from taichi_ndf.boundary.resolution import (
    ResolvedConstraint,
    check_contradictions,
    check_symmetry_planes,
    resolve,
    to_eta,
)
from taichi_ndf.geometry import ParameterDomain, ReferenceSurface
from taichi_ndf.geometry.surface import IDENTITY_FRAME


class BoundaryConditions:
    """Exact boundary conditions on a parameter domain.

    constraints: `ClampedEdge`, `HingedEdge`, `PinnedPoint`, `Handle`, `InteriorLine`,
        `RimRotation`, `SymmetryPlane` (see `taichi_ndf.boundary.constraints`); several may
        act on one component (their factors multiply).
    domain: the reference surface's parameter domain; periodic coordinates need no condition
        (the field is periodic by construction) and have no edges.
    surface: the reference surface; needed by `RimRotation` (positions r on the rim), a
        turning `Handle` (r on its patch) and
        `SymmetryPlane` (the edge must lie in the plane and cross it at right angles).
    length: default band width ℓ of the vanishing factors, a fraction of the domain extent,
        positive; below 0.5 for points and lines (see the module docstring for the choice of
        0.1).
    frame: (e_x, e_y, e_z), world directions of the axes the constraints' components (and a
        symmetry plane's `normal`) refer to; orthonormal, right-handed; None: the world axes.
        A tilted symmetry plane, or a clamp acting differently along and across a tilted
        edge, is stated in a frame whose axes are the plane's normal or the edge's directions.
        The composition holds per component in the frame, u = Fᵀ (φ ⊙ N + g) with F the
        matrix of rows e_x, e_y, e_z (N: the raw field's components along the frame's axes);
        prescribed displacements, rim axes and the result are world vectors.

    Raises ValueError naming the problem for a constraint outside the domain, an edge on a
    periodic coordinate, or a prescribed displacement whose set touches another constraint's
    set on the same component.
    """

    def __init__(
        self,
        constraints: Sequence[Constraint],
        domain: ParameterDomain,
        *,
        surface: ReferenceSurface | None = None,
        length: float = 0.1,
        frame=None,
    ):
        if not (isinstance(length, (int, float)) and math.isfinite(length) and length > 0):
            raise ValueError(
                f"length is a fraction of the domain extent, positive, got {length!r}"
            )
        if surface is not None and (
            surface.domain.bounds != domain.bounds or surface.domain.periodic != domain.periodic
        ):
            raise ValueError(
                "surface.domain does not match domain (bounds or periodic flags differ)"
            )
        self.constraints = tuple(constraints)
        self.domain = domain
        self.surface = surface
        self.length = float(length)
        free = [c for c in self.constraints
                if isinstance(c, PinnedPoint) and c.rotation == "free"]
        if free and len(self.constraints) > 1:
            raise ValueError(
                "a pinned point with rotation='free' must be the only constraint, got "
                f"{len(self.constraints)} constraints ({len(free)} free pin(s)); several free "
                "pins or a free pin with other constraints are not supported"
            )
        self.free_pin: PinnedPoint | None = free[0] if free else None
        self.axes = ComponentFrame(frame)
        self.frame = self.axes.rows  # None: the world axes
        # A free pin has no vanishing factor: it is resolved (checked) but not a term.
        self._terms = tuple(
            term for term in (resolve(c, domain, surface, self.length,
                                      self.frame or IDENTITY_FRAME)
                              for c in self.constraints)
            if term.constraint is not self.free_pin
        )
        check_contradictions(self._terms, domain)
        self.fold = Fold.of_edges(domain, [c.edge for c in self.constraints
                                           if isinstance(c, SymmetryPlane)])
        check_symmetry_planes(self._terms, domain)

    def unfolded(self) -> BoundaryConditions:
        """The same conditions without folded coordinates, for a field that is even across
        its symmetry planes by itself (a spline with `even_ends`)."""
        copy = object.__new__(BoundaryConditions)
        copy.__dict__.update(self.__dict__)
        copy.fold = Fold(self.domain, (frozenset(), frozenset()))
        return copy

    @property
    def narrowest_band(self) -> float | None:
        """The narrowest vanishing band ℓ of the constraints (a fraction of the domain extent;
        None without vanishing factors, e.g. a free pin alone): a discretisation must resolve
        the factors' ramps of that width."""
        return min((term.length for term in self._terms), default=None)

    # ---- composition -------------------------------------------------------------------

    def evaluation_points(self, xi: torch.Tensor) -> torch.Tensor:
        """Where the raw field is needed for `compose` at ξ (N, 2): ξ itself (the folded
        coordinates m(ξ) with a symmetry plane, `taichi_ndf.boundary.fold`), or with a free
        pin ξ followed by the pin ξ₀, shape (N + 1, 2)."""
        if self.free_pin is None:
            return self.fold.points(xi)
        pin = torch.tensor([self.free_pin.xi], dtype=xi.dtype, device=xi.device)
        return torch.cat((xi, pin))

    def compose(self, xi: torch.Tensor, raw_jets: torch.Tensor,
                t: float | torch.Tensor = 1.0) -> torch.Tensor:
        """Displacement jets u = φ N + g, shape (N, 6, 3) [m], from the raw network jets
        at `evaluation_points(ξ)` (N, or N + 1 with a free pin, × 6 × 3) for ξ (N, 2); t is
        the pseudo-time / load factor of prescribed motions: one number, or one per sample
        (tensor (N,), for a pseudo-time field). With a free pin u = N(ξ) − N(ξ₀)."""
        xi = xi.to(raw_jets.dtype)
        raw_jets, pin_jets = self._split(xi, raw_jets)
        raw_jets = self.fold.pullback(xi, raw_jets)
        factors = self._factors(xi)
        phi = self._vanishing(xi, factors)
        u = jets.product(phi, raw_jets) + self._prescribed(xi, factors, t)
        if pin_jets is not None:
            held = self._free_components()
            u[:, jets.VALUE, held] -= pin_jets[jets.VALUE, held]
        return self.axes.to_world(u)

    def compose_adjoint(
        self, xi: torch.Tensor, grad_u_jets: torch.Tensor, t: float | torch.Tensor = 1.0
    ) -> torch.Tensor:
        """Gradient with respect to the raw jets N at `evaluation_points(ξ)` (N, or N + 1 with
        a free pin, × 6 × 3) of a scalar whose gradient with respect to u = compose(ξ, N, t)
        is grad_u_jets (N, 6, 3); g does not depend on N, so t is unused."""
        xi = xi.to(grad_u_jets.dtype)
        grad_u_jets = self.axes.to_frame(grad_u_jets)
        grad = jets.product_adjoint(self._vanishing(xi, self._factors(xi)), grad_u_jets)
        grad = self.fold.pullback_adjoint(xi, grad)
        if self.free_pin is None:
            return grad
        pin = torch.zeros_like(grad[:1])
        held = self._free_components()
        pin[0, jets.VALUE, held] = -grad_u_jets[:, jets.VALUE, held].sum(dim=0)
        return torch.cat((grad, pin))

    def compose_jacobian(self, xi: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
        """Jacobian of u = compose(ξ, N) with respect to θ_k when each raw component is
        N_k = basis · θ_k: basis are the jets (N or N + 1, 6, p) of the p functions at
        `evaluation_points(ξ)`; returns (3, N, 6, p), J[k] = ∂u_k/∂θ_k (u is affine in N),
        u_k the component along the frame's axis k (`axes.to_world` turns J[k] θ_k to world
        components; with the world axes u_k is the world component)."""
        xi = xi.to(basis.dtype)
        basis, pin_basis = self._split(xi, basis)
        basis = self.fold.pullback(xi, basis)
        phi = self.vanishing_factor(xi)
        jacobian = torch.stack([jets.product(phi[:, :, k : k + 1], basis) for k in range(3)])
        if pin_basis is not None:
            for k in self._free_components():
                jacobian[k, :, jets.VALUE] -= pin_basis[jets.VALUE]
        return jacobian

    def _free_components(self) -> list[int]:
        return [COMPONENTS.index(c) for c in self.free_pin.components]

    def _split(self, xi: torch.Tensor, raw: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Raw jets at the samples (N, 6, k) and, with a free pin, at the pin (6, k)."""
        n = xi.shape[0]
        extra = 0 if self.free_pin is None else 1
        if raw.shape[0] != n + extra:
            if self.free_pin is None:
                raise ValueError(f"raw jets have {raw.shape[0]} rows for {n} points")
            raise ValueError(
                f"raw jets have {raw.shape[0]} rows for {n} points: with a free pin "
                "(pinned point, rotation='free') evaluate the field at "
                "evaluation_points(ξ), the points and the pin (N + 1 rows)"
            )
        if not extra:
            return raw, None
        return raw[:n], raw[n]

    def vanishing_factor(self, xi: torch.Tensor) -> torch.Tensor:
        """Jets of φ_c at ξ (N, 2), shape (N, 6, 3): 0 on each constrained set of component c
        (along the frame's axis c), 1 outside the bands of its constraints."""
        return self._vanishing(xi, self._factors(xi))

    def prescribed_displacement(self, xi: torch.Tensor,
                                t: float | torch.Tensor = 1.0) -> torch.Tensor:
        """Jets of g_c at ξ (N, 2), shape (N, 6, 3) [m]: the prescribed displacement at
        pseudo-time t (a number, or one per sample (N,)) on each prescribing constraint's set,
        0 on the other sets. World components."""
        return self.axes.to_world(self._prescribed(xi, self._factors(xi), t))

    def _factors(self, xi: torch.Tensor) -> list[torch.Tensor]:
        return [self._factor(term, xi) for term in self._terms]

    def _vanishing(self, xi: torch.Tensor, factors: list[torch.Tensor]) -> torch.Tensor:
        # Components held by the same constraints (the usual "xyz") share one product.
        products: dict[tuple[int, ...], torch.Tensor] = {}
        per_component = []
        for c in range(3):
            key = tuple(i for i, term in enumerate(self._terms) if c in term.components)
            if key not in products:
                products[key] = _product([factors[i] for i in key], xi)
            per_component.append(products[key])
        return torch.cat(per_component, dim=2)

    def _prescribed(self, xi: torch.Tensor, factors: list[torch.Tensor],
                    t: float | torch.Tensor) -> torch.Tensor:
        t = pseudo_time(t, xi)
        zero = xi.new_zeros(xi.shape[0], jets.CHANNELS, 1)
        if not any(term.prescribes for term in self._terms):
            return torch.cat([zero] * 3, dim=2)
        # Blend weights need factors that are positive off their sets: square the odd ones.
        factors = [
            vanishing.square(f) if term.linear else f
            for term, f in zip(self._terms, factors, strict=True)
        ]
        motions = [self._motion(term, xi, t) if term.prescribes else None for term in self._terms]
        blends: dict[tuple, list[torch.Tensor]] = {}
        per_component = []
        for c in range(3):
            prescribing = tuple(i for i, term in enumerate(self._terms) if c in term.prescribes)
            holding = tuple(
                i
                for i, term in enumerate(self._terms)
                if c in term.components and c not in term.prescribes
            )
            if (prescribing, holding) not in blends:
                blends[prescribing, holding] = self._blend(xi, factors, prescribing, holding)
            g = zero
            for blend, i in zip(blends[prescribing, holding], prescribing, strict=True):
                g = g + jets.product(blend, motions[i][..., c : c + 1])
            per_component.append(g)
        return torch.cat(per_component, dim=2)

    @staticmethod
    def _blend(xi, factors, prescribing, holding) -> list[torch.Tensor]:
        """Weights W_i / Σ_k W_k (jets (N, 6, 1)) of the prescribing constraints."""
        if not prescribing:
            return []
        groups = [factors[i] for i in prescribing]
        if holding:
            groups.append(_product([factors[i] for i in holding], xi))
        weights = [_product(groups[:k] + groups[k + 1 :], xi) for k in range(len(groups))]
        inverse_total = vanishing.reciprocal(sum(weights))
        return [jets.product(w, inverse_total) for w in weights[: len(prescribing)]]

    # ---- per-constraint pieces ---------------------------------------------------------

    def _eta(self, xi: torch.Tensor) -> tuple[torch.Tensor, tuple[float, float]]:
        """Normalised coordinates η (N, 2) and dη/dξ per coordinate."""
        (lo1, _), (lo2, _) = self.domain.bounds
        l1, l2 = self.domain.lengths
        eta = torch.stack(((xi[:, 0] - lo1) / l1, (xi[:, 1] - lo2) / l2), dim=1)
        return eta, (1.0 / l1, 1.0 / l2)

    def _wrap(self, delta: torch.Tensor) -> torch.Tensor:
        """Differences in η (N, 2) taken to the nearest periodic image."""
        delta = delta.clone()
        for k in range(2):
            if self.domain.periodic[k]:
                delta[:, k] -= torch.round(delta[:, k])
        return delta

    def _factor(self, term: ResolvedConstraint, xi: torch.Tensor) -> torch.Tensor:
        """Jets (N, 6, 1) of the vanishing factor of one constraint."""
        con, ell = term.constraint, term.length
        eta, scale = self._eta(xi)
        if isinstance(con, (ClampedEdge, HingedEdge, RimRotation, SymmetryPlane)):
            k = 0 if con.edge.startswith("xi1") else 1
            sign = 1.0 if con.edge.endswith("min") else -1.0
            value = eta[:, k] if sign > 0 else 1.0 - eta[:, k]
            d = (sign * scale[0] / ell, 0.0) if k == 0 else (0.0, sign * scale[1] / ell)
            s = vanishing.affine(value / ell, *d)
            if term.linear:
                return vanishing.linear_vanishing(s)
            return vanishing.quadratic_vanishing(vanishing.square(s))
        if isinstance(con, (PinnedPoint, Handle)):
            p = torch.tensor(to_eta(self.domain, con.xi), dtype=xi.dtype, device=xi.device)
            delta = self._wrap(eta - p)
            d1 = vanishing.affine(delta[:, 0], scale[0], 0.0)
            d2 = vanishing.affine(delta[:, 1], 0.0, scale[1])
            level = vanishing.square(d1) + vanishing.square(d2)
            if term.radius > 0:  # a held patch: the squared distance to its rim, 0 inside
                level = vanishing.beyond(vanishing.sqrt(level), term.radius)
            return vanishing.quadratic_vanishing(level / ell**2)
        if isinstance(con, InteriorLine):
            a, b = to_eta(self.domain, con.start), to_eta(self.domain, con.end)
            if con.extend:
                norm = math.hypot(b[0] - a[0], b[1] - a[1])
                n = (-(b[1] - a[1]) / norm, (b[0] - a[0]) / norm)
                delta = self._wrap(eta - torch.tensor(a, dtype=xi.dtype, device=xi.device))
                f = vanishing.affine(
                    (n[0] * delta[:, 0] + n[1] * delta[:, 1]) / ell,
                    n[0] * scale[0] / ell,
                    n[1] * scale[1] / ell,
                )
                if con.hinged:
                    return vanishing.linear_vanishing(f)
                return vanishing.quadratic_vanishing(vanishing.square(f))
            mid = torch.tensor(
                ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2), dtype=xi.dtype, device=xi.device
            )
            local = mid + self._wrap(eta - mid)
            return vanishing.quadratic_vanishing(
                vanishing.segment_level(local, a, b, scale) / ell**2
            )
        raise TypeError(f"unknown constraint type {type(con).__name__}")

    def _motion(self, term: ResolvedConstraint, xi: torch.Tensor,
                t: float | torch.Tensor) -> torch.Tensor:
        """Jets (N, 6, 3) [m] of the displacement a prescribing constraint imposes on its set
        at pseudo-time t (a float, or a tensor (N,) of one t per sample), along the frame's
        axes."""
        return self.axes.to_frame(prescribed_motion(term.constraint, self.surface, xi, t))


def _product(factors: list[torch.Tensor], xi: torch.Tensor) -> torch.Tensor:
    """Jet (N, 6, 1) of the product of scalar jets; 1 for an empty list."""
    out = jets.constant(xi.new_ones(xi.shape[0], 1))
    for f in factors:
        out = jets.product(out, f)
    return out
