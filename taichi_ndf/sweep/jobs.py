"""The jobs a study runs: which tool a run is, its command line, and the numbers of its outputs.

Every run is a subprocess of an existing tool (``python -m MODULE ... --out RUN``):
- ``scene``: ``ndf-sim BASE`` (`taichi_ndf.cli.sim`). Keys named like one of its options
  (`SIM_OPTIONS`: material, field, seed, iters, ...) are passed as that option; every other
  key is a scene key, passed as ``--set KEY=VALUE`` (`taichi_ndf.scene.overrides`). Outputs:
  RUN/result.json's Π, probe displacements, iterations, convergence and seed.
- ``fit_material``: ``ndf-fit-material`` (`inverse.cli.fit_material`); keys are its options.
  Outputs: RUN/estimate.json's values and standard errors, misfit, iterations.
- ``sft``: ``ndf-sft`` (`inverse.cli.sft`); keys are its options. Outputs: the mean metrics of
  RUN/result.json (with ``gt``).
- ``calibration``: one noisy fit of a calibration case (`inverse.cli.calibration_draw`; keys
  case, noise, seed, flap_spans). Outputs: RUN/draw.json's estimate, standard error and its
  parts per unknown. Its runs share the study's cache of solved cases (``--case-cache
  OUT/cache``, `taichi_ndf.sweep.cache`): each case is solved once per study.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

from taichi_ndf.scene.schema import SceneError

# Option name -> accepted Python types of its value (TOML); bool options are flags.
_RUNTIME = {"precision": (str,), "seed": (int,), "arch": (str,), "threads": (int,)}
SIM_OPTIONS = {"iters": (int,), "samples": (int,), "material": (str,), "field": (str,),
               "refine": (int,), "quick": (bool,), **_RUNTIME}
FIT_OPTIONS = {"scene": (str,), "observed": (str, list), "estimate": (str, list),
               "method": (str,), "spans": (list,), "seeds": (list,), "width": (int,),
               "samples": (int,), "point_cloud": (bool,), "decades": (int, float),
               "box_centre": (str,), "iterations": (int,), "newton": (int,),
               "band": (int, float), "quick": (bool,), **_RUNTIME}
SFT_OPTIONS = {"frames": (str,), "camera": (str,), "template": (str,), "texture": (str,),
               "masks": (str,), "pinned": (str,), "gt": (str,), "method": (str,),
               "field": (str,), "physics_weight": (int, float), "steps": (int,),
               "init": (str,), "fps": (int, float), **_RUNTIME}
CALIBRATION_OPTIONS = {"case": (str,), "noise": (int, float), "seed": (int,),
                       "flap_spans": (list,)}


def toml_value(value) -> str:
    """A value as TOML text (for ``ndf-sim --set``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) \
            + "}"
    raise TypeError(f"not a TOML value: {value!r}")


def option_arguments(name: str, value) -> list[str]:
    """``--name value`` (underscores as dashes); a flag for true, nothing for false; a list
    as several values."""
    flag = "--" + name.replace("_", "-")
    if isinstance(value, bool):
        return [flag] if value else []
    if isinstance(value, list):
        return [flag, *(str(v) for v in value)]
    return [flag, str(value)]


