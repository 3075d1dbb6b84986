"""Which parameter combinations an estimate determines: eigen-analysis of the Fisher matrix.

Coordinates: log θ for positive unknowns (stiffness, density), θ / |group| for signed vector
unknowns (a force divided by the magnitude of its vector), so a standard deviation of 0.05 means
"5 %" for every unknown. A parameter whose marginal standard deviation exceeds
`UNDETERMINED_STD` is reported as undetermined and no value is printed for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Relative standard deviation above which a parameter or combination counts as undetermined.
UNDETERMINED_STD = 0.2


@dataclass
class Identifiability:
    """fisher: Fisher matrix in the normalised coordinates (p, p); eigenvalues (ascending) and
    eigenvectors (columns); std: marginal relative standard deviation per unknown;
    determined: per unknown; combinations: determined / undetermined eigen-directions as text
    with their relative standard deviation."""

    fisher: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    std: np.ndarray
    determined: list[bool]
    combinations: list[dict]

    def to_dict(self) -> dict:
        return {"fisher_eigenvalues": self.eigenvalues.tolist(),
                "fisher_eigenvectors": self.eigenvectors.T.tolist(),
                "relative_std": [finite_or_none(s) for s in self.std],
                "determined": self.determined,
                "combinations": self.combinations,
                "threshold_relative_std": UNDETERMINED_STD}


def finite_or_none(x: float) -> float | None:
    """x as a float for a JSON document, None when it is not finite (JSON has no inf/nan)."""
    return float(x) if math.isfinite(x) else None


def analyse(jacobian: np.ndarray, sigma2: float, names: list[str],
            positive: list[bool]) -> Identifiability:
    """Fisher F = JᵀJ / σ² of residuals with sensitivity `jacobian` (R, p) in normalised
    coordinates and noise variance `sigma2`."""
    fisher = jacobian.T @ jacobian / max(sigma2, 1e-300)
    eigenvalues, eigenvectors = np.linalg.eigh(fisher)
    tiny = eigenvalues.max(initial=0.0) * 1e-14
    inverse_values = np.where(eigenvalues > tiny, 1.0 / np.maximum(eigenvalues, tiny), np.inf)
    with np.errstate(invalid="ignore"):
        variance = (eigenvectors**2 * inverse_values).sum(axis=1)
    std = np.sqrt(np.nan_to_num(variance, nan=np.inf))
    combinations = []
    for value, vector in zip(eigenvalues, eigenvectors.T, strict=True):
        direction_std = 1.0 / math.sqrt(value) if value > tiny else math.inf
        combinations.append({"combination": _describe(vector, names, positive),
                             "relative_std": finite_or_none(direction_std),
                             "determined": bool(direction_std < UNDETERMINED_STD)})
    return Identifiability(fisher, eigenvalues, eigenvectors, std,
                           [bool(s < UNDETERMINED_STD) for s in std], combinations)


def _describe(vector: np.ndarray, names: list[str], positive: list[bool]) -> str:
    """An eigen-direction as a product of powers (log coordinates) or a weighted sum."""
    scale = vector[np.argmax(np.abs(vector))]
    parts = []
    for v, name, pos in zip(vector / scale, names, positive, strict=True):
        if abs(v) < 0.05:
            continue
        parts.append(f"{name}^{v:.2f}" if pos else f"{v:+.2f}·{name}")
    return " · ".join(parts) if all(positive) else " ".join(parts)
