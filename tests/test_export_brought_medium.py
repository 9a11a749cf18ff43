"""``veil export`` of a result whose own medium no renderer expresses (docs/interop.md): the
error says the medium is the one stored in that result file and what to give instead, and
it comes before the closest-family fit of the BRDF (seconds of engine work)."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

import veil
from veil.cli import main
from veil.fitting.result import FitResult, model_entry
from veil.interop import closest
from veil.interop.colour import export_colour
from veil.interop.export import export
from veil.models.renderers import Unsupported


@pytest.fixture
def no_fit(monkeypatch):
    """The closest-family fits fail the test when they run."""

    def fail(*args, **kwargs):
        raise AssertionError("the closest-family fit ran before the refusal")

    monkeypatch.setattr(closest, "closest", fail)
    monkeypatch.setattr(closest, "closest_channels", fail)


def _target_result(path):
    """A result of the paper's BRDF1 fitted through its medium BTDF2."""
    brdf = veil.BRDF1
    FitResult(
        model=brdf.NAME, params=brdf.as_dict(), stderr={k: None for k in brdf.as_dict()},
        correlation={}, residuals=(0.0,), chi2_reduced=1.0, rms_relative=0.01, n_points=10,
        converged=True, message="", options=brdf.options(), step="target",
        given=model_entry(veil.BTDF2),
    ).to_json(path)
    return path


@pytest.mark.parametrize("renderer", ["mitsuba", "pbrt"])
def test_the_targets_own_medium_is_named_and_refused_before_any_fit(tmp_path, no_fit, renderer):
    path = _target_result(tmp_path / "target.json")
    out = tmp_path / "scene.out"
    run = CliRunner().invoke(
        main, ["export", str(path), "--to", renderer, "-o", str(out)], catch_exceptions=False
    )
    assert run.exit_code == 2, run.output
    text = " ".join(run.output.split())
    assert f"{path} stores the medium it was fitted through (henyey-greenstein)" in text
    assert "when no MEDIUM file is given" in text
    assert f"veil export {path} MEDIUM.json --to {renderer} -o {out}" in text
    assert not out.exists()


def test_the_api_checks_every_model_before_the_closest_fit(no_fit):
    with pytest.raises(Unsupported, match="henyey-greenstein"):
        export([veil.BRDF1, veil.BTDF2], "mitsuba")
    with pytest.raises(Unsupported, match="henyey-greenstein"):
        export_colour({c: [veil.BRDF1, veil.BTDF2] for c in "rgb"}, "mitsuba")
