"""Goodness of fit of a material/force estimate: does the model explain the observed shape?

The residuals r (metres: 3 coordinate differences per point with correspondence, one signed
distance per point of a point cloud) are compared with the observation noise σ per coordinate,
stated by the user (`--noise`) or estimated from the observation itself
(`estimated_noise`), together with the forward model's own error σ_m (the rms change of the
residuals between the last two grids or feature bases, `forward_model_error`: what a
discretised model may miss of a perfect observation): χ² = Σ r² / (σ² + σ_m²) on
dof = len(r) − (number of unknowns), its p-value P(χ²_dof ≥ χ²) (scipy), and the residual
rms per entry against σ.

Verdict: the model does not explain the data where p < `P_FAIL` and χ²/dof > `REDUCED_FAIL`:
the misfit is larger than the noise by more than chance (a wrong clamp, thickness or gravity in
the scene, an unknown that is not free, or a forward model too coarse for the noise level);
the second condition keeps a right model from failing on a many-thousand-dof test where the
noise is only estimated to a few per cent. Then no standard error means anything: the
estimate is the best fit of a model the data reject.

Estimated noise: at each observed point the plane through its `NEIGHBOURS` nearest observed
points (itself included; least squares) and the point's distance to it; for isotropic noise σ
the mean squared distance is σ² (k − 3)/k for k points (the plane takes 3 of k degrees of
freedom along the normal), so σ̂² = median(d²) / 0.455 × k/(k − 3) (the median of χ²₁ is
0.455: robust against the few points where the surface bends within the neighbourhood). The
surface's own curvature adds about (κ r²/2)² to σ̂² for a neighbourhood radius r, negligible
on observations sampled finely against the curvature radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.spatial import cKDTree

P_FAIL = 1e-3
REDUCED_FAIL = 1.5
NEIGHBOURS = 12
MEDIAN_CHI2_1 = 0.45493642311957283  # median of χ² with one degree of freedom


def estimated_noise(points: np.ndarray, neighbours: int = NEIGHBOURS) -> float:
    """σ̂ per coordinate [m] of an observed point set (M, 3) from its scatter about local
    planes (module docstring); 0 for fewer than neighbours + 1 points."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) <= neighbours:
        return 0.0
    _, index = cKDTree(points).query(points, k=neighbours)
    local = points[index]  # (M, k, 3)
    centred = local - local.mean(axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    normal = vt[:, -1]  # (M, 3): the least-squares plane's normal
    distance = np.einsum("mc,mc->m", centred[:, 0], normal)  # the point itself is index 0
    k = neighbours
    return float(math.sqrt(np.median(distance**2) / MEDIAN_CHI2_1 * k / (k - 3)))


@dataclass(frozen=True)
class GoodnessOfFit:
    """residual_rms: rms of the residual entries [m]; noise: σ per coordinate [m] and where it
    came from ("stated" / "estimated from the observation's scatter about local planes");
    model_error: the forward model's own error σ_m [m]; chi2, dof, reduced = χ²/dof,
    p_value; explains: False where the data reject the model."""

    residual_rms: float
    noise: float
    noise_source: str
    model_error: float
    chi2: float
    dof: int
    reduced: float
    p_value: float
    explains: bool

    def statement(self) -> str:
        """One line for the console and estimate.json."""
        verdict = ("consistent with the noise" if self.explains else
                   "the model does not explain the data")
        return (f"residual rms {self.residual_rms:.3g} m against noise {self.noise:.3g} m "
                f"({self.noise_source}) and forward-model error {self.model_error:.2g} m: "
                f"χ²/dof = {self.reduced:.3g} on {self.dof} dof, "
                f"p = {self.p_value:.2g}: {verdict}")

    def to_dict(self) -> dict:
        return {"residual_rms_m": self.residual_rms, "noise_m": self.noise,
                "noise_source": self.noise_source, "forward_model_error_m": self.model_error,
                "chi2": self.chi2, "dof": self.dof,
                "chi2_per_dof": self.reduced, "p_value": self.p_value,
                "explains_data": self.explains, "statement": self.statement()}


def goodness_of_fit(residuals: np.ndarray, unknowns: int, noise: float,
                    noise_source: str, model_error: float = 0.0) -> GoodnessOfFit:
    """χ² test of the residuals [m] (stacked over observations) of a fit with `unknowns` free
    parameters against the noise σ [m] per coordinate and the forward model's error σ_m [m]
    (module docstring)."""
    r = np.asarray(residuals, dtype=np.float64).ravel()
    dof = max(len(r) - unknowns, 1)
    rms = float(np.sqrt(np.mean(r**2))) if len(r) else 0.0
    variance = noise**2 + model_error**2
    if variance > 0:
        chi2 = float(r @ r) / variance
        p = float(stats.chi2.sf(chi2, dof))
    else:  # a noise-free observation: any residual is model error
        chi2 = math.inf if rms > 0 else 0.0
        p = 0.0 if rms > 0 else 1.0
    reduced = chi2 / dof
    explains = not (p < P_FAIL and reduced > REDUCED_FAIL)
    return GoodnessOfFit(rms, float(noise), noise_source, float(model_error), chi2, dof,
                         reduced, p, explains)


def forward_model_error(fits) -> float:
    """σ_m [m]: the rms change of the residual entries between the last two fits of an
    `OuterResult` (grids h and h/2, or two feature bases), 0 with one fit."""
    if len(fits) < 2:
        return 0.0
    change = np.asarray(fits[-1].residuals) - np.asarray(fits[-2].residuals)
    return float(np.sqrt(np.mean(change**2)))


def observation_noise(observations, stated: float | None) -> tuple[float, str]:
    """The noise σ [m] and its source: the stated one, else the largest estimate over the
    observations (`estimated_noise`)."""
    if stated is not None:
        return float(stated), "stated"
    sigma = max(estimated_noise(obs.points.numpy()) for obs in observations)
    return sigma, "estimated from the observation's scatter about local planes"
