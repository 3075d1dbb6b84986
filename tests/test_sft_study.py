"""The SfT study (benchmarks/sft_study.py) on one 30-frame sequence: the spline prior beats the
per-frame baseline on e3D, chamfer and normal error (slow: minutes)."""

import pytest

from tests.scripts import load_script


@pytest.mark.slow
@pytest.mark.parametrize("sequence, seed", [("fold", 0), ("corner", 0), ("wave", 1)])
def test_prior_beats_the_baseline(sequence, seed):
    """wave seed 1: lost e3D while the silhouette term pulled the outline in (half a pixel)."""
    study = load_script("benchmarks/sft_study.py")
    args = study.build_parser().parse_args(["--frames", "30"])
    rows = {r["method"]: r for r in study.study(sequence, seed, args)}
    for metric in study.COMPARED:
        assert rows["prior"][metric] < rows["baseline"][metric], (metric, rows)
    assert rows["prior"]["depth_bias_mm"] < 2.0


def test_verdict_judges_the_guided_prior_too():
    study = load_script("benchmarks/sft_study.py")
    base = {"sequence": "fold", "seed": 0, "e3d": 2.0, "chamfer_x1e4": 2.0, "normal_deg": 2.0}
    rows = [dict(base, method="baseline"), dict(base, method="prior", e3d=1.0, chamfer_x1e4=1.0,
                                                normal_deg=1.0),
            dict(base, method="prior+guided", e3d=1.0, chamfer_x1e4=3.0, normal_deg=1.0)]
    lines = study.verdict(rows)
    assert lines == ["fold seed 0: prior beats baseline on e3d yes, chamfer_x1e4 yes, "
                     "normal_deg yes",
                     "fold seed 0: prior+guided beats baseline on e3d yes, chamfer_x1e4 NO, "
                     "normal_deg yes"]


def test_variant_replaces_the_named_prior_settings_and_refuses_bad_ones():
    from inverse.sft.spline_prior import SplinePriorConfig

    study = load_script("benchmarks/sft_study.py")
    config = study.replaced(SplinePriorConfig(), ["silhouette_border_gap=3", "extrapolate=true"])
    assert config.silhouette_border_gap == 3.0 and config.extrapolate is True
    assert config.huber_px == SplinePriorConfig().huber_px
    for bad in (["no_such=1"], ["huber_px=wide"], ["silhouette_border_gap=-1"]):
        with pytest.raises(SystemExit):
            study.replaced(SplinePriorConfig(), bad)
