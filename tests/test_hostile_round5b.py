"""Hostile result files, fifth round (b): a file whose top level is not an object (the
message said "got NoneType", Python's word), values veil never writes that were read
silently (an unknown accuracy, a negative chi-square, a message that is no string, the step
of another kind of model, a joint session's negative count of points), a ``channels``
layout that no measurement table gives (colour names mixed with wavelengths, names that are
no channel), ``--channel`` of a result of one channel (ignored), and an export whose closest
fit cannot take a parameter of 1e308 (the message named ``TorranceSparrow(...)``, a Python
repr, not the file and the key). Each is status 2 naming the file and the key or option,
and nothing is written."""

from __future__ import annotations

import json

import pytest

import veil
from support.cli import run_checked
from test_hostile_tools import _refused, _result
from veil.fitting import FitError, FitResult, JointResult
from veil.models import model_class

TS, HG = model_class("torrance-sparrow"), model_class("henyey-greenstein")


@pytest.fixture(scope="module")
def rgb(tmp_path_factory):
    """A fit of the channels r, g, b, written by veil (simulate + fit reference)."""
    d = tmp_path_factory.mktemp("rgb")
    r = run_checked(["simulate", "--brdf", "BRDF1", "--medium", "none", "--channels", "r,g,b",
                     "--per-channel", "Pd=400,1000,2500", "--psi", "30,90", "--fine-step", "2",
                     "--coarse-step", "10", "-o", d / "rgb.csv"])
    assert r.exit_code == 0, r.output
    r = run_checked(["fit", "reference", d / "rgb.csv", "-o", d / "rgb.json"])
    assert r.exit_code == 0, r.output
    return d / "rgb.json"


@pytest.fixture
def plate(tmp_path):
    return _result(veil.BRDF1, tmp_path / "p.json")


def _damaged(path, out, **changes):
    data = json.loads(path.read_text())
    data.update(changes)
    out.write_text(json.dumps(data))
    return out


def _export(path, tmp_path, *extra):
    return ["export", path, "--to", "csv", *extra, "-o", tmp_path / "out.csv"]


# -- 1. a file whose top level is no object -------------------------------------------------
@pytest.mark.parametrize("text, said", [("null", "holds null"), ("5", "holds a number"),
                                        ("[1]", "holds an array"), ('"fit"', "holds a string")])
def test_a_result_that_is_no_object_is_said_in_json_words(tmp_path, text, said):
    """Was "expected a JSON object with keys model, params, ...; got NoneType"."""
    path = tmp_path / "x.json"
    path.write_text(text)
    r = _refused(_export(path, tmp_path), "x.json", said, "expected a JSON object")
    for python in ("NoneType", "got int", "got list", "got str"):
        assert python not in r.output
    assert not (tmp_path / "out.csv").exists()
    with pytest.raises(FitError, match=said):
        FitResult.from_json(path)


# -- 2. values veil never writes ------------------------------------------------------------
@pytest.mark.parametrize("changes, said", [
    ({"accuracy": "ultra"}, ["key 'accuracy' = 'ultra'", "fast, default, high or null"]),
    ({"accuracy": 3}, ["key 'accuracy' = 3"]),
    ({"chi2_reduced": -1}, ["key 'chi2_reduced' = -1", ">= 0 or null"]),
    ({"rms_relative": -0.5}, ["key 'rms_relative' = -0.5", ">= 0 or null"]),
    ({"message": 5}, ["key 'message' = 5", "a number", "expected a string"]),
    ({"message": None}, ["key 'message' = None", "null", "expected a string"]),
    ({"step": "medium"}, ["key 'step' = 'medium'", "torrance-sparrow", "brdf model",
                          "reference, target, direct or null"]),
])
def test_values_veil_never_writes_are_refused_naming_the_key(plate, tmp_path, changes, said):
    """Each was read silently (exit 0)."""
    bad = _damaged(plate, tmp_path / "bad.json", **changes)
    _refused(_export(bad, tmp_path), "bad.json", *said)
    assert not (tmp_path / "out.csv").exists()
    with pytest.raises(FitError, match="bad.json"):
        FitResult.from_json(bad)


