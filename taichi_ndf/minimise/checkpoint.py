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

from taichi_ndf.field import NeuralField, SplineField
from taichi_ndf.problem.field_types import CHECKPOINT_TYPES, of_field
from taichi_ndf.problem.optim import Adam

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
KIND = "taichi_ndf.minimise.checkpoint"
# A checkpoint is tagged with its field type's name (`problem.field_types.CHECKPOINT_TYPES`:
# the field class and its architecture class; "panels" for a garment's `PanelFields`); one
# without a "field_type" (written before spline fields existed) holds a SIREN field.
UNTAGGED = "siren"


class CheckpointError(ValueError):
    """A file is not a readable checkpoint of this version; the message names it and why."""


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
        "field_type": of_field(field).name,
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


def read_checkpoint(path: str | os.PathLike) -> dict:
    """The checked contents of a checkpoint file: a dict with ``field_type`` (a name of
    `CHECKPOINT_TYPES`: "siren", "spline"; "panels": a garment's `PanelFields`), ``architecture``
    (its config: FieldConfig, SplineConfig, PanelsConfig),
    ``parameters`` (name -> finite tensor), ``optimiser`` (dict or None), ``extra`` (dict) and
    ``format_version``.

    Raises FileNotFoundError if ``path`` does not exist and CheckpointError (one line naming the
    file and the reason) for anything else that is not a checkpoint of this version: a folder,
    an empty, truncated, corrupted or foreign file.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    if not path.is_file():
        raise CheckpointError(f"{path}: not a checkpoint file (it is a directory)")
    if path.stat().st_size == 0:
        raise CheckpointError(f"{path}: not a checkpoint (the file is empty)")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many kinds on damaged or foreign files
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(f"{path}: not a readable checkpoint (truncated, corrupted or "
                              f"another format: {reason[:200]})") from None
    if not isinstance(payload, dict) or payload.get("kind") != KIND:
        raise CheckpointError(f"{path}: not a taichi_ndf checkpoint")
    version = payload.get("format_version")
    if version != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint format {version!r}, this version reads {FORMAT_VERSION}")
    tag = payload.get("field_type", UNTAGGED)
    if tag not in CHECKPOINT_TYPES:
        raise CheckpointError(f"{path}: unknown field type {tag!r}; known: "
                              f"{list(CHECKPOINT_TYPES)}")
    try:
        config = CHECKPOINT_TYPES[tag].config
        architecture = config.from_dict(payload["architecture"])
        parameters = payload["parameters"]
        if not isinstance(parameters, dict) or not all(
                isinstance(v, torch.Tensor) for v in parameters.values()):
            raise ValueError("parameters are not a dict of tensors")
        if not all(torch.isfinite(v).all() for v in parameters.values()):
            raise ValueError("parameters hold NaN or infinity")
        optimiser = payload["optimiser"]
        if optimiser is not None and not isinstance(optimiser, dict):
            raise ValueError("optimiser state is not a dict")
        extra = payload["extra"]
        if not isinstance(extra, dict):
            raise ValueError("extra is not a dict")
    except (KeyError, TypeError, ValueError) as err:
        reason = f"missing entry {err}" if isinstance(err, KeyError) else str(err)
        raise CheckpointError(f"{path}: damaged checkpoint ({reason})") from None
    return {"architecture": architecture, "parameters": parameters, "optimiser": optimiser,
            "extra": extra, "format_version": version, "field_type": tag}


def load_checkpoint(
    path: str | os.PathLike,
    field: NeuralField | SplineField | None = None,
    *,
    optimiser: Adam | None = None,
) -> Checkpoint:
    """Read a checkpoint (``read_checkpoint``); load its weights into ``field`` (or a new field
    of the stored architecture in the runtime's dtype) and its state into ``optimiser`` if given.

    Raises CheckpointError (a ValueError) if the file is not a checkpoint of a supported
    version, if ``field`` has a different architecture (naming each differing setting), or if
    ``optimiser`` is given but the checkpoint holds no optimiser state.
    """
    contents = read_checkpoint(path)
    stored = contents["architecture"]
    tag = contents["field_type"]
    field_class = CHECKPOINT_TYPES[tag].field
    if field is None:
        field = field_class(stored)
    else:
        mismatch = _architecture_mismatch(stored, field.config)
        if mismatch:
            raise CheckpointError(f"{path} does not fit the field: " + "; ".join(mismatch))
    if optimiser is not None and contents["optimiser"] is None:
        raise CheckpointError(f"{path} holds no optimiser state")
    try:
        field.load_state_dict(contents["parameters"])
        if optimiser is not None:
            optimiser.load_state_dict(contents["optimiser"])
    except (KeyError, RuntimeError, TypeError, ValueError) as err:
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(f"{path}: damaged checkpoint ({reason[:200]})") from None
    return Checkpoint(
        field=field,
        optimiser_state=contents["optimiser"],
        extra=contents["extra"],
        format_version=contents["format_version"],
    )
