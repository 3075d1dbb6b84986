"""Run-directory names made of a point's parameters: ``material-silk_gravity-0,0,-4.9``."""

from __future__ import annotations

import hashlib
import json
import re

MAX_LENGTH = 120  # characters; longer names end in a hash of the parameters instead
_UNSAFE = re.compile(r"[^A-Za-z0-9._,+=-]+")


def value_text(value) -> str:
    """A parameter value as a file-name fragment: floats round-trip (repr), lists joined by
    commas, a path by its file name, other characters than [A-Za-z0-9._,+=-] as '-'."""
    if isinstance(value, bool):
        text = str(value).lower()
    elif isinstance(value, float):
        text = repr(value)
    elif isinstance(value, list | tuple):
        text = ",".join(value_text(v) for v in value)
    elif isinstance(value, str) and "/" in value:
        text = value.rstrip("/").rsplit("/", 1)[-1]
    else:
        text = str(value)
    return _UNSAFE.sub("-", text)


def short_keys(keys) -> dict[str, str]:
    """Each key by its last dotted part, or in full (dots as '-') where two share it."""
    keys = list(keys)
    last = [k.rsplit(".", 1)[-1] for k in keys]
    return {k: (s if last.count(s) == 1 else k.replace(".", "-"))
            for k, s in zip(keys, last, strict=True)}


def run_name(parameters: dict, keys: dict[str, str]) -> str:
    """The run directory's name of a point; `keys` maps each parameter to its name part."""
    name = "_".join(f"{keys[k]}-{value_text(v)}" for k, v in parameters.items()) or "run"
    if len(name) <= MAX_LENGTH:
        return name
    digest = hashlib.sha1(json.dumps(parameters, sort_keys=True).encode()).hexdigest()[:10]
    return f"{name[:MAX_LENGTH - 11]}~{digest}"
