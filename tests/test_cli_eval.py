"""``veil eval``: printed values equal the API, CSV round trip, JSON, and user errors (exit 2).

Most tests run the command in-process (click's CliRunner) so JAX compiles each shape once;
angles arrays of length 1 (one configuration) and 3 (the CSV) are reused on purpose.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

import veil
from support.cli import run_checked
from veil.cli.eval_cmd import eval_command

VEIL = shutil.which("veil", path=os.path.dirname(sys.executable)) or "veil"
BASE = ["eval", "--brdf", "BRDF1", "--medium", "BTDF2", "--accuracy", "fast"]

CSV_TEXT = (
    'id,phi_r,theta_i,note,theta_r,phi_i\n'
    '007,0,45,"plain",50,180\n'
    '2,10,30,"with, comma",35,170\n'
    '3,90,60,"say ""hi""",20,200\n'
)
CSV_ANGLES = {  # the CSV's columns in the order apparent() takes them
    "theta_i": np.array([45.0, 30.0, 60.0]), "theta_r": np.array([50.0, 35.0, 20.0]),
    "phi_i": np.array([180.0, 170.0, 200.0]), "phi_r": np.array([0.0, 10.0, 90.0]),
}


run = run_checked


def run_json(args):
    result = run(args + ["--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def api(brdf, medium, ti, tr, pi_=180.0, pr=0.0, accuracy="fast"):
    value, error = veil.apparent(brdf, medium, np.atleast_1d(ti), np.atleast_1d(tr),
                                 np.atleast_1d(pi_), np.atleast_1d(pr), accuracy=accuracy,
                                 return_error=True)
    clear = veil.reflectance(brdf, np.atleast_1d(ti), np.atleast_1d(tr), np.atleast_1d(pi_),
                             np.atleast_1d(pr))
    return np.ravel(value), np.ravel(clear), np.ravel(error)


# -- values -------------------------------------------------------------------------------

def test_table_prints_the_api_values():
    result = run(BASE + ["--theta-i", "45", "--theta-r", "50"])
    assert result.exit_code == 0, result.output
    printed = {m[1]: m[2] for m in re.finditer(r"^(apparent|clear|error|ratio)\s+(\S+)",
                                               result.stdout, re.M)}
    value, clear, error = api(veil.BRDF1, veil.BTDF2, 45.0, 50.0)
    assert float(printed["apparent"]) == pytest.approx(value[0], rel=1e-11)
    assert float(printed["clear"]) == pytest.approx(clear[0], rel=1e-11)
    assert float(printed["error"]) == pytest.approx(error[0], rel=1e-2)
    assert float(printed["ratio"]) == pytest.approx(value[0] / clear[0], rel=1e-11)
    # the medium strongly attenuates the specular peak at these angles
    assert value[0] < 0.1 * clear[0]
    assert "theta_i = 45 deg, phi_i = 180 deg" in result.stdout
    assert "theta_r = 50 deg, phi_r = 0 deg" in result.stdout


def test_json_structure_and_values():
    out = run_json(BASE + ["--theta-i", "45", "--theta-r", "50"])
    assert set(out) >= {"brdf", "medium", "accuracy", "theta_i", "phi_i", "theta_r", "phi_r",
                        "apparent", "clear", "error"}
    assert out["theta_i"] == [45.0] and out["theta_r"] == [50.0]
    assert out["phi_i"] == [180.0] and out["phi_r"] == [0.0]  # documented defaults
    assert out["accuracy"] == "fast"
    assert out["brdf"] == {"model": "torrance-sparrow", "Pd": 200.0, "Ps": 5e5, "n": 0.8,
                           "eta": 1.55}
    assert out["medium"]["Tt"] == 0.13 and out["medium"]["variant"] == "paper"
    value, clear, error = api(veil.BRDF1, veil.BTDF2, 45.0, 50.0)
    assert out["apparent"] == value.tolist()
    assert out["clear"] == clear.tolist()
    assert out["error"] == error.tolist()
    assert 0 < out["error"][0] < 0.05 * out["apparent"][0]


def test_azimuths_are_used():
    out = run_json(BASE + ["--theta-i", "45", "--theta-r", "50", "--phi-i", "150",
                           "--phi-r", "20"])
    value, clear, _ = api(veil.BRDF1, veil.BTDF2, 45.0, 50.0, 150.0, 20.0)
    default, _, _ = api(veil.BRDF1, veil.BTDF2, 45.0, 50.0)
    assert out["phi_i"] == [150.0] and out["phi_r"] == [20.0]
    assert out["apparent"] == value.tolist() and out["clear"] == clear.tolist()
    assert abs(value[0] - default[0]) > 1e-3 * default[0]  # a real change, not ignored


def test_literal_models():
    preset = run_json(BASE + ["--theta-i", "45", "--theta-r", "50"])
    literal = run_json(["eval", "--brdf", "200, 5e5, 0.8, 1.55", "--medium",
                        "1e-3,0.13,0.93,1.3", "--accuracy", "fast", "--theta-i", "45",
                        "--theta-r", "50"])
    assert literal["apparent"] == preset["apparent"]
    other = run_json(["eval", "--brdf", "1000,2e5,0.3,1.4", "--medium", "0.002,0.2,0.9,1.2",
                      "--accuracy", "fast", "--theta-i", "45", "--theta-r", "50"])
    value, clear, _ = api(veil.TorranceSparrow(1000, 2e5, 0.3, 1.4),
                          veil.HenyeyGreenstein(0.002, 0.2, 0.9, 1.2), 45.0, 50.0)
    assert other["apparent"] == value.tolist() and other["clear"] == clear.tolist()
    assert other["medium"] == {"model": "henyey-greenstein", "Td": 0.002, "Tt": 0.2, "g": 0.9,
                               "eta": 1.2, "variant": "paper"}
    assert other["apparent"] != preset["apparent"]


def test_clear_medium_gives_apparent_equal_clear():
    out = run_json(["eval", "--brdf", "BRDF2", "--medium", "none", "--theta-i", "20",
                    "--theta-r", "25"])
    assert out["medium"] is None
    assert out["apparent"] == out["clear"] == veil.reflectance(veil.BRDF2, [20.0], [25.0]).tolist()
    assert out["error"] == [0.0]
    table = run(["eval", "--brdf", "BRDF2", "--medium", "NONE", "--theta-i", "20",
                 "--theta-r", "25"])
    assert table.exit_code == 0
    assert re.search(r"^ratio\s+1\s", table.stdout, re.M)


def test_variant_exit():
    out = run_json(BASE + ["--theta-i", "45", "--theta-r", "50", "--variant", "exit"])
    value, _, _ = api(veil.BRDF1, veil.BTDF2.replace(variant="exit"), 45.0, 50.0)
    paper, _, _ = api(veil.BRDF1, veil.BTDF2, 45.0, 50.0)
    assert out["medium"]["variant"] == "exit"
    assert out["apparent"] == value.tolist()
    assert out["apparent"][0] != paper[0]


# -- CSV ------------------------------------------------------------------------------------

def test_csv_round_trip(tmp_path):
    src = tmp_path / "configs.csv"
    src.write_text(CSV_TEXT)
    dst = tmp_path / "out.csv"
    result = run(BASE + ["--configs", str(src), "-o", str(dst)])
    assert result.exit_code == 0, result.output
    assert src.read_text() == CSV_TEXT  # input untouched
    assert "wrote 3 configurations" in result.stderr
    with open(dst, newline="") as fh:
        rows = list(csv.reader(fh))
    with io.StringIO(CSV_TEXT) as fh:
        original = list(csv.reader(fh))
    assert rows[0] == original[0] + ["apparent", "clear", "error"]
    for got, want in zip(rows[1:], original[1:]):
        assert got[:6] == want  # passthrough verbatim, "007" stays "007", same row order
    assert len(rows) == 4
    got = np.array([[float(x) for x in r[6:]] for r in rows[1:]])
    value, clear, error = api(veil.BRDF1, veil.BTDF2, CSV_ANGLES["theta_i"],
                              CSV_ANGLES["theta_r"], CSV_ANGLES["phi_i"], CSV_ANGLES["phi_r"])
    np.testing.assert_array_equal(got[:, 0], value)  # repr round-trips exactly
    np.testing.assert_array_equal(got[:, 1], clear)
    np.testing.assert_array_equal(got[:, 2], error)
    assert len(set(got[:, 0])) == 3
    assert sorted(os.listdir(tmp_path)) == ["configs.csv", "out.csv"]  # no temp file left

    # stdout gets the same bytes; a second run is identical (deterministic) and replaces -o
    again = run(BASE + ["--configs", str(src)])
    assert again.exit_code == 0
    assert again.stdout == dst.read_text()
    dst.write_text("old content\n")
    run(BASE + ["--configs", str(src), "-o", str(dst)])
    assert dst.read_text() == again.stdout


def test_csv_in_plane_and_goniometer_forms(tmp_path):
    """The three angle forms of measurement tables (docs/model.md sec. 1) give the same values
    as the four angles they mean; the input's columns pass through unchanged."""
    forms = {
        "full": "theta_i,phi_i,theta_r,phi_r\n45,180,15,0\n15,0,75,0\n",
        "inplane": "theta_i,theta_r\n45,15\n-15,75\n",
        "goniometer": "psi,rho,id\n60,15,a\n60,-45,b\n",
    }
    values = {}
    for name, text in forms.items():
        src = tmp_path / f"{name}.csv"
        src.write_text(text)
        result = run(BASE + ["--configs", str(src)])
        assert result.exit_code == 0, result.output
        rows = list(csv.reader(io.StringIO(result.stdout)))
        assert rows[0] == text.splitlines()[0].split(",") + ["apparent", "clear", "error"]
        values[name] = np.array([[float(x) for x in r[-3:]] for r in rows[1:]])
    np.testing.assert_array_equal(values["inplane"], values["full"])
    np.testing.assert_allclose(values["goniometer"], values["full"], rtol=1e-12)


def test_csv_json(tmp_path):
    src = tmp_path / "configs.csv"
    src.write_text(CSV_TEXT)
    out = run_json(BASE + ["--configs", str(src)])
    for name, values in CSV_ANGLES.items():
        assert out[name] == values.tolist()
    value, clear, error = api(veil.BRDF1, veil.BTDF2, CSV_ANGLES["theta_i"],
                              CSV_ANGLES["theta_r"], CSV_ANGLES["phi_i"], CSV_ANGLES["phi_r"])
    assert out["apparent"] == value.tolist() and out["clear"] == clear.tolist()
    assert out["error"] == error.tolist()
    dst = tmp_path / "out.json"
    result = run(BASE + ["--configs", str(src), "--json", "-o", str(dst)])
    assert result.exit_code == 0 and result.stdout == ""
    assert json.loads(dst.read_text()) == out


# -- user errors ------------------------------------------------------------------------------

@pytest.mark.parametrize("args, expected", [
    (["--theta-i", "90", "--theta-r", "10"], ["--theta-i", "90", "[0, 90)"]),
    (["--theta-i", "10", "--theta-r", "-5"], ["--theta-r", "-5", "[0, 90)"]),
    (["--theta-i", "nan", "--theta-r", "10"], ["--theta-i", "nan", "finite"]),
    (["--theta-i", "10", "--theta-r", "inf"], ["--theta-r", "inf", "finite"]),
    (["--theta-i", "10", "--theta-r", "10", "--phi-i", "-inf"], ["--phi-i", "finite"]),
    (["--theta-i", "10"], ["missing --theta-r"]),
    (["--theta-i", "x", "--theta-r", "10"], ["--theta-i", "'x'"]),
    (["--theta-i", "10", "--theta-r", "10", "--medium", "1e-3,0.1,1.0,1.3"], ["--medium", "g = 1", "(-1, 1)"]),
    (["--theta-i", "10", "--theta-r", "10", "--medium", "1e-3,0.1,-1,1.3"], ["--medium", "g = -1"]),
    (["--theta-i", "10", "--theta-r", "10", "--medium", "1e-3,0.1,0.9,0"], ["--medium", "eta = 0"]),
    (["--theta-i", "10", "--theta-r", "10", "--medium", "1e-3,-0.1,0.9,1.3"], ["--medium", "Tt = -0.1"]),
    (["--theta-i", "10", "--theta-r", "10", "--medium", "1e-3,nan,0.9,1.3"], ["--medium", "Tt = nan", "finite"]),
    (["--theta-i", "10", "--theta-r", "10", "--brdf", "-200,5e5,0.8,1.55"], ["--brdf", "Pd = -200"]),
    (["--theta-i", "10", "--theta-r", "10", "--brdf", "200,5e5,0.8,-1"], ["--brdf", "eta = -1"]),
    (["--theta-i", "10", "--theta-r", "10", "--brdf", "200,inf,0.8,1.5"], ["--brdf", "Ps = inf", "finite"]),
    (["--theta-i", "10", "--theta-r", "10", "--brdf", "200,5e5,0.8"], ["--brdf", "4 numbers"]),
    (["--theta-i", "10", "--theta-r", "10", "--brdf", "BRDF9"], ["--brdf", "BRDF9"]),
    (["--theta-i", "10", "--theta-r", "10", "--brdf", "BTDF1"], ["--brdf", "not a BRDF"]),
    (["--theta-i", "10", "--theta-r", "10", "--accuracy", "best"], ["--accuracy", "best"]),
    (["--theta-i", "10", "--theta-r", "10", "--variant", "odd"], ["--variant", "odd"]),
    (["--theta-i", "10", "--theta-r", "10", "-o", "x.json"], ["-o/--output", "--json"]),
])
def test_bad_options_exit_2(args, expected):
    base = ["eval", "--brdf", "BRDF1", "--medium", "BTDF2"]
    # later occurrences of --brdf/--medium override the defaults above
    result = run(base + args)
    assert result.exit_code == 2, result.output
    for text in expected:
        assert text in result.output


ROWS = "(rows counted as lines of the file, header = row 1)"


@pytest.mark.parametrize("text, expected", [
    ("theta_i,phi_i,theta_r\n10,180,10\n", ["missing column 'phi_r'"]),
    ("theta_i,phi_r\n10,0\n", ["missing columns 'phi_i', 'theta_r'"]),
    ("theta_i,theta_r\n10,abc\n", ["line 2 of", "column 'theta_r'", "'abc' is not a number"]),
    ("psi,theta_r\n60,10\n", ["'psi' but not 'rho'"]),
    ("x,y\n1,2\n", ["no angle columns", "psi,rho (goniometer)"]),
    ("theta_i,phi_i,theta_r,phi_r\n10,180,10,0\n10,abc,10,0\n",
     ["row 3", ROWS, "column 'phi_i'", "'abc' is not a number"]),
    ("theta_i,phi_i,theta_r,phi_r\n10,180,10,0\n\n10,180,,0\n",
     ["row 4", "column 'theta_r'", "empty cell"]),
    ("theta_i,phi_i,theta_r,phi_r\n10,180,10\n", ["row 2", "column 'phi_r'", "empty cell"]),
    ("theta_i,phi_i,theta_r,phi_r\n10,180,10,0\nnan,180,10,0\n",
     ["row 3", "column 'theta_i'", "'nan' is not a finite number"]),
    ("theta_i,phi_i,theta_r,phi_r\n10,-inf,10,0\n", ["row 2", "column 'phi_i'", "finite"]),
    ("theta_i,phi_i,theta_r,phi_r\n10,180,10,0\n10,180,90,0\n",
     ["row 3", "column 'theta_r'", "90 deg is outside [0, 90)"]),
    ("theta_i,phi_i,theta_r,phi_r\n-1,180,10,0\n", ["row 2", "column 'theta_i'", "-1 deg"]),
    ("", ["empty", "theta_i, phi_i, theta_r, phi_r"]),
    ("theta_i,phi_i,theta_r,phi_r\n", ["no data rows"]),
    ("theta_i,phi_i,theta_r,phi_r\n10,180,10,0\n10,180,10,0,5\n", ["row 3", "5 fields", "4"]),
    ("theta_i,phi_i,theta_r,phi_r,error\n10,180,10,0,x\n", ["column 'error'", "rename"]),
])
def test_bad_csv_exit_2(tmp_path, text, expected):
    src = tmp_path / "bad.csv"
    src.write_text(text)
    dst = tmp_path / "out.csv"
    result = run(BASE + ["--configs", str(src), "-o", str(dst)])
    assert result.exit_code == 2, result.output
    assert str(src) in result.output
    for piece in expected:
        assert piece in result.output
    assert src.read_text() == text
    assert not dst.exists()  # nothing written on error


def test_output_never_the_input(tmp_path, monkeypatch):
    src = tmp_path / "configs.csv"
    src.write_text(CSV_TEXT)
    monkeypatch.chdir(tmp_path)
    for out in (str(src), "configs.csv", "./configs.csv", "../" + tmp_path.name + "/configs.csv"):
        result = run(BASE + ["--configs", "configs.csv", "-o", out])
        assert result.exit_code == 2
        assert "never overwrites an input" in result.output
        assert src.read_text() == CSV_TEXT
    os.symlink(src, tmp_path / "link.csv")
    result = run(BASE + ["--configs", "configs.csv", "-o", "link.csv"])
    assert result.exit_code == 2 and src.read_text() == CSV_TEXT


def test_other_usage_errors(tmp_path):
    src = tmp_path / "configs.csv"
    src.write_text(CSV_TEXT)
    result = run(BASE + ["--configs", str(src), "--theta-i", "10"])
    assert result.exit_code == 2 and "--theta-i cannot be combined with --configs" in result.output
    result = run(BASE + ["--configs", str(tmp_path / "nope.csv")])
    assert result.exit_code == 2 and "nope.csv" in result.output
    result = run(BASE + ["--configs", str(src), "-o", str(tmp_path / "no" / "out.csv")])
    assert result.exit_code == 2 and "does not exist" in result.output
    result = run(BASE + ["--configs", str(src), "-o", str(tmp_path)])
    assert result.exit_code == 2


# -- the installed command ----------------------------------------------------------------------

def test_help_explains_every_option():
    top = subprocess.run([VEIL, "--help"], capture_output=True, text=True, timeout=60)
    assert top.returncode == 0 and "eval" in top.stdout and "degrees" in top.stdout
    sub = subprocess.run([VEIL, "eval", "--help"], capture_output=True, text=True, timeout=60)
    assert sub.returncode == 0
    flat = " ".join(sub.stdout.split())
    for param in eval_command.params:
        assert param.help, f"option {param.name} has no help"
        assert param.opts[-1] in sub.stdout
        assert " ".join(param.help.split())[:40] in flat
    by_name = {p.name: " ".join(p.help.split()) for p in eval_command.params}
    for name in ("theta_i", "theta_r", "phi_i", "phi_r", "configs"):
        assert "degrees" in by_name[name]
    assert "[0, 90)" in by_name["theta_i"] and "180" in by_name["phi_i"]
    assert "1/deg" in by_name["brdf_text"] and "(-1, 1)" in by_name["medium_text"]
    assert "none" in by_name["medium_text"] and "1/sr" in by_name["as_json"]


def test_installed_command_user_error_has_no_traceback(tmp_path):
    src = tmp_path / "c.csv"
    src.write_text("theta_i,phi_i,theta_r,phi_r\n10,180,x,0\n")
    proc = subprocess.run([VEIL, "eval", "--brdf", "BRDF1", "--medium", "BTDF2",
                           "--configs", str(src)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    assert "row 2" in proc.stderr and "column 'theta_r'" in proc.stderr
