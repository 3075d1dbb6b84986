"""`ndf-fit-material` refuses bad input with a clear message, before any training."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from inverse.cli.fit_material import main
from taichi_ndf.io import write_obj

SCENE = str(Path(__file__).parents[1] / "scenes" / "inverse" / "cantilever_strip.toml")


def _mesh(path, vertices):
    write_obj(path, np.asarray(vertices, dtype=float), np.array([[0, 1, 2]]))
    return str(path)


def _run(capsys, *argv):
    code = main(["--scene", SCENE, *argv])
    return code, capsys.readouterr().err


def test_unknown_parameter_name(tmp_path, capsys):
    obs = _mesh(tmp_path / "o.obj", np.eye(3))
    code, err = _run(capsys, "--observed", obs, "--estimate", "bendy", "--out",
                     str(tmp_path / "out"))
    assert code == 2 and "unknown parameter 'bendy'" in err


def test_vertex_count_differs_from_the_template(tmp_path, capsys):
    obs = _mesh(tmp_path / "o.obj", np.eye(3))
    code, err = _run(capsys, "--observed", obs, "--estimate", "bending", "--out",
                     str(tmp_path / "out"))
    assert code == 2 and "has 3 vertices" in err and "--point-cloud" in err


def test_unreadable_observation(tmp_path, capsys):
    bad = tmp_path / "o.ply"
    bad.write_text("not a mesh")
    code, err = _run(capsys, "--observed", str(bad), "--estimate", "bending", "--out",
                     str(tmp_path / "out"))
    assert code == 2 and "cannot read observation" in err
    code, err = _run(capsys, "--observed", str(tmp_path / "missing.obj"), "--estimate",
                     "bending", "--out", str(tmp_path / "out2"))
    assert code == 2 and "not found" in err


def test_existing_non_empty_output_directory(tmp_path, capsys):
    obs = _mesh(tmp_path / "o.obj", np.eye(3))
    out = tmp_path / "out"
    out.mkdir()
    (out / "x").write_text("")
    code, err = _run(capsys, "--observed", obs, "--estimate", "bending", "--out", str(out))
    assert code == 2 and "not empty" in err


def test_bilevel_refuses_load_unknowns(tmp_path, capsys):
    obs = _mesh(tmp_path / "o.obj", np.eye(3))
    code, err = _run(capsys, "--observed", obs, "--point-cloud", "--estimate", "gravity",
                     "--method", "bilevel", "--out", str(tmp_path / "out"))
    assert code == 2 and "residual method" in err


def test_bilevel_refuses_a_spline_field(tmp_path, capsys):
    """The conditioned field is a SIREN with the scene's [field] architecture: a spline scene
    is refused in one line (on main: AttributeError 'SplinePlan' object has no attribute
    'width', after the observations were read)."""
    text = Path(SCENE).read_text()
    field, probes = text.index("[field]"), text.index("[[probes]]")
    scene = tmp_path / "strip_spline.toml"
    scene.write_text(text[:field] + '[field]\ntype = "spline"\n\n' + text[probes:])
    obs = _mesh(tmp_path / "o.obj", np.eye(3))
    code = main([str(scene), "--observed", obs, "--point-cloud", "--estimate", "bending",
                 "--method", "bilevel", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "is not a SIREN" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_bilevel_refuses_a_scene_with_further_energy_terms(tmp_path, capsys):
    """The conditioned field's energy is the shell's alone: a scene whose [[terms]] add a
    foundation is refused in one line rather than fitted without it."""
    text = Path(SCENE).read_text()
    probes = text.index("[[probes]]")
    scene = tmp_path / "strip_foundation.toml"
    scene.write_text(text[:probes] + '[[terms]]\ntype = "foundation"\nstiffness = 1.0e3\n\n'
                     + text[probes:])
    obs = _mesh(tmp_path / "o.obj", np.eye(3))
    code = main([str(scene), "--observed", obs, "--point-cloud", "--estimate", "bending",
                 "--method", "bilevel", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "[[terms]]" in err and "FoundationTerm" in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_negative_newton_steps_and_band(tmp_path, capsys):
    obs = _mesh(tmp_path / "o.obj", np.eye(3))
    for option, value in (("--newton", "-1"), ("--band", "0")):
        code, err = _run(capsys, "--observed", obs, "--point-cloud", "--estimate", "bending",
                         "--out", str(tmp_path / f"out{option}"), option, value)
        assert code == 2 and f"{option} must be" in err, err


@pytest.mark.slow
def test_end_to_end_writes_estimate_and_overlay(tmp_path):
    """The material demo (quick: observation on 20 × 4 quartic spans). Issue 35: its SIREN
    observation was under-solved and the estimate 0.0161216 ± 7e-5 N·m lay 6 standard errors
    from the true B; now the observation's stated error is far below the noise and the error
    bar holds the truth (measured: 0.0157721 ± 6.7e-5 against 0.015696, 1.1 s.e.)."""
    import json
    import re
    import subprocess
    import sys

    demo = Path(__file__).parents[1] / "demos" / "fit_material.py"
    done = subprocess.run([sys.executable, str(demo), "--quick", "--out", str(tmp_path / "run")],
                          check=True, capture_output=True, text=True)
    stated = re.search(r"largest position error (\S+) m .* noise σ = (\S+) m", done.stdout)
    assert stated, done.stdout
    assert float(stated[1]) < 0.01 * float(stated[2])
    document = json.loads((tmp_path / "run" / "estimate" / "estimate.json").read_text())
    entry = document["parameters"]["bending_stiffness"]
    truth = 0.2 * 9.81 * 0.2**3
    assert entry["determined"] and abs(entry["value"] - truth) < 3 * entry["standard_error"]
    assert document["goodness_of_fit"]["explains_data"] is True
    assert document["method"] == "newton"
    assert (tmp_path / "run" / "estimate" / "overlay.png").stat().st_size > 0


class WorkStarted(Exception):
    """Raised by the stubbed estimators: the command got past its checks into the work."""


def _stubbed(monkeypatch):
    import inverse.cli.fit_material_run as fit

    def started(*args, **kwargs):
        raise WorkStarted

    for name in ("newton_estimate", "implicit_estimate", "bilevel_estimate", "_observations"):
        monkeypatch.setattr(fit, name, started)


@pytest.mark.parametrize("method, options, message", [
    ("newton", ["--spans", "20000", "20000"], "finest grid (2 levels) of 40000 × 40000 spans"),
    ("implicit", ["--width", "100000", "--samples", "100000"],
     "SIREN field 100000 wide × 2 layers on 100000 samples"),
])
def test_absurd_sizes_are_refused_before_any_work(tmp_path, capsys, monkeypatch, method,
                                                  options, message):
    """The fit's largest solve against the machine's memory, the check ndf-sim makes
    (taichi_ndf.problem.run_size), before the observations are read: on main --spans 20000 20000
    read them and started the fit."""
    _stubbed(monkeypatch)
    code, err = _run(capsys, "--observed", str(tmp_path / "o.obj"), "--estimate", "bending",
                     "--method", method, "--out", str(tmp_path / "out"), *options)
    assert code == 2, err
    (line,) = err.strip().splitlines()
    assert message in line and "GiB of memory" in line and "choose" in line


@settings(max_examples=25, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(method=st.sampled_from(["newton", "implicit", "bilevel"]),
       spans=st.integers(1, 10**5), width=st.integers(1, 10**6), samples=st.integers(1, 10**7))
def test_fuzzed_sizes_are_refused_in_one_line_or_reach_the_work(tmp_path_factory, monkeypatch,
                                                                 method, spans, width, samples):
    """Sizes either pass the memory check (the stubbed fit is reached) or are refused in one
    line with the estimate, exit 2, no traceback."""
    import contextlib
    import io

    _stubbed(monkeypatch)
    out = tmp_path_factory.mktemp("fit") / "out"
    err = io.StringIO()
    argv = ["--scene", SCENE, "--observed", str(out.parent / "o.obj"), "--estimate", "bending",
            "--method", method, "--out", str(out), "--spans", str(spans), str(spans),
            "--width", str(width), "--samples", str(samples)]
    with contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except WorkStarted:
            return
    assert code == 2
    (line,) = err.getvalue().strip().splitlines()
    assert "needs about" in line and "GiB" in line
