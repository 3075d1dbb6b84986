"""One Kratos Multiphysics solve of a shell benchmark, run as a child process by
benchmarks/fe_peer.py (issue 28). Needs KratosMultiphysics, KratosStructuralMechanicsApplication
and KratosLinearSolversApplication 10.4.4 (pip); not imported by the package or the tests.

    python benchmarks/fe_peer_kratos.py CASE NX NY

CASE: roof | cylinder | cantilever; NX × NY: quads of a structured mesh, NX along the first
surface coordinate of the case's scene (roof: the arc φ, cylinder: θ, cantilever: x), NY
along the second (y / z / y). Element ShellThinElementCorotational3D4N (thin, corotational),
LinearElasticPlaneStress2DLaw, Eigen's SparseLU (LinearSolversApplication).
The same geometry, material, loads and supports as the scenes in validation/scenes/:

- roof (scordelis_lo_roof.toml): R = 25, L = 50, φ ∈ [−40°, 40°], h = 0.25, E = 4.32e8, ν = 0,
  self-weight 90 per unit area (DENSITY 360 × h, VOLUME_ACCELERATION (0, 0, −1)); the curved ends
  y = 0, L on rigid diaphragms (u_x = u_z = 0), straight edges free. The axial rigid
  translation the diaphragms leave free is held by u_y = 0 at one node of the mid-span
  section (a symmetry plane of the problem: the exact solution has u_y = 0 there, so the
  reaction is zero). Linear static. Reads −u_z at (φ = 40°, y = L/2).
- cylinder (pinched_cylinder.toml): R = 300, L = 600, h = 3, E = 3e6, ν = 0.3, full
  cylinder (θ periodic: the ring closes on shared nodes), diaphragms at z = 0, L
  (u_x = u_y = 0), two unit radial loads inwards at (θ = 0, z = L/2) and (θ = π, z = L/2);
  u_z = 0 at one node of the mid-length section holds the axial translation (symmetry, as
  above). Linear static. Reads the mean inward radial displacement under the two loads.
- cantilever (cantilever_shear.toml): plate [0, 10] × [0, 1], h = 0.1, E = 1.2e6, ν = 0,
  clamped at x = 0 (displacements and rotations), a dead vertical force 4 λ spread along
  x = 10 by the trapezoidal rule over the edge nodes; Newton–Raphson over the scene's load
  factors 0.1, 0.25, 0.5, 0.75, 1 (each step from the last converged state; SUBSTEPS = 4
  increments per step gave the same values to 1e-13 with 117 Newton iterations against 34
  on 20 × 2 quads), displacement criterion 1e-10 relative. Reads W = u_z and −U = −u_x at
  (10, 0.5) at each load factor.

Prints one JSON line: {"case", "mesh", "dofs" (free unknowns), "values": {label: value},
"newton_iterations", "seconds": {"setup", "solve"}}.
"""

from __future__ import annotations

import json
import math
import sys
import time

CASES = ("roof", "cylinder", "cantilever")
CANTILEVER_STEPS = (0.1, 0.25, 0.5, 0.75, 1.0)  # cantilever_shear.toml's load_steps
READ_STEPS = (0.1, 0.5, 1.0)  # the load factors its case file reads
SUBSTEPS = 1  # increments per scene load step (Newton from the last converged state)


def _model(KM, SMA, thickness: float, young: float, poisson: float, density: float):
    """An empty 3D structural model part with displacement and rotation DOFs' variables."""
    model = KM.Model()
    mp = model.CreateModelPart("Structure")
    mp.SetBufferSize(2)
    mp.ProcessInfo[KM.DOMAIN_SIZE] = 3
    for var in (KM.DISPLACEMENT, KM.REACTION, KM.ROTATION, KM.REACTION_MOMENT,
                KM.VOLUME_ACCELERATION, SMA.POINT_LOAD):
        mp.AddNodalSolutionStepVariable(var)
    props = mp.GetProperties()[1]
    props.SetValue(KM.THICKNESS, thickness)
    props.SetValue(KM.YOUNG_MODULUS, young)
    props.SetValue(KM.POISSON_RATIO, poisson)
    props.SetValue(KM.DENSITY, density)
    props.SetValue(KM.CONSTITUTIVE_LAW, SMA.LinearElasticPlaneStress2DLaw())
    return model, mp, props


