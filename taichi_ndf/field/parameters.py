"""What every field shares: its dtype and device, and the parameter bookkeeping (flat vectors
and state dicts for Adam, L-BFGS and checkpoints) over the lists ``parameters``, ``gradients``
and ``parameter_names``."""

from __future__ import annotations

import torch

from taichi_ndf.runtime import current


def resolve_dtype_device(dtype: torch.dtype | None, device: torch.device | str | None
                         ) -> tuple[torch.dtype, torch.device]:
    """A field's dtype and device: the runtime's (``taichi_ndf.current()``) unless given;
    raises ValueError for a dtype other than float32/float64."""
    if dtype is None or device is None:
        runtime = current()
        dtype = runtime.dtype if dtype is None else dtype
        device = runtime.device if device is None else device
    if dtype not in (torch.float32, torch.float64):
        raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    return dtype, torch.device(device)


class FieldParameters:
    """Mixin for a field holding ``parameters`` and ``gradients`` (lists of tensors of equal
    shapes) named by ``parameter_names``."""

    parameters: list[torch.Tensor]
    gradients: list[torch.Tensor]
    parameter_names: list[str]

    @property
    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters)

    def get_flat(self) -> torch.Tensor:
        """Copy of all parameters as one vector, shape (num_parameters,), in list order."""
        return torch.cat([p.reshape(-1) for p in self.parameters])

    def get_flat_gradient(self) -> torch.Tensor:
        """Copy of all gradients as one vector, in the order of ``get_flat``."""
        return torch.cat([g.reshape(-1) for g in self.gradients])

    def set_flat(self, flat: torch.Tensor) -> None:
        """Overwrite all parameters in place from a vector laid out as ``get_flat``."""
        if tuple(flat.shape) != (self.num_parameters,):
            raise ValueError(
                f"flat parameters must have shape ({self.num_parameters},), got {tuple(flat.shape)}"
            )
        offset = 0
        for p in self.parameters:
            p.copy_(flat[offset : offset + p.numel()].view_as(p))
            offset += p.numel()

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Copies of the parameters by name."""
        return {
            name: p.detach().clone()
            for name, p in zip(self.parameter_names, self.parameters, strict=True)
        }

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Overwrite the parameters in place (cast to this field's dtype and device).

        Raises ValueError naming the first missing, unexpected or mis-shaped parameter.
        """
        missing = [name for name in self.parameter_names if name not in state]
        unexpected = [name for name in state if name not in self.parameter_names]
        if missing or unexpected:
            raise ValueError(f"parameter names differ: missing {missing}, unexpected {unexpected}")
        for name, p in zip(self.parameter_names, self.parameters, strict=True):
            if tuple(state[name].shape) != tuple(p.shape):
                raise ValueError(
                    f"{name}: shape {tuple(state[name].shape)} given, field has {tuple(p.shape)}"
                )
        for name, p in zip(self.parameter_names, self.parameters, strict=True):
            p.copy_(state[name])
