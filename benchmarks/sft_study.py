"""Shape-from-template study: the spline + Kirchhoff–Love prior against the per-frame baseline
(and the same spline field without the prior) on the project's own sequence generator.

    python benchmarks/sft_study.py [--sequences roll fold corner wave] [--seeds 0 1]
        [--frames 30] [--field spline|siren] [--cache DIR] [--json OUT]
        [--tracker NAME=VALUE ...] [--guided] [--photometric W] [--variant NAME=VALUE ...]

For every sequence family and seed: render the sequence (`inverse.sft.synth`, default
degradations), track it (`inverse.sft.tracking`), reconstruct it with the baseline
(`inverse.sft.baseline`), the spline field with the prior and without it
(`inverse.sft.spline_prior`), and print the metrics (`inverse.sft.metrics.PROTOCOL`), the
largest per-frame depth bias (mean over vertices of z − z_gt [mm]: a global depth drift shows
here), and seconds per frame (wall, and process CPU summed over threads); then whether the prior
beats the baseline on e3D, chamfer and normal error on every sequence. --field siren runs the
older SIREN + Adam field (`inverse.sft.siren_prior`, initialised from the baseline's meshes)
instead of the spline; its per-frame time excludes the baseline it starts from. --cache keeps the
rendered and tracked sequences (pickles) for reruns. --guided adds the prior with the guided
search (`inverse.sft.guided`: lost texture points re-found near the reconstruction's
prediction), row "prior+guided", beside the prior without it. --photometric W adds the prior
with the photometric term at w_photo = W (`inverse.sft.photometric`), row "prior+photo".
--variant NAME=VALUE ... adds the prior with those `SplinePriorConfig` fields changed, row
"prior+variant", beside the prior at its defaults.
docs/sft_results.md holds a run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from inverse.sft.baseline import reconstruct_baseline
from inverse.sft.frame_fits import reconstruct_sequence
from inverse.sft.guided import GuidedSearch
from inverse.sft.metrics import PROTOCOL, evaluate_sequence
from inverse.sft.photometric import photometric_evidence
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from inverse.sft.synth import SEQUENCES, SynthConfig, generate
from inverse.sft.tracking import track_sequence
from inverse.sft.tracking_config import TrackerConfig

COMPARED = ("e3d", "chamfer_x1e4", "normal_deg")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sequences", nargs="+", choices=SEQUENCES, default=list(SEQUENCES))
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--field", choices=("spline", "siren"), default="spline",
                   help="the prior's displacement field (siren: the older SIREN + Adam path)")
    p.add_argument("--physics-weight", type=float, default=None,
                   help="w_phys (default: the field's own)")
    p.add_argument("--no-prior", action="store_true", help="also run the field without prior")
    p.add_argument("--cache", type=Path, help="folder for rendered and tracked sequences")
    p.add_argument("--json", type=Path, help="write every row here")
    p.add_argument("--tracker", nargs="+", default=[], metavar="NAME=VALUE",
                   help="TrackerConfig fields other than the defaults (e.g. outlier_tolerance=4)")
    p.add_argument("--guided", action="store_true",
                   help="also run the prior with the guided search (inverse.sft.guided)")
    p.add_argument("--photometric", type=float, metavar="W",
                   help="also run the spline prior with the photometric term at w_photo = W "
                   "(inverse.sft.photometric)")
    p.add_argument("--variant", nargs="+", default=[], metavar="NAME=VALUE",
                   help="also run the spline prior with these SplinePriorConfig fields changed "
                   "(e.g. membrane_factor=0.1), row prior+variant")
    return p


def replaced(config, pairs: list[str]):
    """`config` (a frozen dataclass) with NAME=VALUE fields replaced (values of the field's
    default's type; booleans as true/false)."""
    changes = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in {f.name for f in dataclasses.fields(config)}:
            raise SystemExit(f"{type(config).__name__} has no field {name!r}")
        default = getattr(config, name)
        try:
            changes[name] = (value.lower() in ("1", "true", "yes") if isinstance(default, bool)
                             else type(default)(value) if default is not None else float(value))
        except ValueError:
            raise SystemExit(f"{name}={value}: not a {type(default).__name__}") from None
    try:
        return dataclasses.replace(config, **changes)
    except ValueError as err:
        raise SystemExit(str(err)) from None


def tracker_config(pairs: list[str]) -> TrackerConfig:
    """TrackerConfig with NAME=VALUE fields replaced (values of the field's default's type)."""
    changes = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in {f.name for f in dataclasses.fields(TrackerConfig)}:
            raise SystemExit(f"--tracker: TrackerConfig has no field {name!r}")
        changes[name] = type(getattr(TrackerConfig, name))(value)
    return TrackerConfig(**changes)


def prepared(sequence: str, seed: int, frames: int, cache: Path | None,
             tracker: TrackerConfig | None = None) -> dict:
    """The rendered sequence, its tracks and the baseline (from the cache when there; the
    cache file names the tracker settings that differ from the defaults)."""
    tracker = tracker or TrackerConfig()
    changed = "".join(f"_{f.name}{getattr(tracker, f.name)}" for f in dataclasses.fields(tracker)
                      if getattr(tracker, f.name) != f.default)
    path = None if cache is None else cache / f"{sequence}_{seed}_{frames}{changed}.pkl"
    if path is not None and path.exists():
        with path.open("rb") as f:
            data = pickle.load(f)
        if "frames" in data:
            return data
        # An older cache without the images the guided search needs: render them again.
        synth = generate(SynthConfig(sequence=sequence, frames=frames, seed=seed))
        data.update(frames=synth.frames, texture=synth.texture)
        with path.open("wb") as f:
            pickle.dump(data, f)
        return data
    synth = generate(SynthConfig(sequence=sequence, frames=frames, seed=seed))
    clock = time.perf_counter()
    tracks, _ = track_sequence(synth.frames, synth.template, synth.texture, synth.camera,
                               masks=synth.masks, config=tracker)
    tracking = (time.perf_counter() - clock) / frames
    clock, cpu = time.perf_counter(), time.process_time()
    baseline = reconstruct_baseline(synth.template, synth.camera, tracks).vertices
    data = {"template": synth.template, "camera": synth.camera, "faces": synth.faces,
            "gt": synth.vertices, "masks": synth.masks, "tracks": tracks,
            "frames": synth.frames, "texture": synth.texture,
            "tracking_s": tracking, "baseline": baseline,
            "baseline_s": (time.perf_counter() - clock) / (frames - 1),
            "baseline_cpu_s": (time.process_time() - cpu) / (frames - 1)}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as f:
            pickle.dump(data, f)
    return data


def depth_bias_mm(vertices: list[np.ndarray], gt: list[np.ndarray]) -> float:
    """Largest |mean over vertices of z − z_gt| over the frames [mm]."""
    return 1e3 * max(abs(float((v[:, 2] - g[:, 2]).mean())) for v, g in zip(vertices, gt,
                                                                           strict=True))


def row(method: str, data: dict, vertices: list[np.ndarray], wall: float, cpu: float) -> dict:
    metrics = evaluate_sequence(vertices, data["gt"], data["faces"],
                                camera=data["camera"]).summary()
    metrics.pop("protocol")
    return {"method": method, **metrics, "depth_bias_mm": depth_bias_mm(vertices, data["gt"]),
            "s_per_frame": wall, "cpu_s_per_frame": cpu}


def study(sequence: str, seed: int, args: argparse.Namespace) -> list[dict]:
    data = prepared(sequence, seed, args.frames, args.cache, tracker_config(args.tracker))
    rows = [row("baseline", data, data["baseline"], data["baseline_s"], data["baseline_cpu_s"])]
    config = (SplinePriorConfig() if args.field == "spline"
              else ReconstructionConfig(seed=seed))
    if args.physics_weight is not None:
        config = dataclasses.replace(config, physics_weight=args.physics_weight)
    variants = [("prior", config, False)]
    variants += [("prior+guided", config, True)] if args.guided else []
    if args.photometric is not None:
        variants += [("prior+photo", dataclasses.replace(
            config, photometric_weight=args.photometric), False)]
    if args.variant:
        variants += [("prior+variant", replaced(config, args.variant), False)]
    variants += ([("no-prior", dataclasses.replace(config, physics_weight=0.0), False)]
                 if args.no_prior else [])
    for name, settings, guide in variants:
        guided = None if not guide else GuidedSearch(
            data["frames"], data["camera"], data["template"], data["texture"],
            masks=data["masks"])
        result = reconstruct_sequence(
            data["template"], data["camera"], data["tracks"], settings, masks=data["masks"],
            initial=data["baseline"] if args.field == "siren" else None, guided=guided,
            photometric=photometric_evidence(settings, data["frames"], data["camera"],
                                             data["template"], data["texture"],
                                             masks=data["masks"]))
        wall, cpu = float(np.mean(result.seconds[1:])), float(np.mean(result.cpu_seconds[1:]))
        rows.append(row(name, data, result.vertices, wall, cpu))
    for r in rows:
        r.update(sequence=sequence, seed=seed, field=args.field, tracking_s=data["tracking_s"],
                 tracks_per_frame=float(np.mean([len(t) for t in data["tracks"]])))
    return rows


def format_row(r: dict) -> str:
    return (f"{r['sequence']:<7} {r['seed']:>4} {r['method']:<12} {r['e3d']:7.4f} "
            f"{r['e3d_procrustes']:7.4f} {r['chamfer_x1e4']:8.4f} {r['normal_deg']:7.2f} "
            f"{r['reprojection_px']:7.3f} {r['depth_bias_mm']:7.2f} {r['s_per_frame']:6.2f} "
            f"{r['cpu_s_per_frame']:6.2f}")


HEADER = (f"{'seq':<7} {'seed':>4} {'method':<12} {'e3D':>7} {'e3D-P':>7} {'chamfer':>8} "
          f"{'normal°':>7} {'rep px':>7} {'dz mm':>7} {'s/fr':>6} {'cpu s':>6}")


def verdict(rows: list[dict]) -> list[str]:
    """Per sequence and seed: does the prior beat the baseline on e3D, chamfer, normal?"""
    lines = []
    for key in sorted({(r["sequence"], r["seed"]) for r in rows}):
        by = {r["method"]: r for r in rows if (r["sequence"], r["seed"]) == key}
        for method in ("prior", "prior+guided", "prior+photo", "prior+variant"):
            if method not in by:
                continue
            wins = {m: by[method][m] < by["baseline"][m] for m in COMPARED}
            lines.append(f"{key[0]} seed {key[1]}: {method} beats baseline on "
                         + ", ".join(f"{m} {'yes' if w else 'NO'}" for m, w in wins.items()))
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.photometric is not None and (args.field != "spline" or not args.photometric > 0):
        parser.error("--photometric needs --field spline and W > 0")
    if args.variant and args.field != "spline":
        parser.error("--variant needs --field spline")
    if args.variant:
        replaced(SplinePriorConfig(), args.variant)  # a bad name or value: before any work
    taichi_ndf.init(precision="f64")
    torch.set_num_threads(1)
    rows = []
    print(HEADER, flush=True)
    for sequence in args.sequences:
        for seed in args.seeds:
            for r in study(sequence, seed, args):
                rows.append(r)
                print(format_row(r), flush=True)
    print("\n".join(verdict(rows)))
    print(f"protocol: {PROTOCOL}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
