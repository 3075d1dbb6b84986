"""Property-based fuzzing of every user input: shipped scenes, template meshes, camera JSON and
checkpoints, mutated (keys deleted, duplicated or retyped; NaN, infinite, huge numbers; text
and bytes truncated or flipped).

The property: a tool either succeeds or exits with code 2 and one line on stderr (no
traceback), and an output directory that was there is left unchanged.

What is covered, and how:
- Scenes and meshes go through `ndf-sim`'s whole command line in-process (parsing, validation,
  memory estimate, output-directory checks) with `simulate` replaced by a stub: a real run per
  example would take seconds to minutes. Training on accepted inputs is not fuzzed.
- Camera JSON goes through `camera_from_json` and `load_camera` (all of `ndf-sft`'s camera
  checks); the sft pipeline behind them is not run.
- Checkpoints (bytes and payload entries) go through `ndf-export` in-process, end to end
  (a 4 x 4 export on success).
- A handful of real subprocess runs check the installed entry points: a mutated scene refused,
  a damaged checkpoint refused, a quick run that succeeds, and Ctrl-C (SIGINT) during a run.
"""

from __future__ import annotations

import copy
import io
import json
import math
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import pytest
import torch
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from test_cli import RUNTIME, small_napkin

from taichi_ndf.app import simulation
from taichi_ndf.cli import export, sim

ROOT = Path(__file__).resolve().parents[1]
# Every shipped scene but the bowl (its template takes seconds to fit).
SCENES = sorted(p for p in (ROOT / "scenes").rglob("*.toml") if p.name != "bowl.toml")


def fuzz_settings(examples: int) -> settings:
    """Reproducible (derandomised, no example database) and bounded."""
    return settings(max_examples=examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])

ODD_VALUES = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e-308, 10**18,
                              -(10**18), 0, -1, 0.5, "text", "", True, False, [], [1.0],
                              [[0.0, 1.0]], {}, {"x": 1}])


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"


def toml_text(document: dict) -> str:
    """TOML for a document whose tables are all written inline (tomllib reads it back)."""
    return "".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in document.items())


def paths(value, prefix=()):
    """Every (key or index) path inside nested dicts and lists."""
    items = (value.items() if isinstance(value, dict)
             else enumerate(value) if isinstance(value, list) else ())
    for key, item in items:
        yield (*prefix, key)
        yield from paths(item, (*prefix, key))


@st.composite
def mutated(draw, document):
    """`document` (nested dicts and lists) after 1-3 deletions, duplications or retypings."""
    document = json.loads(json.dumps(document))
    for _ in range(draw(st.integers(1, 3))):
        targets = list(paths(document))
        if not targets:
            break
        *parent_path, key = draw(st.sampled_from(targets))
        parent = document
        for step in parent_path:
            parent = parent[step]
        operation = draw(st.sampled_from(["delete", "duplicate", "retype"]))
        if operation == "delete":
            del parent[key]
        elif operation == "duplicate":
            if isinstance(parent, list):
                parent.append(json.loads(json.dumps(parent[key])))
            else:
                parent[f"{key}_copy"] = json.loads(json.dumps(parent[key]))
        else:
            parent[key] = copy.deepcopy(draw(ODD_VALUES))
    return document


