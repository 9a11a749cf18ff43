"""Hostile result files: what veil never writes (overlong integers, deep nesting, NaN and
Infinity literals, uncertainties that are no covariance) is refused where the file is read,
exit 2 naming the file and the key; what veil writes still reads back."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import veil
from support.cli import run_checked
from veil.data.measurements import save_measurements
from veil.fitting import FitError, FitResult, fit_medium, fit_reference, fit_target, load_result

SMALL = dict(psi=(30, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A medium fit (med.json, with total uncertainties), a target fit (tgt.json) and the
    target's table and black cloth."""
    d = tmp_path_factory.mktemp("hostile-json")
    ref_table = veil.simulate(veil.BRDF2, None, seed=4, **SMALL)
    ref = fit_reference(ref_table)
    table, black = veil.simulate(veil.BRDF2, veil.BTDF2, seed=5, black=True, **SMALL)
    medium = fit_medium(table, ref, black=black, accuracy="fast")
    medium.to_json(d / "med.json")
    tgt_table, tgt_black = veil.simulate(veil.BRDF1, veil.BTDF2, seed=6, black=True, **SMALL)
    save_measurements(tgt_table, d / "tgt.csv")
    save_measurements(tgt_black, d / "blk.csv")
    target = fit_target(tgt_table, medium, black=tgt_black, accuracy="fast")
    target.to_json(d / "tgt.json")
    return d


def refused(args, *names):
    """``veil ARGS`` exits 2 with a message holding every one of ``names``."""
    r = run_checked(args)
    assert r.exit_code == 2, r.output
    assert "internal error" not in r.output
    for name in names:
        assert name in r.output, (name, r.output)
    return r


def export(path, tmp_path):
    return ["export", path, "--to", "csv", "-o", tmp_path / "out.csv"]


def written(d, name: str, text: str):
    path = d / name
    path.write_text(text)
    return path


# -- defect 5: an integer beyond any number of a result --------------------------------------


def test_overlong_integer_is_refused_naming_file_and_key(files, tmp_path):
    text = (files / "tgt.json").read_text()
    n = json.loads(text)["n_points"]
    big = written(tmp_path, "big.json", text.replace(f'"n_points": {n}', '"n_points": ' + "9" * 5000))
    refused(export(big, tmp_path), "big.json", "n_points", "5000 digits")
    assert not (tmp_path / "out.csv").exists()
    with pytest.raises(FitError, match="n_points"):
        FitResult.from_json(big)


def test_float_beyond_range_is_refused(files, tmp_path):
    data = json.loads((files / "tgt.json").read_text())
    text = json.dumps({**data, "rms_relative": "X"}).replace('"X"', "1e400")
    path = written(tmp_path, "huge.json", text)
    refused(export(path, tmp_path), "huge.json", "rms_relative", "1e400")


# -- defect 6: nesting ----------------------------------------------------------------------


@pytest.mark.parametrize("text", ["[" * 100000 + "]" * 100000, '{"a":' * 80 + "1" + "}" * 80])
def test_deep_nesting_is_refused_naming_file(tmp_path, text):
    path = written(tmp_path, "deep.json", text)
    refused(export(path, tmp_path), "deep.json", "nested")
    with pytest.raises(FitError, match="deep.json.*nest"):
        load_result(path)
    # the explorer asks first whether the file is one of its states (it is not)
    refused(["explore", path, "--static", "-o", tmp_path / "page.html"], "deep.json", "nested")
    assert not (tmp_path / "page.html").exists()


# -- defect 13: NaN and Infinity literals ---------------------------------------------------


@pytest.mark.parametrize(
    "key, literal",
    [("chi2_reduced", "Infinity"), ("residuals[0]", "NaN"), ("stderr.Pd", "NaN"),
     ("params.n", "-Infinity"), ("stats.nfev", "NaN")],
)
def test_non_finite_literals_are_refused_naming_key(files, tmp_path, key, literal):
    data = json.loads((files / "tgt.json").read_text())
    node, parts = data, key.replace("[0]", ".0").split(".")
    for part in parts[:-1]:
        node = node[part]
    last = int(parts[-1]) if isinstance(node, list) else parts[-1]
    node[last] = "@@LITERAL@@"
    path = written(tmp_path, "nan.json", json.dumps(data, indent=2).replace('"@@LITERAL@@"', literal))
    refused(export(path, tmp_path), "nan.json", f"'{key}'", literal)


