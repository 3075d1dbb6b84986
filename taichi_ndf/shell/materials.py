"""Constitutive laws of the shell (physics.md §3): energy density Ψ per unit reference area
[J/m²] as a function of the membrane strain ε_αβ and bending strain κ_αβ.

Each material is a frozen, validated dataclass. Ψ is linear in the material's stiffness
parameters (`stiffness_names`, `stiffness`, `with_stiffness`, `scaled`), which the inverse
package estimates. The Taichi side of each law (`taichi_ndf.shell.law_terms`) is a `ti.func`
returning the four *stiffness terms* T_k with Ψ = Σ_k S_k T_k for the law's kernel stiffness S
(see `law_stiffness`).

Laws:
- `LinearIsotropic` (Koiter / St. Venant–Kirchhoff shell): Ψ = ½ D ε:H:ε + ½ B κ:H:κ with
  H^{αβγδ} = ν a^{αβ} a^{γδ} + ½ (1 − ν)(a^{αγ} a^{βδ} + a^{αδ} a^{βγ}).
- `OrthotropicStVK`: membrane law Ψ_m = ½ a11 E₁₁² + a12 E₁₁E₂₂ + ½ a22 E₂₂² + G12 E₁₂² in the
  material frame of the reference surface (warp d₁ = a₁/|a₁|, weft d₂ = a₃ × d₁), integrated
  through the thickness with E(ζ) = ε + ζ κ by Simpson's rule, which is exact here: bending
  stiffness = membrane stiffness × h²/12. A woven fabric's bending is not its membrane
  stiffness times one h²/12 (yarns bend and slide), so the warp and weft may have their own
  equivalent thickness h₁, h₂ (`weft_thickness`): the material-frame bending strain K_ij
  enters as √(h_i h_j) K_ij, giving warp / weft bending a11 h₁²/12, a22 h₂²/12 and twist
  G12 h₁h₂/12 (`OrthotropicStVK.from_bending` sets h₁, h₂ from measured bending).
- `ClydeFabric` (Clyde et al. 2017): the same with η_k series, Ψ_m = ½ a11 η₁(E₁₁²) +
  a12 η₂(E₁₁E₂₂) + ½ a22 η₃(E₂₂²) + G12 η₄(E₁₂²), extended beyond the measured strain range by
  its second-order Taylor expansion (C¹, finite energy), Simpson (Ψ(−h/2) + 4Ψ(0) + Ψ(h/2))/6.

Note the convention of G12: it multiplies E₁₂² (tensor shear strain), so the isotropic law is
a11 = a22 = D, a12 = ν D, G12 = (1 − ν) D.
"""

import dataclasses
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch

from taichi_ndf.shell.fabrics import CLYDE_FABRICS, MEASURED_FABRICS
from taichi_ndf.shell.law_terms import KERNEL_STIFFNESS, MAX_SERIES_TERMS


def _finite(name: str, value) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value}")
    return value