def run_tool(main, argv) -> tuple[int, str]:
    """Exit code and stderr of an in-process tool run."""
    err = io.StringIO()
    with mock.patch.object(sys, "stderr", err), mock.patch.object(sys, "stdout", io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as stop:  # argparse
            code = stop.code
    return code, err.getvalue()


def assert_clean(code, err):
    event(f"exit {code}")
    assert code in (0, 2), (code, err)
    assert "Traceback" not in err, err
    if code == 2:
        assert len(err.strip().splitlines()) == 1, err


def fake_simulate(scene, out, **kwargs):
    return {"energy": 0.0, "iterations": 0, "wall_time": 0.0, "probes": {}}


def sim_refuses_or_accepts(scene_path: Path, folder: Path, existing: bool,
                           extra: tuple[str, ...] = ()) -> int:
    """ndf-sim on `scene_path` up to the solve: success, or a one-line refusal that leaves an
    earlier output directory (`existing`) unchanged and creates none; returns the exit code
    the scene alone gets (0 or 2)."""
    out = folder / "run"
    if existing:  # refused as not empty once the scene passes: every check before is run
        out.mkdir()
        (out / "result.json").write_text("previous run")
    with mock.patch.object(simulation, "simulate", fake_simulate):
        code, err = run_tool(sim.main, [str(scene_path), "--out", str(out), *extra, *RUNTIME])
    assert_clean(code, err)
    if existing:
        assert code == 2 and (out / "result.json").read_text() == "previous run"
        assert sorted(p.name for p in out.iterdir()) == ["result.json"]
    else:
        assert out.exists() == (code == 0)
    assert not (folder / "run.incomplete").exists()
    return 0 if existing and "not empty" in err else code


@pytest.mark.parametrize("scene", SCENES, ids=[p.stem for p in SCENES])
def test_shipped_scenes_pass_the_command_line_checks(tmp_path, scene):
    out = tmp_path / "run"
    with mock.patch.object(simulation, "simulate", fake_simulate):
        code, err = run_tool(sim.main, [str(scene), "--out", str(out), *RUNTIME])
    assert code == 0, err


@fuzz_settings(150)
@given(data=st.data())
def test_mutated_scenes_are_refused_in_one_line(data):
    import tomllib

    source = data.draw(st.sampled_from(SCENES))
    document = data.draw(mutated(tomllib.loads(source.read_text())))
    text = toml_text(document)
    if data.draw(st.booleans()):  # now and then a truncated file
        text = text[: data.draw(st.integers(0, len(text)))]
    existing = data.draw(st.booleans())
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "data").symlink_to(ROOT / "data")  # the meshes, at the scenes' ../data
        scene = folder / source.relative_to(ROOT)
        scene.parent.mkdir(parents=True, exist_ok=True)
        scene.write_text(text)
        sim_refuses_or_accepts(scene, folder, existing)


NAPKIN_MESH = (ROOT / "data" / "napkin.obj").read_text().splitlines()


# A scene with every spline, contact and line-load key set, on a plane and on a cylinder (whose
# ξ1 is periodic: its "edges" xi1_min / xi1_max do not exist).
KEYED_PLANE = {
    "name": "keyed",
    "geometry": {"type": "plane", "bounds": [[0.0, 1.0], [0.0, 1.0]]},
    "material": {"preset": "cloth"},
    "loads": {"gravity": [0.0, 0.0, -9.81],
              "line": [{"edge": "xi1_max", "force": [0.0, 0.0, -1.0], "nodes": 8},
                       {"path": [[0.2, 0.5], [0.8, 0.5]], "force": [0.0, 0.0, -1.0]}]},
    "boundary": {"constraint": [{"type": "clamped_edge", "edge": "xi1_min"}]},
    "obstacles": [{"type": "sphere", "centre": [0.5, 0.5, -0.3], "radius": 0.2}],
    "contact": {"check_resolution": 32, "activation_distance": "auto", "stiffness": "auto",
                "margin": "auto"},
    "field": {"type": "spline", "degree": 3, "spans": [8, 8], "levels": 1,
              "quadrature_points": 4, "grading": "features"},
    "training": {"method": "newton", "load_steps": [0.5, 1.0], "newton_max_iterations": 5},
    "output": {"resolution": [8, 8]},
}
KEYED_CYLINDER = {**KEYED_PLANE, "geometry": {"type": "cylinder", "radius": 0.1, "length": 0.4},
                  "boundary": {"constraint": [{"type": "clamped_edge", "edge": "xi2_min"}]},
                  "loads": {"line": [{"edge": "xi2_max", "force": [0.0, 0.0, -1.0]}]}}
# Values for those keys: absurd sizes (the memory check), edges, and the odd values.
SIZE_VALUES = st.sampled_from([[1, 1], [2, 2], [10000, 10000], [2000, 2000], [3, 10**9], 20, 30,
                               1e-5, 1e-300, 1000000, 10**9, "xi1_min", "xi2_max", "auto"])
KEYED_TARGETS = [("field", "spans"), ("field", "levels"), ("field", "span_length"),
                 ("field", "degree"), ("field", "quadrature_points"), ("field", "grading"),
                 ("contact", "check_resolution"), ("contact", "stiffness"),
                 ("obstacles", 0, "radius"), ("loads", "line", 0, "edge"),
                 ("loads", "line", 0, "nodes"), ("loads", "line", 0, "force"),
                 ("training", "newton_max_iterations"), ("training", "load_steps"),
                 ("output", "resolution")]


def set_keys(draw, document: dict, targets, values, counts=(1, 3)) -> tuple[dict, str | None]:
    """`document` (copied) with `counts` (least, most) of the key paths `targets` set to a
    value drawn from `values` or (one in six) deleted; returns it and the last key drawn."""
    document = json.loads(json.dumps(document))
    key = None
    for _ in range(draw(st.integers(*counts))):
        *parents, key = draw(st.sampled_from(targets))
        parent = document
        try:
            for step in parents:
                parent = parent[step]
            parent[key]  # noqa: B018 - the path exists in this document
        except (KeyError, IndexError, TypeError):
            continue
        if draw(st.integers(0, 5)) == 0:
            del parent[key]
        else:
            parent[key] = copy.deepcopy(draw(values))
    return document, key


