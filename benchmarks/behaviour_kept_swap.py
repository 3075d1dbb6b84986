"""Behaviour kept (issue 26): one tree's solve started at the other tree's final state.

Copies a finished spline run of tree A (its output folder, with checkpoint.pt) to NEW and puts
the field parameters of a finished run of tree B (B's checkpoint.pt, the same grid) into NEW's
checkpoint, keeping everything else of A's (its format, levels, history, scene). Then
`ndf-sim SCENE ... --resume --out NEW` with tree A re-solves the last level at the last load
step from B's final state: a state that is an equilibrium of A's code stays (Π, the first
Newton iteration's ‖g‖ and λ² at the rounding floor, no step), one that is not moves. Prints
the largest difference of the two parameter sets.

    python benchmarks/behaviour_kept_swap.py WORK/out/S_spline_after WORK/out/S_spline_before NEW
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import torch


def main(own: Path, other: Path, new: Path) -> None:
    payload = torch.load(own / "checkpoint.pt", map_location="cpu", weights_only=True)
    source = torch.load(other / "checkpoint.pt", map_location="cpu", weights_only=True)
    mine, theirs = payload["parameters"], source["parameters"]
    if mine.keys() != theirs.keys() or any(mine[k].shape != theirs[k].shape for k in mine):
        raise SystemExit(f"behaviour_kept_swap.py: error: the two checkpoints hold other fields: "
                         f"{ {k: tuple(v.shape) for k, v in mine.items()} } and "
                         f"{ {k: tuple(v.shape) for k, v in theirs.items()} }")
    for k in mine:
        print(f"{k} {tuple(mine[k].shape)}: largest |own - other| "
              f"{(mine[k] - theirs[k]).abs().max().item():.3e}, largest |own| "
              f"{mine[k].abs().max().item():.3e}")
    payload["parameters"] = {k: theirs[k].clone() for k in mine}
    shutil.copytree(own, new)
    torch.save(payload, new / "checkpoint.pt")
    print(f"wrote {new / 'checkpoint.pt'}: {own.name}'s checkpoint with {other.name}'s parameters")


if __name__ == "__main__":
    if len(sys.argv) != 4 or Path(sys.argv[3]).exists():
        print("usage: behaviour_kept_swap.py OWN_RUN OTHER_RUN NEW (NEW must not exist)",
              file=sys.stderr)
        sys.exit(2)
    main(*(Path(a) for a in sys.argv[1:]))
