"""Measurement tables (docs/model.md sec. 7): forms, round trip, checks, black-cloth subtraction."""

from __future__ import annotations

import math
import os
import warnings

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import veil
from veil.data.black_cloth import subtract_black
from veil.data.measurements import (
    LikelyRadiansWarning,
    MeasurementError,
    canonical_angles,
    load_measurements,
    save_measurements,
    to_form,
    validate,
)


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# The same four configurations in the three forms (see the test): goniometer (psi, rho) ->
# signed (psi/2 + rho, psi/2 - rho) -> canonical, by hand (docs/model.md sec. 1).
CANONICAL = np.array([[15, 180, 15, 0], [10, 0, 70, 0], [89.5, 180, 0.5, 0], [30, 180, 10, 0]],
                     dtype=float)


def test_three_forms_same_canonical_angles(tmp_path):
    gonio = "psi,rho,value\n30,0,1\n60,-40,2\n90,44.5,3\n40,10,4\n"
    inplane = "theta_i,theta_r,value\n15,15,1\n-10,70,2\n89.5,0.5,3\n30,10,4\n"
    full = ("theta_i,phi_i,theta_r,phi_r,value\n15,180,15,0,1\n10,0,70,-360,2\n"
            "89.5,180,0.5,0,3\n30,-180,10,0,4\n")
    for name, text in (("g.csv", gonio), ("i.csv", inplane), ("f.csv", full)):
        canon = canonical_angles(load_measurements(write(tmp_path, name, text)))
        assert canon.columns[:4].tolist() == ["theta_i", "phi_i", "theta_r", "phi_r"]
        np.testing.assert_allclose(canon.iloc[:, :4].to_numpy(), CANONICAL, rtol=0, atol=1e-12)
        assert canon["value"].tolist() == [1.0, 2.0, 3.0, 4.0]
        assert all(canon[c].dtype == np.float64 for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    # the goniometer table keeps psi and rho after the canonical columns
    canon = canonical_angles(load_measurements(tmp_path / "g.csv"))
    assert canon.columns.tolist() == ["theta_i", "phi_i", "theta_r", "phi_r", "psi", "rho", "value"]


def test_psi_rho_with_agreeing_theta_columns(tmp_path):
    path = write(tmp_path, "m.csv", "psi,rho,theta_i,theta_r,value\n60,-40,-10,70,2\n30,1,16,14,1\n")
    canon = canonical_angles(load_measurements(path))
    assert canon.iloc[0, :4].tolist() == [10.0, 0.0, 70.0, 0.0]


def test_disagreeing_forms_are_ambiguous(tmp_path):
    path = write(tmp_path, "m.csv", "psi,rho,theta_i,theta_r,value\n60,-40,-10,70,2\n30,1,15,15,1\n")
    with pytest.raises(MeasurementError) as err:
        load_measurements(path)
    msg = str(err.value)
    assert "line 3 of" in msg and "m.csv" in msg and "ambiguous" in msg and "psi,rho" in msg
    assert "line 2" not in msg


def test_passthrough_columns_and_order(tmp_path):
    text = 'note,rho,exposure,value,psi,count,sigma\n"a, b",0,0.125,1.5,30,3,0.1\nc,1,,2.5,30,4,0.2\n'
    table = load_measurements(write(tmp_path, "m.csv", text))
    assert table.columns.tolist() == ["note", "rho", "exposure", "value", "psi", "count", "sigma"]
    assert table["note"].tolist() == ["a, b", "c"]
    assert table["count"].tolist() == [3, 4] and table["count"].dtype == np.int64
    assert table["exposure"].iloc[0] == 0.125 and math.isnan(table["exposure"].iloc[1])
    canon = canonical_angles(table)
    assert canon.columns.tolist() == ["theta_i", "phi_i", "theta_r", "phi_r", "note", "rho",
                                      "exposure", "value", "psi", "count", "sigma"]


def test_negative_values_allowed(tmp_path):
    table = load_measurements(write(tmp_path, "m.csv", "psi,rho,value\n30,0,-0.5\n30,1,-1e-3\n"))
    assert table["value"].tolist() == [-0.5, -1e-3]


def test_round_trip_awkward_floats(tmp_path):
    values = [0.1, 1 / 3, 2.0 ** -1074, 1.7976931348623157e308, -0.0, 1e-300, 123456789.12345678]
    table = pd.DataFrame({"psi": 60.0, "rho": np.arange(len(values), dtype=float) - 3.0,
                          "value": values, "sigma": np.abs(values), "x": values})
    path = tmp_path / "t.csv"
    save_measurements(table, path)
    back = load_measurements(path)
    pd.testing.assert_frame_equal(back, table, check_exact=True)
    assert [math.copysign(1, v) for v in back["value"]] == [math.copysign(1, v) for v in values]


angle = st.floats(-89, 89, allow_nan=False).map(lambda x: round(x, 3))
finite = st.floats(allow_nan=False, allow_infinity=False)


@st.composite
def tables(draw):
    n = draw(st.integers(1, 8))
    form = draw(st.sampled_from(["full", "inplane", "goniometer"]))
    # distinct configurations: theta_r (or rho) strictly increasing
    second = sorted(draw(st.sets(st.integers(-880, 880), min_size=n, max_size=n)))
    second = [s / 10 for s in second]
    first = draw(st.lists(angle, min_size=n, max_size=n))
    if form == "full":
        cols = {"theta_i": [abs(a) for a in first],
                "phi_i": draw(st.lists(st.floats(-360, 360), min_size=n, max_size=n)),
                "theta_r": [abs(s) for s in second],
                "phi_r": [0.0 if s >= 0 else 180.0 for s in second]}
    elif form == "inplane":
        cols = {"theta_i": first, "theta_r": second}
    else:
        # |rho| <= 29 and psi <= 120 keep both |psi/2 +- rho| < 90
        cols = {"psi": draw(st.lists(st.sampled_from([10.0, 30.0, 60.0, 90.0, 120.0]),
                                     min_size=n, max_size=n)),
                "rho": [s / 3.0 for s in second]}
    cols["value"] = draw(st.lists(finite, min_size=n, max_size=n))
    if draw(st.booleans()):
        cols["sigma"] = [abs(v) for v in draw(st.lists(finite, min_size=n, max_size=n))]
    if draw(st.booleans()):
        cols["note"] = draw(st.lists(st.text("abc xyz,\"'", min_size=1).filter(
            lambda s: s.strip() and s.strip() == s and s[0].isalpha()), min_size=n, max_size=n))
    if draw(st.booleans()):
        cols["extra"] = draw(st.lists(st.floats(allow_infinity=False), min_size=n, max_size=n))
    if draw(st.booleans()):
        cols["count"] = draw(st.lists(st.integers(-10**12, 10**12), min_size=n, max_size=n))
    names = list(cols)
    order = draw(st.permutations(names))
    return pd.DataFrame({k: cols[k] for k in order})


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(table=tables())
def test_round_trip_random_tables(tmp_path, table):
    path = tmp_path / "rt.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LikelyRadiansWarning)
        try:
            validate(table)
        except MeasurementError as exc:  # e.g. two random configurations coincide
            assert "duplicate" in str(exc)
            return
        save_measurements(table, path)
        back = load_measurements(path)
        again = tmp_path / "again.csv"
        save_measurements(back, again)
    pd.testing.assert_frame_equal(back, table, check_exact=True)
    assert again.read_bytes() == path.read_bytes()


# -- bad input ---------------------------------------------------------------------------

@pytest.mark.parametrize("text, expected", [
    ("", ["bad.csv is empty"]),
    ("\n\n  \n", ["bad.csv is empty"]),
    ('""\n""\n', ["bad.csv has no header", "every line is blank"]),
    ("psi,rho,value\n", ["bad.csv", "no data rows"]),
    ("psi,rho,val\n30,0,1\n", ["bad.csv", "no 'value' column", "val"]),
    ("psi,rho,value\n30,0,1\n30,1,abc\n", ["line 3 of", "bad.csv", "column 'value'", "'abc' is not a number"]),
    ("psi,rho,value\n30,0,1\n\n30,1,nan\n", ["line 4 of", "column 'value'", "'nan' is not a finite number"]),
    ("psi,rho,value\n30,0,1\n30,,2\n", ["line 3 of", "column 'rho'", "is empty"]),
    ("psi,rho,value\n30,0,1\n30,1,inf\n", ["line 3 of", "column 'value'", "not a finite"]),
    ("psi,rho,value,sigma\n30,0,1,0.1\n30,1,1,-0.2\n", ["line 3 of", "sigma = -0.2", ">= 0"]),
    ("theta_i,phi_i,theta_r,phi_r,value\n10,180,95,0,1\n", ["line 2 of", "theta_r = 95", "[0, 90)"]),
    ("theta_i,phi_i,theta_r,phi_r,value\n-10,180,5,0,1\n", ["line 2 of", "theta_i = -10", "signed"]),
    ("theta_i,phi_i,theta_r,phi_r,value\n10,400,5,0,1\n", ["line 2 of", "phi_i = 400"]),
    ("theta_i,theta_r,value\n10,20,1\n-91,5,2\n", ["line 3 of", "theta_i = -91", "(-90, 90)"]),
    ("psi,rho,value\n30,0,1\n100,50,2\n", ["line 3 of", "psi = 100, rho = 50", "theta_i = 100"]),
    ("psi,theta_i,theta_r,value\n30,10,20,1\n", ["column 'psi' but not 'rho'"]),
    ("theta_i,phi_i,theta_r,value\n10,180,20,1\n", ["column 'phi_i' but not 'phi_r'"]),
    ("a,b,value\n1,2,3\n", ["no angle columns", "psi,rho"]),
    ("psi,rho,value,value\n30,0,1,2\n", ["header (line 1)", "'value' twice"]),
    ("psi,rho,,value\n30,0,1,2\n", ["column 3", "no name"]),
    ("psi,rho,value\n30,0,1\n30,1,2,7\n", ["line 3 of", "4 fields", "header (line 1) has 3"]),
    ("psi,rho,value\n30,0,1\n30,1\n", ["line 3 of", "2 fields"]),
    ("psi,rho,value\n30,0,1\n30,1,2\n30,0,3\n30,2,4\n", ["duplicate", "line 2 of", "bad.csv and line 4 of"]),
    # theta = 0: the azimuth does not matter, these are the same configuration
    ("theta_i,phi_i,theta_r,phi_r,value\n0,180,20,0,1\n0,0,20,0,2\n",
     ["duplicate", "line 2 of", "and line 3 of"]),
    ("psi,rho,theta_i,theta_r,value\n30,0,15,16,1\n", ["line 2 of", "ambiguous"]),
])
def test_bad_files(tmp_path, text, expected):
    path = write(tmp_path, "bad.csv", text)
    with pytest.raises(MeasurementError) as err:
        load_measurements(path)
    for part in expected:
        assert part in str(err.value), (part, str(err.value))


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.csv does not exist"):
        load_measurements(tmp_path / "nope.csv")


def test_dataframe_errors_name_index_labels():
    table = pd.DataFrame({"psi": [30.0, 30.0], "rho": [0.0, 1.0], "value": [1.0, "x"]},
                         index=[10, 11])
    with pytest.raises(MeasurementError, match=r"row 11 \(index label\) of the table, column 'value'"):
        validate(table)
    table = pd.DataFrame({"psi": [30.0, 30.0], "rho": [0.0, 1.0], "value": [1.0, np.nan]})
    with pytest.raises(MeasurementError, match="row 1 .*empty or NaN"):
        validate(table)


def test_radians_warning(tmp_path):
    radians = write(tmp_path, "rad.csv", "theta_i,phi_i,theta_r,phi_r,value\n0.5,3.14159,0.5,0,1\n"
                                         "0.7,3.14159,0.3,0,1\n")
    with pytest.warns(LikelyRadiansWarning, match="rad.csv.*radians"):
        load_measurements(radians)
    assert issubclass(LikelyRadiansWarning, UserWarning)
    degrees = write(tmp_path, "deg.csv", "theta_i,phi_i,theta_r,phi_r,value\n0.5,180,0.5,0,1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_measurements(degrees)


def test_save_refuses_bad_table_and_leaves_file(tmp_path):
    path = write(tmp_path, "out.csv", "keep me")
    with pytest.raises(MeasurementError):
        save_measurements(pd.DataFrame({"psi": [30.0], "rho": [0.0]}), path)
    assert path.read_text() == "keep me"
    save_measurements(pd.DataFrame({"psi": [30.0], "rho": [0.0], "value": [1.0]}), path)
    assert path.read_text() == "psi,rho,value\n30.0,0.0,1.0\n"
    assert os.listdir(tmp_path) == ["out.csv"]  # no temporary files left


def test_to_form_round_trip():
    table = pd.DataFrame({"psi": [30.0, 60.0], "rho": [2.0, -40.0], "value": [1.0, 2.0],
                          "note": ["a", "b"]})
    full = to_form(table, "full")
    assert full.columns.tolist() == ["theta_i", "phi_i", "theta_r", "phi_r", "value", "note"]
    inplane = to_form(full, "inplane")
    assert inplane["theta_i"].tolist() == [17.0, -10.0] and inplane["theta_r"].tolist() == [13.0, 70.0]
    gonio = to_form(inplane, "goniometer")
    assert gonio[["psi", "rho"]].to_numpy().tolist() == [[30.0, 2.0], [60.0, -40.0]]
    off_plane = pd.DataFrame({"theta_i": [10.0, 20.0], "phi_i": [180.0, 90.0],
                              "theta_r": [10.0, 20.0], "phi_r": [0.0, 0.0], "value": [1.0, 1.0]})
    with pytest.raises(MeasurementError, match=r"row 1 \(index label\).*not in the plane"):
        to_form(off_plane, "inplane")


# -- black cloth --------------------------------------------------------------------------

SESSION = "psi,rho,value,sigma,note\n30,0,10,3,a\n30,1,20,0.5,b\n60,-40,5,1,c\n"


def test_subtract_black_matches_within_tolerance(tmp_path):
    session = load_measurements(write(tmp_path, "s.csv", SESSION))
    # the black cloth in the full form, in another order, angles off by 0.02 deg, extra row
    black = load_measurements(write(tmp_path, "b.csv",
        "theta_i,phi_i,theta_r,phi_r,value,sigma\n"
        "10.02,0,70,0,0.5,0\n15,180,15.02,0,1,4\n50,180,5,0,9,9\n16,180,14,0,2,1.2\n"))
    out = subtract_black(session, black, tol=0.05)
    assert out.columns.tolist() == ["psi", "rho", "value", "sigma", "note"]
    assert out["value"].tolist() == [9.0, 18.0, 4.5]
    np.testing.assert_allclose(out["sigma"], [5.0, 1.3, 1.0], rtol=1e-15)
    assert out["note"].tolist() == ["a", "b", "c"]
    with pytest.raises(MeasurementError) as err:
        subtract_black(session, black, tol=0.01)
    msg = str(err.value)
    assert "line 2 of" in msg and "s.csv" in msg and "line 4 of" in msg and "line 3" not in msg
    assert "2 configuration(s) have no black-cloth measurement within 0.01 deg in" in msg
    assert "b.csv" in msg and "theta_i=15, phi_i=180, theta_r=15, phi_r=0" in msg


def test_subtract_black_unmatched_named():
    session = pd.DataFrame({"psi": [30.0, 30.0, 90.0], "rho": [0.0, 5.0, 1.0], "value": 1.0})
    black = pd.DataFrame({"psi": [30.0], "rho": [0.0], "value": [0.25]})
    with pytest.raises(MeasurementError) as err:
        subtract_black(session, black)
    msg = str(err.value)
    assert "row 1 (index label) of the table: theta_i=20, phi_i=180, theta_r=10, phi_r=0" in msg
    assert "row 2 (index label)" in msg and "row 0" not in msg
    assert "the black-cloth table" in msg


def test_subtract_black_sigma_rules_and_ambiguity():
    session = pd.DataFrame({"theta_i": [10.0], "theta_r": [20.0], "value": [3.0]})
    black = pd.DataFrame({"theta_i": [10.0], "theta_r": [20.0], "value": [1.0], "sigma": [0.5]})
    out = subtract_black(session, black)
    assert out["value"].tolist() == [2.0] and out["sigma"].tolist() == [0.5]
    assert "sigma" not in subtract_black(session, black.drop(columns="sigma")).columns
    close = pd.DataFrame({"theta_i": [10.0, 10.03], "theta_r": [20.0, 20.0], "value": [1.0, 2.0]})
    with pytest.raises(MeasurementError, match="several black-cloth rows.*smaller tolerance"):
        subtract_black(session, close, tol=0.05)
    assert subtract_black(session, close, tol=0.01)["value"].tolist() == [2.0]
    with pytest.raises(ValueError, match="tol"):
        subtract_black(session, black, tol=-1)


def test_public_exports():
    assert veil.load_measurements is load_measurements
    assert veil.save_measurements is save_measurements
    assert veil.subtract_black is subtract_black
