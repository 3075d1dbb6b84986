"""The record of a dynamic run (`taichi_ndf.solve.dynamics`): the state at a time, each step's
energies and cost, the output frames, and the checkpoint a run is resumed from.

A checkpoint (`write_checkpoint`, at every output frame) holds everything the next steps
depend on: the state (C, V, A [, the boundary's g, ġ, g̈]) and its time, the step index, the
step size, the record so far and, with obstacles, the contact check points flagged so far and
the barrier stiffness (both change over the steps). Resumed from it (`read_checkpoint`), a run
takes the same steps as an uninterrupted one: the final state is the same bit for bit
(tests/test_dynamics_resume.py).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import torch

from taichi_ndf.field import SplineField
from taichi_ndf.io.output_dir import atomic_path
from taichi_ndf.problem.dynamics import DynamicsConfig

CHECKPOINT_KIND = "taichi_ndf dynamics checkpoint"


@dataclass(frozen=True)
class Motion:
    """The state at a time [s]: coefficients (n, 3) of displacement [m], velocity [m/s] and
    acceleration [m/s²]; with a prescribed boundary motion, `boundary`: the boundary's own
    part of the displacement at the Gauss points as a Motion of jets (N, 6, 3) (g, ġ, g̈),
    stepped by the same scheme (None: the boundary held)."""

    time: float
    displacement: torch.Tensor
    velocity: torch.Tensor
    acceleration: torch.Tensor
    boundary: Motion | None = None


@dataclass(frozen=True)
class StepRecord:
    """One time step: its index (1 = the first), the time reached [s], Newton iterations over
    its substeps, substeps (1: not halved), kinetic energy T, potential energy Π and T + Π [J]
    at its end, and the CPU seconds (user + sys of this process) and wall seconds it took."""

    step: int
    time: float
    newton_iterations: int
    substeps: int
    kinetic: float
    potential: float
    total: float
    cpu_seconds: float
    wall_seconds: float
    gap: float | None = None  # with contact: the dense check grid's smallest gap [m]
    size: float | None = None  # the step's length h [s]


@dataclass
class Trajectory:
    """A dynamic run: its settings, spans of the grid, the state at t = 0 (energies), every
    step, the output frames (time [s], coefficients (n, 3)), the probes' displacement [m] at
    t = 0 and after every step, the final field."""

    config: DynamicsConfig
    spans: tuple[int, int]
    initial: StepRecord
    records: list[StepRecord] = field(default_factory=list)
    frames: list[tuple[float, torch.Tensor]] = field(default_factory=list)
    probes: dict[str, list[list[float]]] = field(default_factory=dict)
    field: SplineField | None = None

    @property
    def times(self) -> list[float]:
        return [self.initial.time] + [r.time for r in self.records]

    @property
    def cpu_seconds(self) -> float:
        return sum(r.cpu_seconds for r in self.records)

    def to_dict(self) -> dict:
        """result.json's `dynamics`: settings, per step times and energies, frames' times, and
        the CPU cost per step and per simulated second."""
        records = [self.initial, *self.records]
        steps = max(1, len(self.records))
        return {**self.config.to_dict(), "spans": list(self.spans),
                "times": self.times, "kinetic": [r.kinetic for r in records],
                "potential": [r.potential for r in records],
                "total": [r.total for r in records],
                "newton_iterations": [r.newton_iterations for r in self.records],
                "substeps": [r.substeps for r in self.records],
                **({"step_sizes": [r.size for r in self.records]} if self.config.adaptive
                   else {}),
                **({"gaps": [r.gap for r in records]} if self.initial.gap is not None
                   else {}),
                "frame_times": [t for t, _ in self.frames], "probes": self.probes,
                "cpu_seconds": self.cpu_seconds,
                "wall_seconds": sum(r.wall_seconds for r in self.records),
                "cpu_per_step": self.cpu_seconds / steps,
                "cpu_per_simulated_second": self.cpu_seconds / max(self.times[-1], 1e-300)}


@dataclass
class Checkpoint:
    """Where a run stands after step `step` (0: none yet): its state, its record so far, the
    step size h [s] the next step takes (None: dt) and the adaptive rule's count of easy
    steps, and with obstacles the contact check grid's flags `active` (bool (G,)) and the
    barrier stiffness [N/m³] (None without)."""

    step: int
    state: Motion
    trajectory: Trajectory
    step_size: float | None = None
    easy: int = 0
    active: torch.Tensor | None = None
    stiffness: float | None = None


def _motion_dict(state: Motion | None) -> dict | None:
    if state is None:
        return None
    return {"time": state.time, "displacement": state.displacement,
            "velocity": state.velocity, "acceleration": state.acceleration,
            "boundary": _motion_dict(state.boundary)}


def _motion(document: dict | None) -> Motion | None:
    if document is None:
        return None
    return Motion(document["time"], document["displacement"], document["velocity"],
                  document["acceleration"], _motion(document["boundary"]))


def write_checkpoint(path: str | Path, checkpoint: Checkpoint, extra: dict) -> None:
    """Save `checkpoint` (and `extra`, e.g. the scene) to `path` atomically (torch.save)."""
    trajectory = checkpoint.trajectory
    document = {"kind": CHECKPOINT_KIND, "step": checkpoint.step,
                "step_size": checkpoint.step_size, "easy": checkpoint.easy,
                "state": _motion_dict(checkpoint.state), "config": trajectory.config.to_dict(),
                "spans": list(trajectory.spans),
                "initial": dataclasses.asdict(trajectory.initial),
                "records": [dataclasses.asdict(r) for r in trajectory.records],
                "frames": trajectory.frames, "probes": trajectory.probes,
                "active": checkpoint.active, "stiffness": checkpoint.stiffness, "extra": extra}
    with atomic_path(path) as temporary:
        torch.save(document, temporary)


def read_checkpoint(path: str | Path, config: DynamicsConfig) -> tuple[Checkpoint, dict]:
    """The `Checkpoint` saved at `path` and its `extra`; ValueError when the file is not a
    dynamics checkpoint or was written with other [dynamics] settings than `config`'s."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no checkpoint at {path}")
    document = torch.load(path, weights_only=False)
    if not isinstance(document, dict) or document.get("kind") != CHECKPOINT_KIND:
        raise ValueError(f"{path} is not a dynamics checkpoint (a quasistatic run's?)")
    if document["config"] != config.to_dict():
        raise ValueError(f"{path} was written with other [dynamics] settings")
    trajectory = Trajectory(config, tuple(document["spans"]),
                            StepRecord(**document["initial"]),
                            [StepRecord(**r) for r in document["records"]],
                            list(document["frames"]), document["probes"])
    return Checkpoint(document["step"], _motion(document["state"]), trajectory,
                      document["step_size"], document["easy"], document["active"],
                      document["stiffness"]), document["extra"]
