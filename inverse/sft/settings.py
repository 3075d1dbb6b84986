"""Settings of the shape-from-template tools: the spline prior's (`spline_prior`), the SIREN
reconstruction's (`siren_prior`) and the material estimate's from a video
(`material_from_video`), frozen dataclasses checked on construction.

Apart from their modules so that `ndf-sft --help` shows their defaults without importing torch
or Taichi (the material presets are imported where a check needs them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from taichi_ndf.shell.fabrics import FENG_2022_PERCENTILES, STANDARD_GRAVITY

if TYPE_CHECKING:
    from taichi_ndf.shell.materials import LinearIsotropic

__all__ = ["SplinePriorConfig", "ReconstructionConfig", "MaterialFromVideoConfig",
           "FABRIC_BENDING_LENGTH", "FABRIC_AREAL_DENSITY"]

# Bending length of measured fabrics (Feng et al., TOG 2022, 251 fabrics) [m] and areal
# density [kg/m²]: 5th, 50th and 95th percentile.
FABRIC_BENDING_LENGTH = FENG_2022_PERCENTILES["bending_length"]
FABRIC_AREAL_DENSITY = FENG_2022_PERCENTILES["areal_density"]
# Start value of an estimated membrane stiffness D [N/m] (measured: from 300 N/m the estimate
# reached 101.7 ± 4.3 N/m against a true 100 N/m).
MEMBRANE_START = 300.0
# What the material fit compares of each reconstructed vertex (MaterialFromVideoConfig.observed)
OBSERVED = ("3d", "ray")
# Where the flat size comes from without a stated one (MaterialFromVideoConfig.sheet_size_from)
SHEET_SIZE_FROM = ("template", "equilibrium")
# How the material fit weights the frames (MaterialFromVideoConfig.frame_weights)
FRAME_WEIGHTS = ("equal", "misfit")
# Where the material fit holds each frame's corners (MaterialFromVideoConfig.corners)
CORNERS = ("held", "fitted")


def _positive(name: str, value) -> None:
    if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value)
                                       and value > 0):
        raise ValueError(f"{name} must be positive and finite, got {value!r}")


@dataclass(frozen=True)
class SplinePriorConfig:
    """Weights and solver settings of the spline reconstruction.

    physics_weight: w_phys (0 switches the prior off); material: preset name of a linear
    isotropic material (ν and thickness set the prior's shape); membrane_factor: multiplies
    the material's membrane stiffness (inextensibility against bending); span_edges: knot span
    length in template mean edge lengths; degree: spline degree (3 or 4); quadrature_points:
    Gauss points per span and direction (None: degree + 1; 3 measured as accurate as 4 for
    cubics here at half the Hessian cost); silhouette_weight: w_sil; outline_weight: w_out,
    the visible border vertices held no deeper inside the mask than in frame 0
    (`inverse.sft.outline`; needs masks and w_sil > 0); silhouette_border_gap: the silhouette
    acts on a border vertex only where no tracked point lies within this many template mean
    edge lengths of it (0: on every border vertex; inf: on none; interior vertices always);
    silhouette_allowance: the silhouette term tolerates each border vertex as far outside the
    mask as the template lay outside mask 0 (`inverse.sft.silhouette.silhouette_allowance`);
    allowance_reach: that allowance only where a tracked point lies within this many template
    mean edge lengths of the vertex (None: everywhere);
    temporal_weight: w_temp;
    huber_px: reprojection error [px] beyond which the penalty grows linearly; max_iterations:
    Newton iterations per frame; tolerance: stop when the Newton decrement's predicted
    decrease λ²/2 is below this fraction of E; extrapolate: start each frame from the
    constant-velocity extrapolation of the coefficients (else from the last frame's);
    photometric_weight: w_photo, the texture compared with the frame at about
    photometric_points surface points on an image level blurred by photometric_sigma [px]
    (`inverse.sft.photometric`; 0 switches it off; needs the frames and the texture);
    cover_weight: w_cover, the mask's outline covered by the sheet's projected border
    (`inverse.sft.contour`; 0 switches it off; needs masks and w_sil > 0); cover_reach: the
    outline points within this many mean projected border edges of the border at the frame's
    start are compared, and Tukey's reach; cover_points: points per border edge;
    allowance_fade: the silhouette allowance fades as each vertex moves from its frame-0 pixel,
    to none at this many mean projected edge lengths of frame 0
    (`inverse.sft.silhouette.faded_allowance`; None: no fading); cover_slack: an outline
    point uncovered by less than this many mean projected border edges (beyond frame 0's
    allowance) is not charged by the cover term.
    """

    physics_weight: float = 1e-2
    material: str = "cloth"
    membrane_factor: float = 1.0
    span_edges: float = 3.0
    degree: int = 3
    quadrature_points: int | None = 3
    silhouette_weight: float = 1.0
    outline_weight: float = 1.0
    silhouette_border_gap: float = 0.0
    silhouette_allowance: bool = False
    allowance_reach: float | None = None
    temporal_weight: float = 0.1
    huber_px: float = 2.0
    max_iterations: int = 8
    tolerance: float = 1e-2
    extrapolate: bool = False
    photometric_weight: float = 0.0
    photometric_sigma: float = 2.0
    photometric_points: int = 4096
    cover_weight: float = 0.0
    cover_reach: float = 3.0
    cover_points: int = 6
    allowance_fade: float | None = None
    cover_slack: float = 0.0
    # Inertia (wip-sft12): frame_interval Δt [s] between frames adds the incremental
    # potential's inertia ½ ρ_A/Δt² ‖u − û‖²_M (consistent mass matrix of the spline over the
    # sheet's quadrature, ρ_A the material's), scaled like the prior (by w_phys / E_ref), û the
    # constant-velocity prediction 2 C_{t−1} − C_{t−2} of the coefficients (frame 1: C_0).
    # None: off. Needs physics_weight > 0.
    frame_interval: float | None = None

    def __post_init__(self):
        if self.frame_interval is not None:
            _positive("frame_interval", self.frame_interval)
            if self.physics_weight == 0:
                raise ValueError("frame_interval needs physics_weight > 0 (the inertia is "
                                 "scaled like the prior)")
        for name in ("physics_weight", "silhouette_weight", "outline_weight", "temporal_weight",
                     "photometric_weight"):
            if not 0 <= getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)}")
        for name in ("span_edges", "huber_px", "tolerance", "membrane_factor",
                     "photometric_sigma"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and positive, got {getattr(self, name)}")
        if not self.silhouette_border_gap >= 0:  # inf allowed: no border vertex
            raise ValueError(f"silhouette_border_gap must be >= 0, got "
                             f"{self.silhouette_border_gap}")
        if self.allowance_reach is not None and not 0 <= self.allowance_reach < math.inf:
            raise ValueError(f"allowance_reach must be finite and >= 0, got "
                             f"{self.allowance_reach}")
        if not isinstance(self.silhouette_allowance, bool):
            raise ValueError(f"silhouette_allowance must be True or False, got "
                             f"{self.silhouette_allowance!r}")
        if isinstance(self.photometric_points, bool) or not isinstance(
                self.photometric_points, int) or self.photometric_points < 1:
            raise ValueError(f"photometric_points must be a positive integer, got "
                             f"{self.photometric_points!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if not 0 <= self.cover_weight < math.inf:
            raise ValueError(f"cover_weight must be finite and >= 0, got {self.cover_weight}")
        if not 0 < self.cover_reach < math.inf:
            raise ValueError(f"cover_reach must be finite and positive, got {self.cover_reach}")
        if isinstance(self.cover_points, bool) or not isinstance(self.cover_points, int) or \
                self.cover_points < 1:
            raise ValueError(f"cover_points must be a positive integer, got "
                             f"{self.cover_points!r}")
        if not 0 <= self.cover_slack < math.inf:
            raise ValueError(f"cover_slack must be finite and >= 0, got {self.cover_slack}")
        if self.allowance_fade is not None and not 0 < self.allowance_fade < math.inf:
            raise ValueError(f"allowance_fade must be finite and positive, got "
                             f"{self.allowance_fade}")
        if self.degree not in (3, 4):
            raise ValueError(f"degree must be 3 or 4, got {self.degree}")
        from taichi_ndf.shell.materials import LinearIsotropic, preset

        if not isinstance(preset(self.material), LinearIsotropic):
            raise ValueError(
                f"material {self.material!r} is not linear isotropic; the prior uses a fixed "
                "linear material (e.g. 'cloth')")


@dataclass(frozen=True)
class ReconstructionConfig:
    """Weights and solver settings of the physics-regularised reconstruction.

    physics_weight: w_phys (0 switches the prior off); material: preset name of a linear
    isotropic material (its ν and thickness set the prior's shape, see the module docstring);
    silhouette_weight: w_sil [px² per px²]; temporal_weight: w_temp; huber_px: reprojection
    error [px] beyond which the penalty grows linearly; width, hidden_layers, omega0: the SIREN;
    output_scale: field output per network unit, as a fraction of √A; energy_samples: Monte-Carlo
    samples of Π_int per step; steps: Adam steps per frame; lr, min_lr: cosine learning-rate
    schedule per frame; init_steps: steps fitting the field to the initial guess of each frame
    (when one is given); seed: field initialisation and energy samples.
    """

    # No photometric term on this fit (`inverse.sft.photometric`): weight 0, not a setting;
    # nor the spline prior's outline, cover and silhouette-allowance terms or its membrane
    # factor: the one reconstruction (`inverse.sft.reconstruct`) reads them as these values.
    photometric_weight: ClassVar[float] = 0.0
    outline_weight: ClassVar[float] = 0.0
    silhouette_border_gap: ClassVar[float] = 0.0
    silhouette_allowance: ClassVar[bool] = False
    allowance_reach: ClassVar[float | None] = None
    allowance_fade: ClassVar[float | None] = None
    cover_weight: ClassVar[float] = 0.0
    membrane_factor: ClassVar[float] = 1.0

    physics_weight: float = 1e-2
    material: str = "cloth"
    silhouette_weight: float = 1.0
    temporal_weight: float = 1.0
    huber_px: float = 2.0
    width: int = 64
    hidden_layers: int = 3
    omega0: float = 10.0
    output_scale: float = 0.1
    energy_samples: int = 512
    steps: int = 100
    lr: float = 5e-4
    min_lr: float = 5e-5
    init_steps: int = 100
    seed: int = 0

    def __post_init__(self):
        for name in ("physics_weight", "silhouette_weight", "temporal_weight", "init_steps"):
            if not 0 <= getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)}")
        for name in ("huber_px", "omega0", "output_scale", "lr", "energy_samples", "steps",
                     "width", "hidden_layers"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and positive, got {getattr(self, name)}")
        if not 0 <= self.min_lr <= self.lr:
            raise ValueError(f"min_lr must be in [0, lr], got {self.min_lr}")
        from taichi_ndf.shell.materials import LinearIsotropic, preset

        if not isinstance(preset(self.material), LinearIsotropic):
            raise ValueError(
                f"material {self.material!r} is not linear isotropic; the prior uses a fixed "
                "linear material (e.g. 'cloth')"
            )


@dataclass(frozen=True)
class MaterialFromVideoConfig:
    """Settings of the estimate.

    areal_density: stated ρ_A [kg/m²] that turns B / (ρ_A g) into B (default: the median of
    measured fabrics); gravity: (3,) [m/s²] in camera coordinates (default: down the image);
    start_bending_length: c of the start value [m]; membrane_stiffness: D [N/m] held at this
    stated value, or None (default) to estimate D beside B from a start of
    `MEMBRANE_START` (a held D that is wrong was the largest error measured: −87 % in B at a
    held 300 N/m against a true 100 N/m; benchmarks/RESULTS.md, Material from video);
    poisson_ratio: ν; frames: number of frames used, evenly spread over the sequence (0: all);
    spans: the coarse grid (the fine grid halves its spans), or None (default) to choose it
    from the bending length — spans of at most 1.5 c, at least 7 and at most 16 per side,
    from the guess `start_bending_length`, then from the coarse and the final estimate
    (`material_grid`); degree: the splines' degree
    (3 or 4; default 4, cubic splines on the same grids measured undetermined);
    sheet_size: (W, H) [m] of the flat sheet, W along the held edge, when it is known (e.g.
    measured with a ruler), or None (default) for the template's grid-line lengths; band:
    the handles' band (fraction of the domain); fps: frame rate of the video [1/s], for the
    quasi-static check; max_iterations: outer Levenberg–Marquardt iterations per grid;
    observed: what of each reconstructed vertex the fit compares — "3d" (all three
    coordinates) or "ray" (the two directions perpendicular to its camera ray, i.e. what the
    image observed; the depth is left to the physics; `observations.ray_rows`);
    sheet_size_from: without `sheet_size`, the flat size from the template — "template" (its
    grid-line lengths as they are) or "equilibrium" (the template is the sheet's shape in
    frame 0, as SfT templates are: its lengths divided by the stretch of the fitted frame-0
    equilibrium, `material_from_video.unstretched_grid`; a planar template is the flat sheet
    and is taken as it is); frame_weights: how the frames' residuals are weighted — "misfit"
    (default: each frame by the inverse of the rms misfit of its coarse-grid fit, a frame the
    model explains worse, e.g. a reconstruction further from the truth, counts less;
    `material_from_video.misfit_weights`; measured through `ndf-sft`: c = 5 cm +25.7 → +12.5 %,
    c = 3 cm +24.0 → +3.3 %, the truth unchanged within 2.2 %) or "equal" (every vertex of
    every frame alike); corners: "fitted" (default: the held corners of every used frame whose
    corners are not the template's — SfT's frame 0 is the template, the given shape, and keeps
    them — are unknowns of the fit, 3 coordinates each,
    with their implicit-function Jacobian, `inverse.material.handles`: a reconstruction's
    corner error is no longer imposed on the frame's equilibrium, and B's standard error
    includes them) or "held" (each frame's equilibrium held exactly where the reconstruction
    puts its corners); quasi_static_limit: use only frames whose whole sheet accelerates by
    at most this fraction of g (second differences of the reconstruction at `fps`; frame 0
    always kept; `material_frames`), or None (default) to take every frame as an
    equilibrium."""

    areal_density: float = FABRIC_AREAL_DENSITY[1]
    gravity: tuple[float, float, float] = (0.0, STANDARD_GRAVITY, 0.0)
    start_bending_length: float = FABRIC_BENDING_LENGTH[1]
    membrane_stiffness: float | None = None
    poisson_ratio: float = 0.25
    frames: int = 8
    spans: tuple[int, int] | None = None
    degree: int = 4
    sheet_size: tuple[float, float] | None = None
    band: float = 0.1
    fps: float = 30.0
    max_iterations: int = 12
    observed: str = "3d"
    sheet_size_from: str = "equilibrium"
    frame_weights: str = "misfit"
    corners: str = "fitted"
    quasi_static_limit: float | None = None

    def __post_init__(self):
        for name in ("areal_density", "start_bending_length", "fps"):
            _positive(name, getattr(self, name))
        for name in ("membrane_stiffness", "quasi_static_limit"):
            if getattr(self, name) is not None:
                _positive(name, getattr(self, name))
        if self.sheet_size is not None:
            if len(self.sheet_size) != 2:
                raise ValueError(f"sheet_size must be (W, H) [m], got {self.sheet_size!r}")
            for value in self.sheet_size:
                _positive("sheet_size", value)
        g = np.asarray(self.gravity, dtype=np.float64)
        if g.shape != (3,) or not np.all(np.isfinite(g)) or not np.linalg.norm(g) > 0:
            raise ValueError(f"gravity must be a non-zero 3-vector [m/s²], got {self.gravity!r}")
        if isinstance(self.frames, bool) or not isinstance(self.frames, int) or \
                (self.frames != 0 and self.frames < 2):
            raise ValueError(f"frames must be 0 (all) or >= 2, got {self.frames!r}")
        if self.spans is not None and (
                len(self.spans) != 2 or any(int(s) != s or s < 1 for s in self.spans)):
            raise ValueError(f"spans must be two positive integers, got {self.spans!r}")
        if self.degree not in (3, 4):
            raise ValueError(f"degree must be 3 or 4, got {self.degree!r}")
        if not 0 < self.band < 0.5:
            raise ValueError(f"band must be in (0, 0.5), got {self.band!r}")
        if self.sheet_size_from not in SHEET_SIZE_FROM:
            raise ValueError(f"sheet_size_from must be one of {SHEET_SIZE_FROM}, got "
                             f"{self.sheet_size_from!r}")
        if self.frame_weights not in FRAME_WEIGHTS:
            raise ValueError(f"frame_weights must be one of {FRAME_WEIGHTS}, got "
                             f"{self.frame_weights!r}")
        if self.corners not in CORNERS:
            raise ValueError(f"corners must be one of {CORNERS}, got {self.corners!r}")
        if self.observed not in OBSERVED:
            raise ValueError(f"observed must be one of {OBSERVED}, got {self.observed!r}")

    @property
    def estimate_membrane(self) -> bool:
        """Whether D is estimated beside B (no membrane stiffness stated)."""
        return self.membrane_stiffness is None

    @property
    def start_material(self) -> LinearIsotropic:
        from taichi_ndf.shell.materials import LinearIsotropic

        g = float(np.linalg.norm(self.gravity))
        return LinearIsotropic(
            membrane_stiffness=(MEMBRANE_START if self.membrane_stiffness is None
                                else self.membrane_stiffness),
            bending_stiffness=self.areal_density * g * self.start_bending_length ** 3,
            poisson_ratio=self.poisson_ratio, areal_density=self.areal_density)