@dataclass(frozen=True)
class Job:
    """kind: the study's ``job``; module: the tool run as ``python -m``; options: the tool's
    option names and value types; scene_keys: other keys are scene keys (``--set``);
    base_option: how the base file is passed ("" positional, None: no base file);
    path_options: options whose (relative) paths are relative to the study file; result: the
    file of RUN the outputs are read from; cache_option: the tool's option naming the study's
    cache folder (OUT/cache, `taichi_ndf.sweep.cache`), None for a tool without one."""

    kind: str
    module: str
    options: dict
    result: str
    scene_keys: bool = False
    base_option: str | None = None
    path_options: tuple[str, ...] = field(default_factory=tuple)
    cache_option: str | None = None

    def check_option(self, key: str, where: str) -> None:
        """StudyError-ready SceneError for an unknown key (naming it and where it is)."""
        if key in self.options or self.scene_keys:
            return
        raise SceneError(f"{where}.{key}: not an option of job {self.kind!r} (one of "
                         f"{', '.join(sorted(self.options))})")

    def check_value(self, key: str, value, where: str) -> None:
        """SceneError naming the key if a tool option's value has the wrong type."""
        types = self.options.get(key)
        if types is None:
            return
        ok = isinstance(value, types) and not (bool not in types and isinstance(value, bool))
        if isinstance(value, float) and not math.isfinite(value):
            ok = False
        if not ok:
            names = " or ".join(t.__name__ for t in types)
            raise SceneError(f"{where}.{key}: expected {names}, got {value!r}")

    def resolve_paths(self, values: dict, folder: Path) -> dict:
        """The values with relative paths of `path_options` made absolute against `folder`."""
        out = dict(values)
        for key in self.path_options:
            if key in out:
                value = out[key]
                out[key] = ([str((folder / v).resolve()) for v in value]
                            if isinstance(value, list) else str((folder / value).resolve()))
        return out

    def command(self, base: Path | None, parameters: dict, out: Path,
                cache: Path | None = None) -> list[str]:
        """The run's command line: the tool, its base file, the options, the study's cache
        folder `cache` (for a tool with a `cache_option`), ``--out out``."""
        argv = [sys.executable, "-m", self.module]
        if self.base_option == "":
            argv.append(str(base))
        elif self.base_option is not None:
            argv += [self.base_option, str(base)]
        for key, value in parameters.items():
            if key in self.options:
                argv += option_arguments(key, value)
            else:
                argv += ["--set", f"{key}={toml_value(value)}"]
        if self.cache_option is not None and cache is not None:
            argv += [self.cache_option, str(cache)]
        return [*argv, "--out", str(out)]

    def outputs(self, run: Path) -> dict:
        """The numbers of a finished run (columns of the results table)."""
        document = json.loads((run / self.result).read_text())
        return _READERS[self.kind](document)


def _scene_outputs(result: dict) -> dict:
    out = {"energy_J": result["energy"]}
    for name, u in result.get("probes", {}).items():
        for axis, value in zip(("ux", "uy", "uz"), u, strict=True):
            out[f"probe_{name}_{axis}_m"] = value
    levels = result.get("levels")
    out["iterations"] = result["iterations"]
    out["converged"] = levels[-1]["converged"] if levels else ""
    out["seed"] = result.get("seed", "")
    return out


def _fit_outputs(estimate: dict) -> dict:
    """Per unknown: the estimate and its standard error where the fit determines it (else
    ''), whether it does, and the best-fit value of a fit whose model does not explain the
    data (`inverse.material.report`)."""
    out = {}
    for name, entry in estimate["parameters"].items():
        out[f"estimate_{name}"] = entry.get("value", "")
        out[f"standard_error_{name}"] = entry.get("standard_error", "")
        out[f"determined_{name}"] = entry.get("determined", "")
        out[f"best_fit_{name}"] = entry.get("best_fit_value", "")
    out["misfit"] = estimate.get("misfit", "")
    out["iterations"] = estimate.get("iterations", "")
    return out


def _sft_outputs(result: dict) -> dict:
    metrics = result.get("metrics", {})
    return {f"mean_{k}": v for k, v in metrics.items() if isinstance(v, int | float)}


def _draw_outputs(draw: dict) -> dict:
    out = {}
    for j, name in enumerate(draw["unknowns"]):
        for part in ("truth", "value", "standard_error", "fisher", "discretisation"):
            out[f"{part}_{name}"] = draw[part][j]
    out["fit_s"] = draw["seconds"]
    out["seed"] = draw["seed"]
    return out


_READERS = {"scene": _scene_outputs, "fit_material": _fit_outputs, "sft": _sft_outputs,
            "calibration": _draw_outputs}

JOBS = {
    "scene": Job("scene", "taichi_ndf.cli.sim", SIM_OPTIONS, "result.json", scene_keys=True,
                 base_option=""),
    "fit_material": Job("fit_material", "inverse.cli.fit_material", FIT_OPTIONS,
                        "estimate.json", path_options=("scene", "observed")),
    "sft": Job("sft", "inverse.cli.sft", SFT_OPTIONS, "result.json",
               path_options=("frames", "camera", "template", "texture", "masks", "pinned",
                             "gt")),
    "calibration": Job("calibration", "inverse.cli.calibration_draw", CALIBRATION_OPTIONS,
                       "draw.json", cache_option="--case-cache"),
}
