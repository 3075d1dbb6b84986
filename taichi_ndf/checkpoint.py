"""Save and load a field (type, architecture and weights), its optimiser state and caller metadata.

A checkpoint is a ``torch.save`` of a dict holding only tensors, dicts, lists, numbers,
strings, booleans and None, so ``torch.load(path, weights_only=True)`` reads it. Files are
written to a temporary file in the same folder and renamed over the target, so an interrupted
save leaves the previous checkpoint intact.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path

import torch

from taichi_ndf.field import FieldConfig, NeuralField, SplineConfig, SplineField
from taichi_ndf.optim import Adam

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
KIND = "taichi_ndf.checkpoint"
# Field types by checkpoint tag: (field class, its config class). A checkpoint without a
# "field_type" (written before spline fields existed) holds a SIREN field.
FIELD_TYPES = {"siren": (NeuralField, FieldConfig), "spline": (SplineField, SplineConfig)}


@dataclass
class Checkpoint:
    """What ``load_checkpoint`` found: the field (loaded), optimiser state and metadata."""

    field: NeuralField | SplineField
    optimiser_state: dict | None
    extra: dict
    format_version: int


def _check_plain(value, where: str) -> None:
    """Raise TypeError if value holds anything a weights_only load cannot read."""
    if value is None or isinstance(value, (bool, int, float, str, torch.Tensor)):
        return
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _check_plain(item, f"{where}[{i}]")
        return
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError(f"{where}: keys must be strings, got {key!r}")
            _check_plain(item, f"{where}[{key!r}]")
        return
    raise TypeError(
        f"{where} is a {type(value).__name__}; checkpoints hold only tensors, dicts, lists, "
        "numbers, strings, booleans and None"
    )


def _to_cpu(value):
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().clone()
    if isinstance(value, dict):
        return {k: _to_cpu(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_to_cpu(v) for v in value]
    return value


def _field_type(field) -> str:
    for tag, (cls, _) in FIELD_TYPES.items():
        if isinstance(field, cls):
            return tag
    raise TypeError(f"cannot checkpoint a {type(field).__name__}; fields: {list(FIELD_TYPES)}")


def save_checkpoint(
    path: str | os.PathLike,
    field: NeuralField | SplineField,
    optimiser: Adam | None = None,
    *,
    extra: dict | None = None,
) -> Path:
    """Write field architecture and weights, optimiser state and ``extra`` (e.g. iteration,
    scene name) to ``path`` atomically; returns the path."""
    path = Path(path)
    extra = {} if extra is None else extra
    _check_plain(extra, "extra")
    payload = {
        "kind": KIND,
        "format_version": FORMAT_VERSION,
        "field_type": _field_type(field),
        "architecture": field.config.to_dict(),
        "parameters": _to_cpu(field.state_dict()),
        "optimiser": None if optimiser is None else _to_cpu(optimiser.state_dict()),
        "extra": _to_cpu(extra),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(handle, 0o644)  # mkstemp's 0600 would make checkpoints private
        with os.fdopen(handle, "wb") as stream:
            torch.save(payload, stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    log.info("saved checkpoint %s", path)
    return path


def _architecture_mismatch(stored, ours) -> list[str]:
    if type(stored) is not type(ours):
        return [f"field type: checkpoint {type(stored).__name__}, field {type(ours).__name__}"]
    return [
        f"{f.name}: checkpoint {getattr(stored, f.name)}, field {getattr(ours, f.name)}"
        for f in fields(stored)
        if getattr(stored, f.name) != getattr(ours, f.name)
    ]


def load_checkpoint(
    path: str | os.PathLike,
    field: NeuralField | SplineField | None = None,
    *,
    optimiser: Adam | None = None,
) -> Checkpoint:
    """Read a checkpoint; load its weights into ``field`` (or a new field of the stored
    architecture in the runtime's dtype) and its state into ``optimiser`` if given.

    Raises ValueError if the file is not a checkpoint of a supported version, if ``field``
    has a different architecture (naming each differing setting), or if ``optimiser`` is
    given but the checkpoint holds no optimiser state.
    """
    payload = torch.load(Path(path), map_location="cpu", weights_only=True)
    if not isinstance(payload, dict) or payload.get("kind") != KIND:
        raise ValueError(f"{path} is not a taichi_ndf checkpoint")
    version = payload["format_version"]
    if version != FORMAT_VERSION:
        raise ValueError(
            f"{path}: checkpoint format {version}, this version reads {FORMAT_VERSION}"
        )
    tag = payload.get("field_type", "siren")
    if tag not in FIELD_TYPES:
        raise ValueError(f"{path}: unknown field type {tag!r}; known: {list(FIELD_TYPES)}")
    field_class, config_class = FIELD_TYPES[tag]
    stored = config_class.from_dict(payload["architecture"])
    if field is None:
        field = field_class(stored)
    else:
        mismatch = _architecture_mismatch(stored, field.config)
        if mismatch:
            raise ValueError(f"{path} does not fit the field: " + "; ".join(mismatch))
    field.load_state_dict(payload["parameters"])
    if optimiser is not None:
        if payload["optimiser"] is None:
            raise ValueError(f"{path} holds no optimiser state")
        optimiser.load_state_dict(payload["optimiser"])
    return Checkpoint(
        field=field,
        optimiser_state=payload["optimiser"],
        extra=payload["extra"],
        format_version=version,
    )