@pytest.mark.parametrize("step", ["reference", "target", "direct"])
def test_a_medium_result_of_a_brdf_step_is_refused(tmp_path, step):
    medium = _result(HG(Td=0.001, Tt=0.1, g=0.9, eta=1.3), tmp_path / "m.json")
    bad = _damaged(medium, tmp_path / "bad.json", step=step)
    _refused(["render", "--brdf", "BRDF1", "--medium", bad, "--size", "8",
              "-o", tmp_path / "x.png"],
             "bad.json", f"key 'step' = '{step}'", "henyey-greenstein", "medium or null")
    assert not (tmp_path / "x.png").exists()
    # the step veil writes for a medium reads
    ok = _damaged(medium, tmp_path / "ok.json", step="medium")
    assert FitResult.from_json(ok).step == "medium"


def _joint(path):
    """A joint result (one medium 'm', the target and the reference), as veil writes it."""
    ref = {f"ref.{k}": v for k, v in veil.BRDF2.as_dict().items()}
    medium = {"Td[m]": 0.001, "Tt[m]": 0.13, "g[m]": 0.9, "eta_u": 1.33}
    params = {**veil.BRDF1.as_dict(), **ref, **medium}
    names = list(veil.BRDF1.as_dict())
    sessions = [{"name": f"{obj} in {m}", "object": obj, "medium": m, "n_points": 36,
                 "chi2": 1.0, "rms_relative": 0.01}
                for obj, m in (("target", "m"), ("reference", "none"), ("reference", "m"))]
    layout = {"models": {"brdf": "torrance-sparrow", "medium": "henyey-greenstein"},
              "options": {"brdf": {}, "medium": {"variant": "paper"}},
              "objects": {"target": {n: n for n in names},
                          "reference": {n: f"ref.{n}" for n in names}},
              "media": {"m": {"Td": "Td[m]", "Tt": "Tt[m]", "g": "g[m]", "eta_u": "eta_u"}},
              "shared": ["eta_u"], "reference_given": False, "sessions": sessions}
    path.write_text(json.dumps({
        "format": "veil.fit/2", "model": "joint", "step": "joint", "params": params,
        "stderr": dict.fromkeys(params), "correlation": {}, "chi2_reduced": 1.0,
        "rms_relative": 0.01, "n_points": 108, "converged": True, "message": "",
        "residuals": [0.0] * 108,
        "variant": "paper", "options": {}, "fixed": {}, "layout": layout}))
    assert isinstance(JointResult.from_json(path), JointResult)
    return path


@pytest.mark.parametrize("count", [-5, 3.5, "36"])
def test_a_joint_sessions_count_of_points_must_be_a_count(tmp_path, count):
    """layout.sessions[k].n_points was not read: -5 was printed as '-5 points'."""
    data = json.loads(_joint(tmp_path / "j.json").read_text())
    data["layout"]["sessions"][1]["n_points"] = count
    (tmp_path / "bad.json").write_text(json.dumps(data))
    r = _refused(_export(tmp_path / "bad.json", tmp_path), "bad.json",
                 "layout.sessions[1].n_points", "expected an integer >= 0")
    assert r.output.count("bad.json") == 1, r.output  # the file named once
    with pytest.raises(FitError, match=r"sessions\[1\]\.n_points"):
        JointResult.from_json(tmp_path / "bad.json")


# -- 3. channels that no table gives --------------------------------------------------------
def _channels(rgb, out, names: list):
    """The fit ``rgb`` with its channel layout (and parameters) renamed to ``names``."""
    data = json.loads(rgb.read_text())
    per = [p for p in TS.param_names() if p + "[r]" in data["params"]]
    tied = [p for p in TS.param_names() if p not in per]
    first = dict(zip(per, (data["params"][f"{p}[r]"] for p in per)))
    params = {f"{p}[{c}]": first[p] for p in per for c in names}
    params.update({p: data["params"][p] for p in tied})
    layout = {c: {p: (f"{p}[{c}]" if p in per else p) for p in TS.param_names()} for c in names}
    data.update(params=params, stderr=dict.fromkeys(params), correlation={},
                correlation_total=None, stderr_total=None, model_error=None, channels=layout)
    out.write_text(json.dumps(data))
    return out


