"""The study cache (taichi_ndf.sweep.cache) and the calibration job's use of it: a cached case
fits bit-identically to a built one, concurrent writers never leave a torn or mixed entry, and
a case with other parameters (or other code) never reuses an entry."""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import pytest
import torch

import inverse.material.calibration as calibration
from inverse.cli import calibration_draw
from inverse.cli.calibration_draw import build_case, case_key
from taichi_ndf.sweep import cache
from taichi_ndf.sweep.jobs import JOBS


def _fake_solve(calls: list):
    """A stand-in for the minutes-long converged_observation: positions of the right shape
    (a non-contiguous view, as a solver's output may be), order nan (a non-converging
    Richardson check), error 1e-5 m."""
    def solve(model, unknowns, truth, points, spans):
        calls.append(spans)
        positions = torch.cat([points, torch.zeros(len(points), 1)], dim=1).double()
        return positions.t().contiguous().t() + 1e-3 * len(calls), math.nan, 1e-5
    return solve


def test_cached_strip_fits_bit_identically(tmp_path, monkeypatch):
    built = build_case("strip", (40, 40))
    stored = build_case("strip", (40, 40), tmp_path)  # solves and stores
    assert len(list(tmp_path.glob("strip-*.npz"))) == 1

    def no_solve(*args, **kwargs):
        raise AssertionError("the cached case was solved again")

    monkeypatch.setattr(calibration, "cantilever", no_solve)
    loaded = build_case("strip", (40, 40), tmp_path)
    assert loaded.observation_order is None and loaded.observation_error is None
    assert torch.equal(loaded.observation.points, built.observation.points)
    assert torch.equal(stored.observation.points, built.observation.points)
    a = calibration.fit_draw(built, calibration.newton_fit, 0.005, 1)
    b = calibration.fit_draw(loaded, calibration.newton_fit, 0.005, 1)
    for part in ("values", "errors", "fisher", "model_part"):
        assert np.array_equal(getattr(a, part), getattr(b, part)), part


@pytest.mark.parametrize("name", ["flap", "point_load"])
def test_solved_case_round_trip(tmp_path, monkeypatch, name):
    calls = []
    monkeypatch.setattr(calibration, "converged_observation", _fake_solve(calls))
    first = build_case(name, (8, 8), tmp_path)
    again = build_case(name, (8, 8), tmp_path)
    assert len(calls) == 1
    assert torch.equal(again.observation.points, first.observation.points)
    assert again.observation.points.dtype == torch.float64
    assert math.isnan(again.observation_order) and again.observation_error == 1e-5
    assert np.array_equal(again.truth, first.truth)


def test_changed_case_does_not_reuse(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(calibration, "converged_observation", _fake_solve(calls))
    a = build_case("flap", (8, 8), tmp_path)
    b = build_case("flap", (12, 12), tmp_path)
    assert calls == [(8, 8), (12, 12)]
    assert not torch.equal(a.observation.points, b.observation.points)
    assert len(list(tmp_path.glob("flap-*.npz"))) == 2
    # Other code: another key, another entry.
    monkeypatch.setattr(calibration_draw, "code_version", lambda: "another-commit")
    build_case("flap", (8, 8), tmp_path)
    assert len(calls) == 3


def test_entry_holding_another_key_is_not_used(tmp_path):
    key, other = {"case": "x", "code": "a"}, {"case": "x", "code": "b"}
    cache.store(tmp_path, "x", other, {"points": np.ones(3)})
    cache.entry_path(tmp_path, "x", other).rename(cache.entry_path(tmp_path, "x", key))
    assert cache.load(tmp_path, "x", key) is None
    assert cache.load(tmp_path, "x", other) is None  # moved away


def test_concurrent_writers_never_tear_an_entry(tmp_path):
    key = {"case": "big"}
    arrays = {"points": np.arange(2_000_000, dtype=np.float64)}
    errors: list[BaseException] = []

    def write():
        try:
            for _ in range(6):
                cache.store(tmp_path, "big", key, arrays)
        except BaseException as error:  # noqa: BLE001 - reported by the test
            errors.append(error)

    writers = [threading.Thread(target=write) for _ in range(2)]
    for w in writers:
        w.start()
    reads = 0
    while any(w.is_alive() for w in writers):
        loaded = cache.load(tmp_path, "big", key)  # raises on a torn file
        if loaded is not None:
            assert np.array_equal(loaded["points"], arrays["points"])
            reads += 1
    for w in writers:
        w.join()
    assert not errors
    assert reads > 0
    assert [p.name for p in Path(tmp_path).iterdir()] == [cache.entry_path(tmp_path, "big",
                                                                             key).name]


def test_key_names_what_the_case_depends_on():
    assert case_key("flap", (40, 40))["flap_spans"] == [40, 40]
    assert "flap_spans" not in case_key("strip", (40, 40))
    assert case_key("strip", (8, 8)) == case_key("strip", (40, 40))
    assert set(case_key("strip", (40, 40))["versions"]) == {"numpy", "scipy", "torch", "taichi"}


def test_calibration_runs_get_the_study_cache(tmp_path):
    run = JOBS["calibration"].command(None, {"case": "flap", "noise": 0.0, "seed": 0},
                                      tmp_path / "runs" / "r", cache=tmp_path / "cache")
    assert run[run.index("--case-cache") + 1] == str(tmp_path / "cache")
    scene = JOBS["scene"].command(Path("s.toml"), {}, tmp_path / "r", cache=tmp_path / "c")
    assert "--case-cache" not in scene


def test_code_version_changes_with_the_code_not_the_docs(tmp_path, monkeypatch):
    import subprocess

    from taichi_ndf.sweep import provenance

    def git(*args):
        subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True)

    (tmp_path / "taichi_ndf").mkdir()
    (tmp_path / "taichi_ndf" / "x.py").write_text("a = 1\n")
    (tmp_path / "README.md").write_text("docs\n")
    git("init", "-q")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c")
    monkeypatch.setattr(provenance, "_PACKAGE", tmp_path / "taichi_ndf")

    def version():
        provenance.package_commit.cache_clear()
        provenance.code_version.cache_clear()
        return provenance.code_version()

    try:
        clean = version()
        assert "+" not in clean and len(clean) == 12
        (tmp_path / "README.md").write_text("other docs\n")
        assert version() == clean
        (tmp_path / "taichi_ndf" / "x.py").write_text("a = 2\n")
        edited = version()
        assert edited.startswith(clean + "+dirty-")
        (tmp_path / "taichi_ndf" / "x.py").write_text("a = 3\n")
        assert version() not in (clean, edited)
    finally:
        provenance.package_commit.cache_clear()
        provenance.code_version.cache_clear()