# -- defect 12: uncertainties that are no covariance -----------------------------------------


def _medium_variant(files, tmp_path, edit) -> object:
    data = json.loads((files / "med.json").read_text())
    assert data["stderr_total"] is not None and data["correlation_total"] is not None
    edit(data)
    return written(tmp_path, "bad_med.json", json.dumps(data, indent=2))


def _set_pair(matrix, a, b, value):
    matrix[a][b] = matrix[b][a] = value


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda d: _set_pair(d["correlation_total"], "g", "Td", 5.0), "correlation_total.Td.g"),
        (lambda d: _set_pair(d["correlation"], "Tt", "eta", -1.5), "correlation.Tt.eta"),
        (lambda d: d["stderr_total"].update(Td=-1), "stderr_total.Td"),
        (lambda d: d["stderr"].update(g=-0.5), "stderr.g"),
        (lambda d: d["correlation_total"]["g"].update(Td=0.9), "correlation_total"),
        (lambda d: d["stderr_total"].update(Td="big"), "stderr_total.Td"),
    ],
)
def test_invalid_uncertainties_of_a_given_medium_are_refused(files, tmp_path, edit, key):
    bad = _medium_variant(files, tmp_path, edit)
    refused(["fit", "target", files / "tgt.csv", "--black", files / "blk.csv", "--accuracy",
             "fast", "--medium", bad, "-o", tmp_path / "o.json"], "bad_med.json", f"'{key}")
    assert not (tmp_path / "o.json").exists()


def test_correlations_that_are_no_covariance_are_refused(files, tmp_path):
    def edit(d):
        for a, b, r in (("Td", "Tt", 0.99), ("Td", "g", 0.99), ("Tt", "g", -0.99)):
            _set_pair(d["correlation_total"], a, b, r)

    bad = _medium_variant(files, tmp_path, edit)
    r = refused(["fit", "target", files / "tgt.csv", "--black", files / "blk.csv",
                 "--accuracy", "fast", "--medium", bad, "-o", tmp_path / "o.json"],
                "bad_med.json", "'stderr_total'", "'correlation_total'")
    assert "covariance" in r.output


def test_a_nan_literal_standard_error_is_refused(files, tmp_path):
    data = json.loads((files / "med.json").read_text())
    data["stderr_total"]["Td"] = "@@"
    path = written(tmp_path, "bad_med.json", json.dumps(data).replace('"@@"', "NaN"))
    refused(["fit", "target", files / "tgt.csv", "--black", files / "blk.csv", "--accuracy",
             "fast", "--medium", path, "-o", tmp_path / "o.json"], "bad_med.json",
            "'stderr_total.Td'", "NaN")


def test_non_finite_values_in_a_dict_are_refused(files):
    data = json.loads((files / "med.json").read_text())
    for key in ("stderr", "stderr_total"):
        bad = {**data, key: {**data[key], "g": math.nan}}
        with pytest.raises(FitError, match=f"the source: key '{key}.g'"):
            FitResult.from_dict(bad, "the source")
    bad = {**data, "residuals": [math.inf] + data["residuals"][1:]}
    with pytest.raises(FitError, match=r"'residuals\[0\]'"):
        FitResult.from_dict(bad, "the source")
    with pytest.raises(FitError, match="key 'fixed'"):
        FitResult.from_dict({**data, "fixed": {"g": "x"}}, "the source")


# -- what veil writes still reads ------------------------------------------------------------


def test_results_veil_writes_read_back(files):
    for name in ("med.json", "tgt.json"):
        data = json.loads((files / name).read_text())
        back = FitResult.from_json(files / name)
        assert back.to_dict() == data
        names, cov = back.covariance(total=True)
        assert np.all(np.isfinite(cov))
        assert np.linalg.eigvalsh((cov + cov.T) / 2)[0] > -1e-9 * np.abs(cov).max()
    # rounding of what veil writes (a diagonal of 1.0000000000000002, pairs a last digit apart)
    data = json.loads((files / "med.json").read_text())
    data["correlation"]["Td"]["Td"] = 1.0000000000000002
    data["correlation"]["Td"]["Tt"] += 1e-16
    FitResult.from_dict(data, "rounded")
    # null where an uncertainty is not determined
    data["stderr"]["Td"] = None
    data["correlation"]["Td"] = {k: None for k in data["correlation"]["Td"]}
    assert FitResult.from_dict(data, "undetermined").stderr["Td"] is None