@pytest.mark.parametrize("names, said", [
    (["r", "g", "b", "650"], ["mixes colour channels (r, g, b) with wavelengths (650"]),
    (["r", "450"], ["mixes colour channels"]),
    ([f"c{k}" for k in range(3000)], ["names channel 'c0'", "r, g, b or wavelengths"]),
    (["R", "G"], ["names channel 'R'"]),
    (["650.0", "550"], ["names channel '650.0'", "650, not 650.0"]),
    (["100", "550"], ["names channel '100'", "from 200 to 2500"]),
])
def test_a_channel_layout_no_table_gives_is_refused(rgb, tmp_path, names, said):
    """Each was exported (exit 0), 3000 channels in eight seconds."""
    bad = _channels(rgb, tmp_path / "bad.json", names)
    _refused(_export(bad, tmp_path), "bad.json", "key 'channels'", *said)
    assert not (tmp_path / "out.csv").exists()
    with pytest.raises(FitError, match="key 'channels'"):
        FitResult.from_json(bad)


def test_channel_layouts_a_table_gives_still_read(rgb, tmp_path):
    assert FitResult.from_json(rgb).channel_names == ("r", "g", "b")
    waves = FitResult.from_json(_channels(rgb, tmp_path / "w.json", ["450", "550.5", "650"]))
    assert waves.channel_names == ("450", "550.5", "650")


# -- 4. --channel of a result of one channel ------------------------------------------------
@pytest.mark.parametrize("command", ["export", "render"])
def test_channel_of_a_result_of_one_channel_is_refused(plate, tmp_path, command):
    """Was ignored: the one channel's model exported (exit 0)."""
    out = tmp_path / ("out.csv" if command == "export" else "x.png")
    args = (_export(plate, tmp_path, "--channel", "r") if command == "export" else
            ["render", "--brdf", plate, "--medium", "none", "--channel", "r", "--size", "8",
             "-o", out])
    _refused(args, "--channel r", "p.json", "fit of one channel", "leave --channel out")
    assert not out.exists()


def test_channel_of_a_result_of_several_still_exports(rgb, plate, tmp_path):
    r = run_checked(_export(rgb, tmp_path, "--channel", "G"))
    assert r.exit_code == 0, r.output
    medium = _result(HG(Td=0.001, Tt=0.1, g=0.9, eta=1.3), tmp_path / "m.json")
    r = run_checked(["export", rgb, medium, "--to", "csv", "--channel", "g",
                     "-o", tmp_path / "two.csv"])
    assert r.exit_code == 0, r.output


# -- 5. an export whose closest fit cannot take a parameter ---------------------------------
def test_an_export_beyond_the_closest_fit_names_file_and_key(tmp_path):
    """Was "TorranceSparrow(Pd=199.943, Ps=1e+308, ...): f_r reaches ...": the Python repr."""
    big = _result(veil.BRDF1.replace(Ps=1e308), tmp_path / "big.json")
    out = tmp_path / "x.xml"
    for to in ("mitsuba", "pbrt"):
        r = _refused(["export", big, "--to", to, "-o", out],
                     "big.json: key 'params.Ps' = 1e+308", "torrance-sparrow", "rescale")
        assert "TorranceSparrow" not in r.output and not out.exists()
    # a medium result that brings it along (its 'given' reference) names that key
    medium = json.loads(_result(HG(Td=0.001, Tt=0.1, g=0.9, eta=1.3),
                                tmp_path / "m.json").read_text())
    medium["given"] = {"model": "torrance-sparrow", "params": json.loads(big.read_text())["params"]}
    (tmp_path / "m.json").write_text(json.dumps(medium))
    r = _refused(["export", tmp_path / "m.json", "--to", "mitsuba", "-o", out],
                 "m.json: key 'given.params.Ps' = 1e+308")
    assert "TorranceSparrow" not in r.output and not out.exists()


def test_a_colour_export_beyond_the_closest_fit_names_the_channels_key(rgb, tmp_path):
    data = json.loads(rgb.read_text())
    data["params"]["Ps[g]"] = 1e308
    data.update(stderr=dict.fromkeys(data["params"]), correlation={}, model_error=None,
                stderr_total=None, correlation_total=None)
    (tmp_path / "big.json").write_text(json.dumps(data))
    out = tmp_path / "x.xml"
    r = _refused(["export", tmp_path / "big.json", "--to", "mitsuba", "-o", out],
                 "big.json: key 'params.Ps[g]' = 1e+308")
    assert "TorranceSparrow" not in r.output and not out.exists()
