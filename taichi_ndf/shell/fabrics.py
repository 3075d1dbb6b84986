"""Published fabric measurements behind the material presets (`materials.preset`).

Two sets, each cited where its numbers come from (docs/scenes.md, "Material presets", lists
every preset with its bending length):

- `CLYDE_FABRICS`: the nonlinear woven-fabric law of Clyde, Teran and Tamstorf, "Modeling and
  data-driven parameter estimation for woven fabrics", SCA 2017, with the parameters as used
  by NeuralClothSim (physics.md §3). Membrane measured; the bending follows from the
  thickness h (a × h²/12), which was not fitted to a bending test.
- `MEASURED_FABRICS`: Wang, Ramamoorthi and O'Brien, "Data-driven elastic models for cloth:
  modeling and measurement", ACM TOG 30(4), 71 (SIGGRAPH 2011), the measured database shipped
  with ARCSim (`materials/<name>.json`). Each file gives the areal density [kg/m²], the
  stretching stiffness at zero strain (first row, [k₁₁, k₁₂, k₂₂, k₃₃] in N/m; the other five
  rows are at 16.7 % stretch) and the bending stiffness [N·m] in the 0°, 45° and 90°
  directions at five curvatures (first column: zero curvature). ARCSim's energy is
  Ψ = ½ (2k₁₁ E₁₁² + 2·2k₁₂ E₁₁E₂₂ + 2k₂₂ E₂₂² + 2k₃₃ E₁₂²) (its `evaluate_stretching_sample`
  doubles the table), so in the convention of `OrthotropicStVK` a11 = 2 k₁₁, a12 = 2 k₁₂,
  a22 = 2 k₂₂, G12 = k₃₃; warp and weft bending are the 0° and 90° zero-curvature values. The
  law that fits them is the orthotropic StVK law with its own warp and weft bending
  thickness (`OrthotropicStVK.from_bending`): linear, so the strain stiffening these
  fabrics show (the 16.7 % rows: up to 2.3× for the wovens, 3–10× for the knit) is not
  modelled; the 45° bending is not used (the law's twist term is G12 h₁h₂/12).

For scale: Feng, Huang, Xu and Wang, "Learning-based bending stiffness parameter estimation by
a drape tester", ACM TOG 41(6) (SIGGRAPH Asia 2022), measured 251 fabrics: bending length
1.1 / 2.0 / 3.3 cm, areal density 0.041 / 0.197 / 0.487 kg/m² and B 1.2e-6 / 1.4e-5 /
1.1e-4 N·m at the 5th / 50th / 95th percentile (warp) (`FENG_2022_PERCENTILES`).
"""

from __future__ import annotations

from dataclasses import dataclass

STANDARD_GRAVITY = 9.81  # [m/s²], as in the shipped scenes

WANG_2011 = ("Wang, Ramamoorthi, O'Brien, Data-driven elastic models for cloth, ACM TOG 30(4) "
             "2011; ARCSim materials/{}.json")

# (5th, 50th, 95th percentile) of 251 fabrics, Feng et al. 2022 (module docstring).
FENG_2022_PERCENTILES = {
    "bending_length": (0.011, 0.020, 0.033),  # [m]
    "areal_density": (0.041, 0.197, 0.487),  # [kg/m²]
    "bending_stiffness": (1.2e-6, 1.4e-5, 1.1e-4),  # [N·m]
}


def bending_length(bending_stiffness: float, areal_density: float,
                   gravity: float = STANDARD_GRAVITY) -> float:
    """Peirce's bending length c = (B / (ρ_A g))^(1/3) [m] of a strip with bending stiffness
    B [N·m] and areal density ρ_A [kg/m²] (the cantilever test's measure, Peirce 1930)."""
    return (bending_stiffness / (areal_density * gravity)) ** (1 / 3)


@dataclass(frozen=True)
class MeasuredFabric:
    """One fabric of a published database.

    description: what it is (use, fibre content); source: the citation and the file;
    stiffness: the arguments of `OrthotropicStVK.from_bending` (a11, a12, a22, G12 [N/m],
    warp_bending, weft_bending [N·m], areal_density [kg/m²]).
    """

    description: str
    source: str
    stiffness: dict


def _wang(file: str, description: str, density: float, stretch: tuple[float, ...],
          warp_bending: float, weft_bending: float) -> MeasuredFabric:
    """A fabric of the Wang 2011 database from its file's numbers (module docstring)."""
    k11, k12, k22, k33 = stretch
    return MeasuredFabric(description, WANG_2011.format(file), dict(
        a11=2 * k11, a12=2 * k12, a22=2 * k22, G12=k33, warp_bending=warp_bending,
        weft_bending=weft_bending, areal_density=density))


# Verbatim from the files (first stretching row, first column of the 0° and 90° bending rows).
MEASURED_FABRICS = {
    "denim": _wang("11oz-black-denim", "11 oz denim (jeans), 99 % cotton 1 % spandex", 0.324,
                   (205.352005, 10.234077, 1013.88629, 53.387184), 64.196457e-6, 96.951576e-6),
    "cotton_polyester": _wang("royal-target", "woven trouser fabric, 65 % cotton 35 % polyester",
                              0.220, (2016.55456, 9.170511, 2034.97644, 104.759674),
                              125.409805e-6, 125.409805e-6),
    "polyester": _wang("white-dots-on-blk", "woven tablecloth fabric, 100 % polyester", 0.128,
                       (2002.08618, 0.345588, 2027.48559, 19.189022), 51.713814e-6,
                       31.282822e-6),
    "polyester_knit": _wang("camel-ponte-roma", "ponte roma double knit (jacket), 60 % "
                            "polyester 40 % rayon", 0.284,
                            (31.146198, -12.802702, 44.028667, 31.896357), 36.348366e-6,
                            37.157593e-6),
}

# Clyde et al. 2017 as used by NeuralClothSim, physics.md §3 (module docstring).
CLYDE_FABRICS = {
    "canvas": dict(
        areal_density=0.294, thickness=3.7e-4, a11=5.366, a12=2.683, a22=19.804, G12=2.009,
        strain_limits=(0.11, 0.067, 0.059),
        eta=(((1881.386, -1880.386), (22.619, 22.082)), ((1.0,), (1.0,)),
             ((-27.627, 70.532, -41.905), (212.682, 149.080, 69.532)),
             ((19.484, -1.805, -16.679), (2.1, 0.869, 1.132)))),
    "cotton": dict(
        areal_density=0.1036, thickness=2.53e-4, a11=15.557, a12=7.779, a22=25.004, G12=1.076,
        strain_limits=(0.14, 0.14, 0.063),
        eta=(((-352.871, 4.952, 348.919), (-63.206, -550.784, -54.525)), ((1.0,), (1.0,)),
             ((-2587.08, -285.733, 2873.813), (109.194, 102.720, 108.583)),
             ((8.362, -7.362), (5.973, 3.496)))),
    "silk": dict(
        areal_density=0.083, thickness=2.39e-4, a11=4.3, a12=4.971, a22=9.942, G12=0.57,
        strain_limits=(0.41, 0.34, 0.11),
        eta=(((61.769, -60.769), (-2.23, -115.578)), ((1.0,), (1.0,)),
             ((13.46, -12.46), (-2.612, -195.533)),
             ((3213.226, -3503.817, 291.591), (-2.926, -3.205, -6.401)))),
}
