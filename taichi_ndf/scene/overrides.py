"""Scene-key overrides: ``KEY=VALUE`` assignments applied to a parsed scene document.

``ndf-sim --set material.stiffness_scale=0.5 --set loads.gravity=[0,0,-5]`` and the axes of a
study file (`taichi_ndf.sweep`) change scene keys this way before the scene is validated, so an
override is checked exactly like the same key written in the file. KEY is a dotted path of
table names (``training.seed``); an array of tables is indexed with ``[i]``
(``boundary.constraint[0].xi``). VALUE is a TOML value (``0.5``, ``"silk"``, ``[0, 0, -5]``,
``true``); a missing table on the path is created, and a key the scene format does not know is
refused by the scene parser, naming it.
"""

from __future__ import annotations

import copy
import re
import tomllib

from taichi_ndf.scene.schema import SceneError

_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


def parse_assignment(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` -> (KEY, the TOML value); SceneError naming the text if it is not one."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise SceneError(f"--set {text!r}: expected KEY=VALUE, e.g. material.preset=\"silk\"")
    _segments(key)
    try:
        return key, tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        raise SceneError(f"--set {key}: {value.strip()!r} is not a TOML value (a string needs "
                         "quotes: \"silk\")") from None


def _segments(key: str) -> list[tuple[str, int | None]]:
    out = []
    for part in key.split("."):
        match = _SEGMENT.match(part)
        if match is None:
            raise SceneError(f"{key}: not a scene key (dotted names, [i] for an array of "
                             "tables)")
        out.append((match.group(1), None if match.group(2) is None else int(match.group(2))))
    return out


def apply_overrides(document: dict, overrides: dict[str, object]) -> dict:
    """A copy of the scene document with every KEY of `overrides` set to its value."""
    document = copy.deepcopy(document)
    for key, value in overrides.items():
        segments = _segments(key)
        table = document
        for depth, (name, index) in enumerate(segments):
            last = depth == len(segments) - 1
            if index is None and last:
                table[name] = copy.deepcopy(value)
                break
            if index is None:
                table = table.setdefault(name, {})
            else:
                array = table.get(name)
                if not isinstance(array, list) or index >= len(array):
                    size = len(array) if isinstance(array, list) else 0
                    raise SceneError(f"{key}: the scene has {size} [[{name}]] table(s), no "
                                     f"index {index}")
                if last:
                    array[index] = copy.deepcopy(value)
                    break
                table = array[index]
            if not isinstance(table, dict):
                raise SceneError(f"{key}: {name} is a value, not a table")
    return document