def _grid(mp, props, points, nx: int, ny: int, periodic_x: bool):
    """Nodes at points(i, j) (i < nx + 1, or nx where periodic_x: column nx is column 0) and
    nx × ny quads; returns the node-id function."""
    ncol = nx if periodic_x else nx + 1

    def nid(i: int, j: int) -> int:
        return (i % ncol) + j * ncol + 1

    for j in range(ny + 1):
        for i in range(ncol):
            x, y, z = points(i, j)
            mp.CreateNewNode(nid(i, j), x, y, z)
    eid = 1
    for j in range(ny):
        for i in range(nx):
            mp.CreateNewElement("ShellThinElementCorotational3D4N", eid,
                                [nid(i, j), nid(i + 1, j), nid(i + 1, j + 1), nid(i, j + 1)],
                                props)
            eid += 1
    return nid


def _add_dofs(KM, mp) -> None:
    for c in "XYZ":
        KM.VariableUtils().AddDof(getattr(KM, f"DISPLACEMENT_{c}"),
                                  getattr(KM, f"REACTION_{c}"), mp)
        KM.VariableUtils().AddDof(getattr(KM, f"ROTATION_{c}"),
                                  getattr(KM, f"REACTION_MOMENT_{c}"), mp)


def _fix(KM, node, names: str) -> None:
    for name in names.split():
        node.Fix(getattr(KM, name))


def _point_load(SMA, mp, props, cid: int, node_id: int, force) -> None:
    cond = mp.CreateNewCondition("PointLoadCondition3D1N", cid, [node_id], props)
    cond.SetValue(SMA.POINT_LOAD, force)


def _strategy(KM, SMA, mp, nonlinear: bool):
    import KratosMultiphysics.LinearSolversApplication  # noqa: F401  (registers sparse_lu)
    from KratosMultiphysics import python_linear_solver_factory

    solver = python_linear_solver_factory.ConstructSolver(
        KM.Parameters('{"solver_type": "sparse_lu"}'))
    scheme = KM.ResidualBasedIncrementalUpdateStaticScheme()
    builder = KM.ResidualBasedBlockBuilderAndSolver(solver)
    if nonlinear:
        criterion = KM.DisplacementCriteria(1e-10, 1e-14)
        criterion.SetEchoLevel(0)
        strategy = KM.ResidualBasedNewtonRaphsonStrategy(mp, scheme, criterion, builder, 50,
                                                         False, False, True)
    else:
        strategy = KM.ResidualBasedLinearStrategy(mp, scheme, builder, False, False, False,
                                                  False)
    strategy.SetEchoLevel(0)
    strategy.Initialize()
    strategy.Check()
    return strategy


def _free_dofs(KM, mp) -> int:
    """The unknowns the linear system solves for: 6 per node less the fixed ones."""
    names = [f"{v}_{c}" for v in ("DISPLACEMENT", "ROTATION") for c in "XYZ"]
    return sum(1 for node in mp.Nodes for n in names if not node.IsFixed(getattr(KM, n)))


