"""Several B-spline fields, one per panel of a garment, as one field to checkpoint:
`PanelFields` with its architecture `PanelsConfig` (the panels' names and grids).

What a checkpoint needs of a field (`taichi_ndf.minimise.checkpoint`: `config.to_dict`,
`state_dict`, `load_state_dict`) and what the divergence guard needs (`get_flat`,
`set_flat`), over the panels' `SplineField`s side by side in the panels' order; the fields
themselves are shared, not copied (a solve that writes a panel's coefficients writes them
here).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from taichi_ndf.field.spline import SplineConfig, SplineField

__all__ = ["PanelFields", "PanelsConfig"]


@dataclass(frozen=True)
class PanelsConfig:
    """The panels' names (unique, in order) and each one's spline grid."""

    names: tuple[str, ...]
    configs: tuple[SplineConfig, ...]

    def __post_init__(self):
        if len(self.names) != len(self.configs) or not self.names:
            raise ValueError(f"panels: {len(self.names)} names for {len(self.configs)} grids")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"panels: names repeat: {list(self.names)}")

    def to_dict(self) -> dict:
        return {"panels": [{"name": n, **c.to_dict()}
                           for n, c in zip(self.names, self.configs, strict=True)]}

    @classmethod
    def from_dict(cls, data: dict) -> PanelsConfig:
        panels = data["panels"]
        return cls(tuple(str(p["name"]) for p in panels),
                   tuple(SplineConfig.from_dict({k: v for k, v in p.items() if k != "name"})
                         for p in panels))


class PanelFields:
    """The panels' fields (coefficients (n_i, 3) [m] each) under their names.
    config: the architecture; fields: existing fields to share (their grids must be
    config's), else new zero fields of `dtype` (float64: a garment's solve's precision)."""

    def __init__(self, config: PanelsConfig, fields: Sequence[SplineField] | None = None, *,
                 dtype: torch.dtype = torch.float64):
        if fields is None:
            fields = [SplineField(c, dtype=dtype) for c in config.configs]
        fields = tuple(fields)
        if tuple(f.config for f in fields) != config.configs:
            raise ValueError("panels: the fields' grids differ from the configuration's")
        self.config = config
        self.fields = fields

    @classmethod
    def of(cls, names: Sequence[str], fields: Sequence[SplineField]) -> PanelFields:
        """The fields `fields` (shared) named `names`."""
        return cls(PanelsConfig(tuple(names), tuple(f.config for f in fields)), fields)

    def get_flat(self) -> torch.Tensor:
        """All panels' coefficients as one vector (3 Σ n_i,) [m], in order."""
        return torch.cat([f.get_flat() for f in self.fields])

    def set_flat(self, flat: torch.Tensor) -> None:
        offset = 0
        for f in self.fields:
            n = f.num_parameters
            f.set_flat(flat[offset:offset + n])
            offset += n

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Copies of every panel's parameters, named "<panel>.<parameter>"."""
        return {f"{name}.{key}": value for name, f in zip(self.config.names, self.fields,
                                                          strict=True)
                for key, value in f.state_dict().items()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Overwrite every panel's parameters in place (ValueError naming what differs)."""
        names = self.config.names
        unexpected = [k for k in state if k.split(".", 1)[0] not in names]
        if unexpected:
            raise ValueError(f"parameters of no panel: {unexpected}")
        for name, f in zip(names, self.fields, strict=True):
            f.load_state_dict({k.split(".", 1)[1]: v for k, v in state.items()
                               if k.split(".", 1)[0] == name})