def _positive(name: str, value, unit: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite positive number [{unit}], got {value}")
    return value


def _poisson(value) -> float:
    value = float(value)
    if not (math.isfinite(value) and -1.0 < value < 0.5):
        raise ValueError(f"poisson_ratio must be in (-1, 0.5), got {value}")
    return value


class Material(ABC):
    """Common interface of the constitutive laws (see module docstring)."""

    stiffness_names: ClassVar[tuple[str, ...]]
    law: ClassVar[str]  # name of the Taichi law ("linear_isotropic", "orthotropic", "clyde")
    areal_density: float

    @property
    def stiffness(self) -> tuple[float, ...]:
        """Current stiffness values, in the order of `stiffness_names`."""
        return tuple(getattr(self, name) for name in self.stiffness_names)

    def with_stiffness(self, **values: float):
        """A copy with some stiffness parameters replaced (names from `stiffness_names`)."""
        unknown = set(values) - set(self.stiffness_names)
        if unknown:
            raise ValueError(f"unknown stiffness parameter(s) {sorted(unknown)} for "
                             f"{type(self).__name__}; choose from {self.stiffness_names}")
        return dataclasses.replace(self, **values)

    def scaled(self, factor: float):
        """A copy with every stiffness multiplied by `factor` (> 0): Ψ scales by `factor`."""
        factor = _positive("factor", factor, "1")
        return self.with_stiffness(**{n: factor * getattr(self, n) for n in self.stiffness_names})

    @abstractmethod
    def small_strain_stiffness(self) -> tuple[float, float]:
        """Representative (membrane D [N/m], bending B [N·m]) at small strain (the dimensional
        scales of `taichi_ndf.problem.scaling`)."""

    @abstractmethod
    def law_parameters(self) -> list[float]:
        """Non-stiffness parameters of the Taichi law, packed in the order the law reads them."""

    @abstractmethod
    def law_stiffness(self, stiffness: torch.Tensor) -> torch.Tensor:
        """Per-sample kernel stiffness (N, 4) from per-sample stiffness values (N, K) in the
        order of `stiffness_names`."""


@dataclass(frozen=True)
class LinearIsotropic(Material):
    """Linear isotropic Koiter shell.

    membrane_stiffness D = E h / (1 − ν²) [N/m]; bending_stiffness B = E h³ / (12 (1 − ν²))
    [N·m]; poisson_ratio ν in (−1, 0.5); areal_density ρ_A [kg/m²].
    """

    membrane_stiffness: float
    bending_stiffness: float
    poisson_ratio: float
    areal_density: float

    stiffness_names: ClassVar[tuple[str, ...]] = ("membrane_stiffness", "bending_stiffness")
    law: ClassVar[str] = "linear_isotropic"

    def __post_init__(self):
        object.__setattr__(self, "membrane_stiffness",
                           _positive("membrane_stiffness", self.membrane_stiffness, "N/m"))
        object.__setattr__(self, "bending_stiffness",
                           _positive("bending_stiffness", self.bending_stiffness, "N·m"))
        object.__setattr__(self, "poisson_ratio", _poisson(self.poisson_ratio))
        object.__setattr__(self, "areal_density",
                           _positive("areal_density", self.areal_density, "kg/m²"))

    @classmethod
    def from_young(cls, young_modulus: float, poisson_ratio: float, thickness: float,
                   areal_density: float) -> "LinearIsotropic":
        """From Young's modulus E [Pa], Poisson's ratio ν, thickness h [m] and areal density
        ρ_A [kg/m²]."""
        e = _positive("young_modulus", young_modulus, "Pa")
        nu = _poisson(poisson_ratio)
        h = _positive("thickness", thickness, "m")
        d = e * h / (1 - nu * nu)
        return cls(membrane_stiffness=d, bending_stiffness=d * h * h / 12,
                   poisson_ratio=nu, areal_density=areal_density)

    @property
    def thickness(self) -> float:
        """Equivalent thickness h = √(12 B / D) [m]."""
        return math.sqrt(12 * self.bending_stiffness / self.membrane_stiffness)

    @property
    def young_modulus(self) -> float:
        """Equivalent Young's modulus E = D (1 − ν²) / h [Pa]."""
        return self.membrane_stiffness * (1 - self.poisson_ratio**2) / self.thickness

    def small_strain_stiffness(self) -> tuple[float, float]:
        return self.membrane_stiffness, self.bending_stiffness

    def law_parameters(self) -> list[float]:
        return [self.poisson_ratio]

    def law_stiffness(self, stiffness: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.pad(stiffness, (0, KERNEL_STIFFNESS - 2))


@dataclass(frozen=True)
class OrthotropicStVK(Material):
    """Orthotropic St. Venant–Kirchhoff membrane law in the warp/weft frame, bending by
    through-thickness integration.

    a11, a22: warp and weft stretch stiffness [N/m] (> 0); a12: coupling [N/m] with
    a12² < a11 a22; G12: shear stiffness [N/m] multiplying E₁₂² (> 0); thickness h₁ [m]
    (the warp's equivalent thickness; the one contact and the grid rule use);
    areal_density ρ_A [kg/m²]; weft_thickness h₂ [m] (default h₁).
    """

    a11: float
    a12: float
    a22: float
    G12: float
    thickness: float
    areal_density: float
    weft_thickness: float | None = None

    stiffness_names: ClassVar[tuple[str, ...]] = ("a11", "a12", "a22", "G12")
    law: ClassVar[str] = "orthotropic"

    def __post_init__(self):
        _check_woven_stiffness(self)
        object.__setattr__(self, "thickness", _positive("thickness", self.thickness, "m"))
        object.__setattr__(self, "areal_density",
                           _positive("areal_density", self.areal_density, "kg/m²"))
        weft = self.thickness if self.weft_thickness is None else self.weft_thickness
        object.__setattr__(self, "weft_thickness", _positive("weft_thickness", weft, "m"))

    @classmethod
    def from_bending(cls, a11: float, a12: float, a22: float, G12: float, warp_bending: float,
                     weft_bending: float, areal_density: float) -> "OrthotropicStVK":
        """From the membrane stiffness [N/m] and the measured warp and weft bending
        stiffness B₁, B₂ [N·m]: h₁ = √(12 B₁ / a11), h₂ = √(12 B₂ / a22)."""
        b1 = _positive("warp_bending", warp_bending, "N·m")
        b2 = _positive("weft_bending", weft_bending, "N·m")
        a11 = _positive("a11", a11, "N/m")
        a22 = _positive("a22", a22, "N/m")
        return cls(a11=a11, a12=a12, a22=a22, G12=G12, thickness=math.sqrt(12 * b1 / a11),
                   areal_density=areal_density, weft_thickness=math.sqrt(12 * b2 / a22))

    @property
    def warp_bending(self) -> float:
        """Bending stiffness about the weft axis, bending the warp yarns: a11 h₁²/12 [N·m]."""
        return self.a11 * self.thickness**2 / 12

    @property
    def weft_bending(self) -> float:
        """Bending stiffness bending the weft yarns: a22 h₂²/12 [N·m]."""
        return self.a22 * self.weft_thickness**2 / 12

    @classmethod
    def isotropic(cls, membrane_stiffness: float, poisson_ratio: float, thickness: float,
                  areal_density: float) -> "OrthotropicStVK":
        """The isotropic special case: a11 = a22 = D, a12 = ν D, G12 = (1 − ν) D."""
        d = _positive("membrane_stiffness", membrane_stiffness, "N/m")
        nu = _poisson(poisson_ratio)
        return cls(a11=d, a12=nu * d, a22=d, G12=(1 - nu) * d, thickness=thickness,
                   areal_density=areal_density)

    def small_strain_stiffness(self) -> tuple[float, float]:
        """The mean of warp and weft: ((a11 + a22) / 2, (warp + weft bending) / 2)."""
        return 0.5 * (self.a11 + self.a22), 0.5 * (self.warp_bending + self.weft_bending)

    def law_parameters(self) -> list[float]:
        return [self.thickness, self.weft_thickness]

    def law_stiffness(self, stiffness: torch.Tensor) -> torch.Tensor:
        return stiffness


Series = tuple[tuple[float, ...], tuple[float, ...]]  # (μ_j, α_j) of one η_k


@dataclass(frozen=True)
class ClydeFabric(Material):
    """Nonlinear anisotropic woven-fabric law of Clyde et al. 2017.

    a11, a12, a22, G12: small-strain stiffness [N/m] as in `OrthotropicStVK`;
    eta: four series (μ, α), η_k(x) = Σ_j (μ_j/α_j)((x + 1)^{α_j} − 1) with Σ_j μ_j = 1
        (so η_k′(0) = 1), at most 3 terms each, α_j ≠ 0;
    strain_limits: measured range (E₁₁max, E₂₂max, |E₁₂|max); the law is used for
        E₁₁ ∈ [0, E₁₁max], E₂₂ ∈ [0, E₂₂max], E₁₂ ∈ [−|E₁₂|max, |E₁₂|max] (tension only was
        measured) and continued outside by its second-order Taylor expansion at the nearest
        point of that box, which is C¹ and equals the small-strain law in compression;
    thickness h [m]; areal_density ρ_A [kg/m²];
    stiffness_scale: global factor on a11, a12, a22, G12 (the estimated stiffness).
    """

    a11: float
    a12: float
    a22: float
    G12: float
    eta: tuple[Series, Series, Series, Series]
    strain_limits: tuple[float, float, float]
    thickness: float
    areal_density: float
    stiffness_scale: float = 1.0

    stiffness_names: ClassVar[tuple[str, ...]] = ("stiffness_scale",)
    law: ClassVar[str] = "clyde"

    def __post_init__(self):
        _check_woven_stiffness(self)
        object.__setattr__(self, "thickness", _positive("thickness", self.thickness, "m"))
        object.__setattr__(self, "areal_density",
                           _positive("areal_density", self.areal_density, "kg/m²"))
        object.__setattr__(self, "stiffness_scale",
                           _positive("stiffness_scale", self.stiffness_scale, "1"))
        if len(self.strain_limits) != 3:
            raise ValueError(f"strain_limits must be (E11max, E22max, E12max), "
                             f"got {self.strain_limits!r}")
        limits = tuple(_positive(f"strain_limits[{k}]", v, "1")
                       for k, v in enumerate(self.strain_limits))
        object.__setattr__(self, "strain_limits", limits)
        if len(self.eta) != 4:
            raise ValueError(f"eta must hold 4 series (η₁ … η₄), got {len(self.eta)}")
        object.__setattr__(self, "eta", tuple(_check_series(k, s) for k, s in enumerate(self.eta)))

    def small_strain(self) -> OrthotropicStVK:
        """The orthotropic StVK law this one reduces to at small strain."""
        s = self.stiffness_scale
        return OrthotropicStVK(a11=s * self.a11, a12=s * self.a12, a22=s * self.a22,
                               G12=s * self.G12, thickness=self.thickness,
                               areal_density=self.areal_density)

    def small_strain_stiffness(self) -> tuple[float, float]:
        return self.small_strain().small_strain_stiffness()

    def law_parameters(self) -> list[float]:
        mu, alpha = [], []
        for m, a in self.eta:
            pad = MAX_SERIES_TERMS - len(m)
            mu += list(m) + [0.0] * pad
            alpha += list(a) + [1.0] * pad
        return [self.thickness, *self.strain_limits, *mu, *alpha]

    def law_stiffness(self, stiffness: torch.Tensor) -> torch.Tensor:
        base = stiffness.new_tensor([self.a11, self.a12, self.a22, self.G12])
        return stiffness[:, :1] * base


def _check_woven_stiffness(material) -> None:
    for name in ("a11", "a22", "G12"):
        object.__setattr__(material, name, _positive(name, getattr(material, name), "N/m"))
    a12 = _finite("a12", material.a12)
    if a12 * a12 >= material.a11 * material.a22:
        raise ValueError(f"a12 must satisfy a12² < a11·a22 (positive-definite law), got a12 = "
                         f"{a12} with a11 = {material.a11}, a22 = {material.a22}")
    object.__setattr__(material, "a12", a12)


def _check_series(k: int, series) -> Series:
    try:
        mu, alpha = series
        mu = tuple(_finite(f"eta[{k}] mu", v) for v in mu)
        alpha = tuple(_finite(f"eta[{k}] alpha", v) for v in alpha)
    except (TypeError, ValueError) as err:
        raise ValueError(f"eta[{k}] must be (mu values, alpha values): {err}") from err
    if not 1 <= len(mu) <= MAX_SERIES_TERMS or len(mu) != len(alpha):
        raise ValueError(f"eta[{k}] needs 1 to {MAX_SERIES_TERMS} terms with as many mu as "
                         f"alpha values, got {len(mu)} and {len(alpha)}")
    if any(a == 0 for a in alpha):
        raise ValueError(f"eta[{k}] alpha values must be non-zero, got {alpha}")
    if abs(sum(mu) - 1) > 1e-6:
        raise ValueError(f"eta[{k}] mu values must sum to 1 (so that η′(0) = 1), "
                         f"got sum {sum(mu)}")
    return mu, alpha


PRESETS = ("cloth", *CLYDE_FABRICS, *MEASURED_FABRICS)


def preset(name: str) -> Material:
    """A named material: "cloth" (linear isotropic, E = 5000 Pa, ν = 0.25, h = 1.2 mm,
    ρ_A = 0.144 kg/m²; kept for the tests and the SfT prior: softer in bending than 99 % of
    measured fabrics), the Clyde fabrics "canvas", "cotton", "silk" (`ClydeFabric`), or a
    fabric of `taichi_ndf.shell.fabrics.MEASURED_FABRICS` (orthotropic StVK with measured
    membrane and warp / weft bending; docs/scenes.md lists them with their sources)."""
    if name == "cloth":
        return LinearIsotropic.from_young(5000.0, 0.25, 1.2e-3, 0.144)
    if name in CLYDE_FABRICS:
        return ClydeFabric(**CLYDE_FABRICS[name])
    if name in MEASURED_FABRICS:
        fabric = MEASURED_FABRICS[name]
        return OrthotropicStVK.from_bending(**fabric.stiffness)
    raise ValueError(f"unknown material preset {name!r}; choose one of {PRESETS}")