@st.composite
def keyed_scene(draw):
    """KEYED_PLANE or KEYED_CYLINDER with 1-3 of its spline / contact / line-load keys set to
    a size or odd value (or deleted), and now and then mutated further."""
    document, key = set_keys(draw, draw(st.sampled_from([KEYED_PLANE, KEYED_CYLINDER])),
                             KEYED_TARGETS, st.one_of(SIZE_VALUES, ODD_VALUES))
    if key == "span_length" and "spans" in document.get("field", {}):
        del document["field"]["spans"]  # so that span_length is read
    return draw(mutated(document)) if draw(st.integers(0, 3)) == 0 else document


@fuzz_settings(120)
@given(document=keyed_scene(), refine=st.sampled_from([None, "1", "3", "30", "0", "-1"]),
       existing=st.booleans())
def test_spline_contact_and_line_load_keys_are_refused_in_one_line(document, refine,
                                                                   existing):
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        scene = folder / "keyed.toml"
        scene.write_text(toml_text(document))
        extra = () if refine is None else ("--refine", refine)
        accepted = sim_refuses_or_accepts(scene, folder, existing, extra) == 0
    assert not (accepted and periodic_edge_load(document)), "a load on a periodic edge passed"


def periodic_edge_load(document: dict) -> bool:
    """Whether `document` is a cylinder (ξ1 periodic) with a line load on an edge of ξ1."""
    def table(value, key):
        item = value.get(key) if isinstance(value, dict) else None
        return item if isinstance(item, (dict, list)) else {}

    lines = table(table(document, "loads"), "line")
    return table(document, "geometry").get("type") == "cylinder" and any(
        isinstance(line, dict) and str(line.get("edge", "")).startswith("xi1")
        for line in (lines if isinstance(lines, list) else []))



@st.composite
def mutated_mesh(draw) -> str:
    lines = list(NAPKIN_MESH)
    for _ in range(draw(st.integers(1, 4))):
        if not lines:
            break
        i = draw(st.integers(0, len(lines) - 1))
        operation = draw(st.sampled_from(["delete", "duplicate", "number", "truncate"]))
        if operation == "delete":
            del lines[i]
        elif operation == "duplicate":
            lines.insert(i, lines[i])
        elif operation == "number" and len(lines[i].split()) > 1:
            parts = lines[i].split()
            j = draw(st.integers(1, len(parts) - 1))
            parts[j] = draw(st.sampled_from(["nan", "inf", "1e308", "-1", "0", "x", "1/1/1",
                                             "999999", "2.5"]))
            lines[i] = " ".join(parts)
        elif operation == "truncate":
            lines = lines[:i]
    return "\n".join(lines) + "\n"


@fuzz_settings(60)
@given(text=mutated_mesh(), existing=st.booleans())
def test_mutated_template_meshes_are_refused_in_one_line(text, existing):
    template = (ROOT / "scenes" / "napkin_template.toml").read_text()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "mesh.obj").write_text(text)
        scene = folder / "scene.toml"
        scene.write_text(template.replace("../data/napkin.obj", "mesh.obj"))
        assert "mesh.obj" in scene.read_text()
        sim_refuses_or_accepts(scene, folder, existing)


CAMERA = {"fx": 600.0, "fy": 610.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480,
          "dist": [0.0, 0.0, 0.0, 0.0, 0.0], "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
          "t": [0.0, 0.0, 1.0]}


@fuzz_settings(150)
@given(data=st.data())
def test_mutated_camera_json_is_refused_in_one_line(data):
    from inverse.sft.inputs import Camera, InputError, load_camera

    document = data.draw(mutated(CAMERA))
    text = json.dumps(document)
    if data.draw(st.booleans()):
        text = text[: data.draw(st.integers(0, len(text)))]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "camera.json"
        path.write_text(text)
        try:
            camera = load_camera(path)
        except InputError as err:
            assert len(str(err).splitlines()) == 1 and str(path) in str(err)
        else:
            assert isinstance(camera, Camera)
            assert all(math.isfinite(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))


@pytest.fixture(scope="module")
def checkpoint_bytes(tmp_path_factory) -> bytes:
    folder = tmp_path_factory.mktemp("fuzz-checkpoint")
    assert sim.main([str(small_napkin(folder)), "--out", str(folder / "run"), "--iters", "1",
                     *RUNTIME]) == 0
    return (folder / "run" / "checkpoint.pt").read_bytes()


