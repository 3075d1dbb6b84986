"""The specification of a dynamic run: integrator, time step, duration, output frames, damping
(a scene's `[dynamics]` section; solved by `taichi_ndf.solve.dynamics`)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

from taichi_ndf.problem.wind import Wind

# implicit_euler: first order, dissipative; newmark: the average-acceleration (trapezoidal)
# Newmark scheme β = 1/4, γ = 1/2, second order, energy-conserving for linear problems.
INTEGRATORS = ("implicit_euler", "newmark")
NEWMARK_BETA = 0.25
NEWMARK_GAMMA = 0.5


@dataclass(frozen=True)
class BoundaryMotion:
    """The prescribed boundary motion in time (a scene's `[dynamics.motion]`): the factor μ(t)
    by which the scene's prescribed displacements (handles' displacement, rim rotations'
    angle: the boundary's load-factor path, `boundary.motions.prescribed_motion`) are
    applied at time t [s]. Either keyframes ((t_i [s], μ_i), t_0 = 0 < t_1 < …, μ_0 = 0:
    linear between them, held after the last) or a sinusoid μ(t) = amplitude sin(2π
    frequency t) (frequency [Hz] > 0). μ(0) = 0: the run starts in the reference state."""

    keyframes: tuple[tuple[float, float], ...] = ()
    amplitude: float = 0.0
    frequency: float = 0.0

    def __post_init__(self):
        frames = tuple((float(t), float(m)) for t, m in self.keyframes)
        object.__setattr__(self, "keyframes", frames)
        if bool(frames) == bool(self.frequency):
            raise ValueError("motion: give either keyframes or a sinusoid (amplitude, "
                             "frequency), not both or neither")
        if frames:
            times = [t for t, _ in frames]
            if not all(math.isfinite(v) for f in frames for v in f) or len(frames) < 2:
                raise ValueError(f"motion keyframes must be at least two finite [t, μ] pairs, "
                                 f"got {list(self.keyframes)!r}")
            if times[0] != 0 or frames[0][1] != 0:
                raise ValueError(f"motion keyframes must start at [0, 0] (the reference state), "
                                 f"got {list(frames[0])}")
            if any(b <= a for a, b in zip(times, times[1:], strict=False)):
                raise ValueError(f"motion keyframes' times must increase, got {times}")
        elif not (math.isfinite(self.amplitude) and math.isfinite(self.frequency)
                  and self.frequency > 0):
            raise ValueError(f"motion: amplitude must be finite and frequency finite and > 0 "
                             f"[Hz], got {self.amplitude!r}, {self.frequency!r}")

    def factor(self, t: float) -> float:
        """μ(t) at time t [s] ≥ 0."""
        if not self.keyframes:
            return self.amplitude * math.sin(2 * math.pi * self.frequency * t)
        times = [k for k, _ in self.keyframes]
        i = bisect.bisect_right(times, t)
        if i >= len(times):
            return self.keyframes[-1][1]
        (t0, m0), (t1, m1) = self.keyframes[i - 1], self.keyframes[i]
        return m0 + (m1 - m0) * (t - t0) / (t1 - t0)

    def to_dict(self) -> dict:
        if self.keyframes:
            return {"keyframes": [list(k) for k in self.keyframes]}
        return {"amplitude": self.amplitude, "frequency": self.frequency}


GROWTH = 1.25  # an adaptive step grows by this factor after `grow_after` easy steps


@dataclass(frozen=True)
class AdaptiveStep:
    """The step-size rule of an adaptive run (`[dynamics] adaptive = true`): start at dt; after
    `grow_after` consecutive steps that each converged unhalved in at most `easy_iterations`
    Newton iterations, h ← min(max_dt, GROWTH h); a step whose Newton does not converge is
    redone as two halves (the halving of every run) and the run goes on at h/2 (not below
    dt/2^halvings, the halving's floor); a step is shortened to land on the next output frame
    and the step size stays what it was. max_dt [s] ≥ dt."""

    max_dt: float
    easy_iterations: int = 4
    grow_after: int = 3

    def __post_init__(self):
        if not (math.isfinite(self.max_dt) and self.max_dt > 0):
            raise ValueError(f"max_dt must be finite and > 0 [s], got {self.max_dt!r}")
        for name in ("easy_iterations", "grow_after"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")

    def after(self, h: float, easy: int, iterations: int, substeps: int) -> tuple[float, int]:
        """(the next step size [s], the count of easy steps) after a step taken at size h
        with `iterations` Newton iterations over `substeps` substeps."""
        if substeps > 1:
            return 0.5 * h, 0
        if iterations > self.easy_iterations:
            return h, 0
        if easy + 1 >= self.grow_after:
            return min(self.max_dt, GROWTH * h), 0
        return h, easy + 1

    def to_dict(self) -> dict:
        return {"max_dt": self.max_dt, "easy_iterations": self.easy_iterations,
                "grow_after": self.grow_after, "growth": GROWTH}


@dataclass(frozen=True)
class DynamicsConfig:
    """integrator: one of INTEGRATORS; dt: the time step h [s] > 0; duration: the simulated
    time [s] ≥ dt (steps = round(duration / dt), which must be a whole number to 1e-9);
    frame_rate: output frames per second [1/s] (one frame every round(1 / (frame_rate dt))
    steps, at most one per step; None: the first and last state only); mass_damping: the
    mass-proportional Rayleigh coefficient α [1/s] ≥ 0 (damping force −α M v);
    stiffness_damping: the stiffness-proportional one β_R [s] ≥ 0 (force −β_R K₀ v, K₀ the
    shell's tangent stiffness at the start of each step, made positive semi-definite);
    load_ramp: the time [s] ≥ 0 over which the loads rise linearly from 0 to their full value,
    load factor λ(t) = min(1, t / load_ramp) (0: on in full from t = 0); halvings: how
    often a step whose Newton solve does not converge may be split in two halves, recursively,
    before the run fails; wind: the air's motion and drag (`Wind`) or None; motion: the
    prescribed boundary motion in time (`BoundaryMotion`) or None (the boundary held);
    adaptive: the step-size rule (`AdaptiveStep`, its max_dt ≥ dt) or None (every step dt;
    output frames stay at multiples of frame_every × dt either way)."""

    dt: float
    duration: float
    integrator: str = "implicit_euler"
    frame_rate: float | None = None
    mass_damping: float = 0.0
    stiffness_damping: float = 0.0
    load_ramp: float = 0.0
    halvings: int = 4
    wind: Wind | None = None
    motion: BoundaryMotion | None = None
    adaptive: AdaptiveStep | None = None

    def __post_init__(self):
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {self.integrator!r}")
        for name in ("dt", "duration"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0 [s], got {value!r}")
        if self.duration < self.dt * (1 - 1e-9):
            raise ValueError(f"duration ({self.duration} s) must be at least dt ({self.dt} s)")
        ratio = self.duration / self.dt
        if abs(ratio - round(ratio)) > 1e-9 * ratio:
            raise ValueError(f"duration ({self.duration} s) must be a whole number of steps of "
                             f"dt ({self.dt} s), got {ratio:.6g} steps")
        if self.frame_rate is not None:
            if not (math.isfinite(self.frame_rate) and self.frame_rate > 0):
                raise ValueError(f"frame_rate must be finite and > 0 [1/s], got "
                                 f"{self.frame_rate!r}")
            if self.frame_rate * self.dt > 1 + 1e-9:
                raise ValueError(f"frame_rate ({self.frame_rate} /s) asks for more than one frame "
                                 f"per step of dt = {self.dt} s")
        if not (math.isfinite(self.mass_damping) and self.mass_damping >= 0):
            raise ValueError(f"mass_damping must be finite and >= 0 [1/s], got "
                             f"{self.mass_damping!r}")
        if not (math.isfinite(self.stiffness_damping) and self.stiffness_damping >= 0):
            raise ValueError(f"stiffness_damping must be finite and >= 0 [s], got "
                             f"{self.stiffness_damping!r}")
        if not (math.isfinite(self.load_ramp) and self.load_ramp >= 0):
            raise ValueError(f"load_ramp must be finite and >= 0 [s], got {self.load_ramp!r}")
        if isinstance(self.halvings, bool) or not isinstance(self.halvings, int) or \
                self.halvings < 0:
            raise ValueError(f"halvings must be an integer >= 0, got {self.halvings!r}")
        if self.wind is not None and not isinstance(self.wind, Wind):
            raise ValueError(f"wind must be a Wind, got {self.wind!r}")
        if self.motion is not None and not isinstance(self.motion, BoundaryMotion):
            raise ValueError(f"motion must be a BoundaryMotion, got {self.motion!r}")
        if self.adaptive is not None and not (isinstance(self.adaptive, AdaptiveStep)
                                              and self.adaptive.max_dt >= self.dt):
            raise ValueError(f"adaptive: max_dt must be >= dt ({self.dt} s), got "
                             f"{getattr(self.adaptive, 'max_dt', self.adaptive)!r}")

    @property
    def steps(self) -> int:
        """The number of time steps."""
        return round(self.duration / self.dt)

    def load_factor(self, t: float) -> float:
        """λ(t) = min(1, t / load_ramp) (1 without a ramp) at time t [s]."""
        return 1.0 if self.load_ramp == 0 else min(1.0, t / self.load_ramp)

    def boundary_factor(self, t: float) -> float:
        """μ(t), the factor of the prescribed boundary motion at time t [s] (1 without a
        motion: a boundary without prescribed displacements)."""
        return 1.0 if self.motion is None else self.motion.factor(t)

    @property
    def frame_every(self) -> int | None:
        """Steps between output frames (None: no frame rate: first and last state only)."""
        if self.frame_rate is None:
            return None
        return max(1, round(1.0 / (self.frame_rate * self.dt)))

    def frame_times(self) -> list[float]:
        """The output frames' times [s] after t = 0: every frame_every × dt and the end."""
        every = self.frame_every or self.steps
        steps = list(range(every, self.steps, every)) + [self.steps]
        return [k * self.dt for k in steps]

    @property
    def frames(self) -> int:
        """The number of output frames: t = 0, every `frame_every` steps and the last."""
        every = self.frame_every or self.steps
        return 1 + self.steps // every + (1 if self.steps % every else 0)

    def to_dict(self) -> dict:
        return {"integrator": self.integrator, "dt": self.dt, "duration": self.duration,
                "frame_rate": self.frame_rate, "mass_damping": self.mass_damping,
                "stiffness_damping": self.stiffness_damping, "load_ramp": self.load_ramp,
                "halvings": self.halvings, "steps": self.steps,
                **({"wind": self.wind.to_dict()} if self.wind else {}),
                **({"motion": self.motion.to_dict()} if self.motion else {}),
                **({"adaptive": self.adaptive.to_dict()} if self.adaptive else {})}


def combine(coefficients, terms):
    """Σ c_i t_i: a linear map (coefficients) applied to states (terms, tensors [m, m/s, …])."""
    return sum(c * t for c, t in zip(coefficients, terms, strict=True))


@dataclass(frozen=True)
class StepMap:
    """One step of h [s] of the configured scheme as linear maps of the state (C, V, A): the one
    place the integrators' formulas are written (`taichi_ndf.solve.dynamics` steps with it,
    `taichi_ndf.solve.dynamics_adjoint` differentiates it).

    The step's end x minimises ½ s |x − x*|²_M + Π(x) with x* = x̂ − (α/s) ṽ, where
    - implicit Euler: x̂ = C + hV, ṽ = V, s = 1/h² + α/h; V' = (x − C)/h, A' = (V' − V)/h;
    - Newmark (β, γ): x̂ = C + hV + (½ − β)h²A, ṽ = V + (1 − γ)hA, s = 1/(βh²) + αγ/(βh);
      A' = (x − x̂)/(βh²), V' = ṽ + γhA'.
    scale s [1/s²]; rate r [1/s]: s = s₀ + α r, and the stiffness damping's coefficient is β_R r
    with origin x̂ − ṽ/r; predicted (x̂), carried (ṽ) and target (x*): coefficients on
    (C, V, A); velocity and acceleration: coefficients on (x, C, V, A)."""

    scale: float
    rate: float
    predicted: tuple[float, float, float]
    carried: tuple[float, float, float]
    target: tuple[float, float, float]
    velocity: tuple[float, float, float, float]
    acceleration: tuple[float, float, float, float]

    @classmethod
    def of(cls, config: DynamicsConfig, h: float) -> StepMap:
        alpha = config.mass_damping
        if config.integrator == "implicit_euler":
            inertia, rate = 1.0 / h**2, 1.0 / h
            predicted, carried = (1.0, h, 0.0), (0.0, 1.0, 0.0)
            velocity = (1.0 / h, -1.0 / h, 0.0, 0.0)
            acceleration = (1.0 / h**2, -1.0 / h**2, -1.0 / h, 0.0)
        else:
            beta, gamma = NEWMARK_BETA, NEWMARK_GAMMA
            inertia, rate = 1.0 / (beta * h**2), gamma / (beta * h)
            predicted = (1.0, h, (0.5 - beta) * h**2)
            carried = (0.0, 1.0, (1.0 - gamma) * h)
            acceleration = (inertia, *(-inertia * p for p in predicted))
            velocity = (gamma * h * inertia, *(v - gamma * h * inertia * p
                                               for p, v in zip(predicted, carried, strict=True)))
        scale = inertia + alpha * rate
        target = tuple(p - alpha / scale * v for p, v in zip(predicted, carried, strict=True))
        return cls(scale, rate, predicted, carried, target, velocity, acceleration)

    def apply(self, x, state):
        """(V', A') after the step from `state` (its displacement C, velocity V, acceleration
        A) that ended at x."""
        y = (x, state.displacement, state.velocity, state.acceleration)
        return combine(self.velocity, y), combine(self.acceleration, y)
