"""Architecture of the neural deformation field."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields


def _finite_range(name: str, pair) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in pair)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (lo, hi) of numbers, got {pair!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"{name} must satisfy lo < hi with finite bounds, got {pair!r}")
    return lo, hi


def check_domain_and_periodic(config) -> None:
    """Validate a field configuration's `domain` (two finite (lo, hi) pairs, lo < hi) and
    `periodic` (two booleans) and store them as tuples of floats and booleans."""
    if len(config.domain) != 2:
        raise ValueError(f"domain must hold two (lo, hi) pairs, got {config.domain!r}")
    domain = tuple(_finite_range(f"domain[{i}]", p) for i, p in enumerate(config.domain))
    object.__setattr__(config, "domain", domain)
    if len(config.periodic) != 2 or not all(isinstance(p, bool) for p in config.periodic):
        raise ValueError(f"periodic must be two booleans, got {config.periodic!r}")
    object.__setattr__(config, "periodic", tuple(config.periodic))


def _lists(value):
    return [_lists(v) for v in value] if isinstance(value, (tuple, list)) else value


def _tuples(value):
    return tuple(_tuples(v) for v in value) if isinstance(value, (tuple, list)) else value


def config_to_dict(config) -> dict:
    """A field configuration (frozen dataclass) as a plain dict, tuples as lists."""
    return {key: _lists(value) for key, value in asdict(config).items()}


def config_from_dict(cls, data: dict):
    """The configuration of class `cls` from `config_to_dict`'s dict (lists back to tuples).

    Raises ValueError naming unknown keys (and whatever the configuration's checks raise)."""
    unknown = set(data) - {f.name for f in fields(cls)}
    if unknown:
        raise ValueError(f"unknown {cls.__name__} keys: {sorted(unknown)}")
    return cls(**{key: _tuples(value) for key, value in data.items()})


@dataclass(frozen=True)
class FieldConfig:
    """SIREN field u(ξ, c): surface coordinates ξ (and conditioning inputs c) -> displacement.

    width: neurons per hidden layer.
    hidden_layers: number of sine layers (hidden_layers - 1 width x width matrices).
    omega0: SIREN frequency ω₀, used in every sine layer as sin(ω₀ (W h + b)).
    out_dim: number of output components (3 for a displacement).
    domain: ((lo1, hi1), (lo2, hi2)), bounds of ξ¹ and ξ², mapped to the network's [-1, 1].
    periodic: per coordinate, whether it enters as (cos θ, sin θ), θ = 2π(ξ - lo)/(hi - lo),
        which makes the field exactly periodic with period hi - lo.
    conditioning: (lo, hi) range of each extra input (material parameter, pseudo-time),
        mapped to [-1, 1]; these inputs carry no ξ-derivatives.
    output_scale: factor on the linear output [m per network unit].
    pseudo_time: the one conditioning input is the pseudo-time t of a quasistatic path, and
        the displacement operator multiplies the field's output by t, so the path starts at
        rest exactly (u(ξ, 0) = 0, the reference: no load, no prescribed motion at t = 0).
    """

    width: int = 128
    hidden_layers: int = 3
    omega0: float = 30.0
    out_dim: int = 3
    domain: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 1.0), (0.0, 1.0))
    periodic: tuple[bool, bool] = (False, False)
    conditioning: tuple[tuple[float, float], ...] = ()
    output_scale: float = 1.0
    pseudo_time: bool = False

    def __post_init__(self):
        for name in ("width", "hidden_layers", "out_dim"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("omega0", "output_scale"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        check_domain_and_periodic(self)
        conditioning = tuple(
            _finite_range(f"conditioning[{i}]", p) for i, p in enumerate(self.conditioning)
        )
        object.__setattr__(self, "conditioning", conditioning)
        if self.pseudo_time not in (False, True) or (self.pseudo_time and len(conditioning) != 1):
            raise ValueError(f"pseudo_time needs exactly one conditioning input (t), got "
                             f"pseudo_time={self.pseudo_time!r} with {len(conditioning)}")

    @property
    def in_dim(self) -> int:
        """Number of network inputs: 1 or 2 per coordinate (periodic), plus conditioning."""
        return sum(2 if p else 1 for p in self.periodic) + len(self.conditioning)

    @property
    def layer_sizes(self) -> list[tuple[int, int]]:
        """(out, in) of every linear map, first sine layer to output layer."""
        dims = [self.in_dim] + [self.width] * self.hidden_layers + [self.out_dim]
        return list(zip(dims[1:], dims[:-1], strict=True))

    def to_dict(self) -> dict:
        """Plain dict (lists instead of tuples) for checkpoints and logs."""
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, data: dict) -> FieldConfig:
        return config_from_dict(cls, data)