@st.composite
def damaged_checkpoint(draw, good: bytes) -> bytes:
    kind = draw(st.sampled_from(["truncate", "flip", "payload"]))
    if kind == "truncate":
        return good[: draw(st.integers(0, len(good) - 1))]
    if kind == "flip":
        data = bytearray(good)
        for _ in range(draw(st.integers(1, 8))):
            data[draw(st.integers(0, len(data) - 1))] ^= draw(st.integers(1, 255))
        return bytes(data)
    payload = torch.load(io.BytesIO(good), weights_only=True)
    target = draw(st.sampled_from(["kind", "format_version", "architecture", "parameters",
                                   "optimiser", "extra"]))
    if draw(st.booleans()):
        del payload[target]
    elif isinstance(payload[target], dict) and payload[target] and draw(st.booleans()):
        key = draw(st.sampled_from(sorted(payload[target])))
        payload[target][key] = copy.deepcopy(draw(ODD_VALUES))
    else:
        payload[target] = copy.deepcopy(draw(ODD_VALUES))
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return buffer.getvalue()


@fuzz_settings(50)
@given(data=st.data())
def test_damaged_checkpoints_are_refused_in_one_line(data, checkpoint_bytes):
    damaged = data.draw(damaged_checkpoint(checkpoint_bytes))
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "checkpoint.pt").write_bytes(damaged)
        mesh = folder / "mesh.obj"
        code, err = run_tool(export.main, [str(folder / "checkpoint.pt"), "--resolution", "4",
                                           "--out", str(mesh), *RUNTIME])
        assert_clean(code, err)
        assert mesh.exists() == (code == 0)


# -- real processes ---------------------------------------------------------------------------

def tool(module: str, *args, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, *map(str, args)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def test_real_processes_refuse_in_one_line_succeed_and_stop_on_ctrl_c(tmp_path,
                                                                     checkpoint_bytes):
    bad_scene = small_napkin(tmp_path, name="bad.toml")
    bad_scene.write_text(bad_scene.read_text().replace("width = 16", "width = nan"))
    broken = tmp_path / "broken.pt"
    broken.write_bytes(checkpoint_bytes[:1000])
    previous = tmp_path / "previous"
    previous.mkdir()
    (previous / "result.json").write_text("previous run")
    refusals = [tool("taichi_ndf.cli.sim", bad_scene, "--out", previous, "--overwrite"),
                tool("taichi_ndf.cli.export", broken, "--out", tmp_path / "m.obj")]
    for process, name in zip(refusals, ("field.width", str(broken)), strict=True):
        _, err = process.communicate(timeout=300)
        assert process.returncode == 2 and name in err, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert (previous / "result.json").read_text() == "previous run"
    assert not (tmp_path / "m.obj").exists()

    # A quick run that succeeds, and beside it one stopped by Ctrl-C (SIGINT) once it has
    # written its first checkpoint.
    scene = small_napkin(tmp_path)
    long = small_napkin(tmp_path, name="long.toml")
    long.write_text(long.read_text().replace("iterations = 10", "iterations = 100000"))
    done = tool("taichi_ndf.cli.sim", scene, "--out", tmp_path / "quick", "--iters", "2")
    # As from a terminal: a suite started in the background (`cmd &` without job control)
    # hands its children SIGINT ignored, and Python then never raises KeyboardInterrupt.
    running = tool("taichi_ndf.cli.sim", long, "--out", tmp_path / "long",
                   preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    _, err = done.communicate(timeout=300)
    assert done.returncode == 0, err
    assert json.loads((tmp_path / "quick" / "result.json").read_text())["iterations"] == 2

    staged = tmp_path / "long.incomplete" / "checkpoint.pt"
    deadline = time.monotonic() + 600
    while not staged.exists() and running.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    running.send_signal(signal.SIGINT)
    try:
        _, err = running.communicate(timeout=300)
    finally:
        running.kill()  # never leave it training if the assertion below fails
    assert running.returncode == 130, err
    # The one line naming the interruption is the last; before it only warnings (the small
    # napkin's point pin leaves a rotation that only its held slope holds: a warning line).
    lines = err.strip().splitlines()
    assert lines[-1] == (
        f"ndf-sim: interrupted; the last checkpoint is in {staged.parent} (continue with "
        "--resume)"), err
    assert all(line.startswith("WARNING") for line in lines[:-1]), err
    assert not (tmp_path / "long").exists()