def roof(KM, SMA, nx: int, ny: int) -> tuple:
    R, L, half, h = 25.0, 50.0, math.radians(40.0), 0.25
    model, mp, props = _model(KM, SMA, h, 4.32e8, 0.0, 90.0 / h)

    def point(i, j):
        phi = -half + 2.0 * half * i / nx
        return R * math.sin(phi), L * j / ny, R * math.cos(phi)

    nid = _grid(mp, props, point, nx, ny, periodic_x=False)
    _add_dofs(KM, mp)
    for node in mp.Nodes:
        node.SetSolutionStepValue(KM.VOLUME_ACCELERATION, [0.0, 0.0, -1.0])
    for i in range(nx + 1):
        for j in (0, ny):
            _fix(KM, mp.GetNode(nid(i, j)), "DISPLACEMENT_X DISPLACEMENT_Z")
    _fix(KM, mp.GetNode(nid(nx // 2, ny // 2)), "DISPLACEMENT_Y")
    probe = mp.GetNode(nid(nx, ny // 2))
    return model, mp, False, {"-u_z @ 1": lambda: -probe.GetSolutionStepValue(KM.DISPLACEMENT_Z)}


def cylinder(KM, SMA, nx: int, ny: int) -> tuple:
    R, L = 300.0, 600.0
    model, mp, props = _model(KM, SMA, 3.0, 3.0e6, 0.3, 1.0)

    def point(i, j):
        theta = 2.0 * math.pi * i / nx
        return R * math.cos(theta), R * math.sin(theta), L * j / ny

    nid = _grid(mp, props, point, nx, ny, periodic_x=True)
    _add_dofs(KM, mp)
    for i in range(nx):
        for j in (0, ny):
            _fix(KM, mp.GetNode(nid(i, j)), "DISPLACEMENT_X DISPLACEMENT_Y")
    _fix(KM, mp.GetNode(nid(nx // 4, ny // 2)), "DISPLACEMENT_Z")
    a, b = mp.GetNode(nid(0, ny // 2)), mp.GetNode(nid(nx // 2, ny // 2))
    _point_load(SMA, mp, props, 1, a.Id, [-1.0, 0.0, 0.0])
    _point_load(SMA, mp, props, 2, b.Id, [1.0, 0.0, 0.0])

    def u_r():
        return 0.5 * (-a.GetSolutionStepValue(KM.DISPLACEMENT_X)
                      + b.GetSolutionStepValue(KM.DISPLACEMENT_X))

    return model, mp, False, {"u_r @ 1": u_r}


def cantilever(KM, SMA, nx: int, ny: int) -> tuple:
    model, mp, props = _model(KM, SMA, 0.1, 1.2e6, 0.0, 1.0)
    nid = _grid(mp, props, lambda i, j: (10.0 * i / nx, 1.0 * j / ny, 0.0), nx, ny,
                periodic_x=False)
    _add_dofs(KM, mp)
    for j in range(ny + 1):
        _fix(KM, mp.GetNode(nid(0, j)), "DISPLACEMENT_X DISPLACEMENT_Y DISPLACEMENT_Z "
                                        "ROTATION_X ROTATION_Y ROTATION_Z")
    loads = []
    for j in range(ny + 1):
        weight = (0.5 if j in (0, ny) else 1.0) / ny  # trapezoidal rule, total 1 per unit λ
        _point_load(SMA, mp, props, j + 1, nid(nx, j), [0.0, 0.0, 0.0])
        loads.append((mp.GetCondition(j + 1), 4.0 * weight))
    tip = mp.GetNode(nid(nx, ny // 2))
    reads = {"W": lambda: tip.GetSolutionStepValue(KM.DISPLACEMENT_Z),
             "-U": lambda: -tip.GetSolutionStepValue(KM.DISPLACEMENT_X)}
    return model, mp, loads, reads


def main(argv: list[str]) -> int:
    if len(argv) != 3 or argv[0] not in CASES or not all(a.isdigit() for a in argv[1:]):
        print(f"usage: fe_peer_kratos.py {{{'|'.join(CASES)}}} NX NY", file=sys.stderr)
        return 2
    case, nx, ny = argv[0], int(argv[1]), int(argv[2])
    if nx < 2 or ny < 2 or nx % 2 or ny % 2 or (case == "cylinder" and nx % 4):
        print("fe_peer_kratos.py: NX and NY must be even and >= 2 (cylinder: NX a multiple "
              "of 4), so that nodes sit at the probes", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    import KratosMultiphysics as KM
    import KratosMultiphysics.StructuralMechanicsApplication as SMA

    KM.Logger.GetDefaultOutput().SetSeverity(KM.Logger.Severity.WARNING)
    model, mp, loads, reads = {"roof": roof, "cylinder": cylinder,
                               "cantilever": cantilever}[case](KM, SMA, nx, ny)
    strategy = _strategy(KM, SMA, mp, nonlinear=bool(loads))
    t1 = time.perf_counter()
    values, iterations = {}, 0
    if not loads:
        mp.CloneTimeStep(1.0)
        strategy.Solve()
        iterations = 1
        values = {label: read() for label, read in reads.items()}
    else:
        previous, step = 0.0, 0
        for target in CANTILEVER_STEPS:
            for k in range(1, SUBSTEPS + 1):
                lam = previous + (target - previous) * k / SUBSTEPS
                step += 1
                mp.CloneTimeStep(float(step))
                for cond, weight in loads:
                    cond.SetValue(SMA.POINT_LOAD, [0.0, 0.0, weight * lam])
                strategy.Solve()
                iterations += mp.ProcessInfo[KM.NL_ITERATION_NUMBER]
                if not strategy.IsConverged():
                    print(json.dumps({"case": case, "error": f"Newton did not converge at "
                                      f"load {lam:g}"}))
                    return 1
            previous = target
            if target in READ_STEPS:
                for label, read in reads.items():
                    values[f"{label} @ {target:g}"] = read()
    t2 = time.perf_counter()
    print(json.dumps({"case": case, "mesh": [nx, ny], "dofs": _free_dofs(KM, mp), "values": values,
                      "newton_iterations": iterations,
                      "seconds": {"setup": t1 - t0, "solve": t2 - t1}}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
