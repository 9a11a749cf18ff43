"""Hostile use of the command line, fifth round: an output path that is a device or a named
pipe (``-o /dev/null`` put a regular file in place of /dev/null), an output file path ending
in '/', a manifest with a NUL byte in a file name (status 3), a manifest row naming a folder
or a pipe, a manifest row with more cells than the header, an unclosed quote or a byte that
is not UTF-8 (the line named), an angle beyond float64 (numpy's repr in the message), an
empty or all-white-space result file, a dark frame that is one of the photos measured, and
a photo whose ROI is flat (sigma 0, which a fit refuses). Each is status 2 naming the file,
line or option, nothing written, the inputs unchanged; or, for the flat ROI, a warning."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from support.cli import run_checked
from test_hostile_tools import _refused, _result, plastic  # noqa: F401 (plastic: a fixture)
from test_ingest import write_manifest, write_png
from veil.errors import NotAFileError
from veil.io import write_text_atomic

H, W = 20, 30
ROI = "5,5,10,8"


@pytest.fixture
def stack(tmp_path):
    """Three 16-bit grey photos of noise and their manifest."""
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(1)
    names = [f"p{k}.png" for k in range(3)]
    for k, name in enumerate(names):
        write_png(photos / name, rng.normal(500 + 50 * k, 10, (H, W)).astype(np.uint16))
    return photos, write_manifest(tmp_path / "m.csv", names)


def _ingest(stack, tmp_path, *extra):
    photos, manifest = stack
    return run_checked(["ingest", photos, "--manifest", manifest, "--roi", ROI,
                        "-o", tmp_path / "out.csv", *extra])


def _said(r) -> str:
    return " ".join(r.output.split())


# -- 1. an output that is a device or a pipe, or a path ending in '/' ----------------------
@pytest.mark.parametrize("command", [
    lambda out, res: ["export", res, "--to", "csv", "-o", out],  # OutputPath, at parsing
    lambda out, res: ["eval", "--brdf", "BRDF1", "--medium", "none", "--configs",
                      res.parent / "c.csv", "-o", out],  # click.Path, checked by the command
    lambda out, res: ["simulate", "--brdf", "BRDF1", "--medium", "none", "-o", out],
])
def test_an_output_that_is_a_named_pipe_is_refused_and_left_a_pipe(plastic, tmp_path, command):
    """Each output was a temporary file renamed over the pipe: status 0 and the pipe gone
    (``-o /dev/null`` as root replaced /dev/null by a regular file)."""
    (tmp_path / "c.csv").write_text("theta_i,theta_r\n30,30\n")
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    _refused(command(fifo, plastic), "pipe.csv", "named pipe (FIFO)", "not a regular file")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


@pytest.mark.skipif(os.geteuid() != 0, reason="making a device node needs root")
def test_an_output_that_is_a_character_device_is_refused(plastic, tmp_path):
    null = tmp_path / "null.csv"
    os.mknod(null, 0o666 | stat.S_IFCHR, os.makedev(1, 3))  # a /dev/null of the test's own
    _refused(["export", plastic, "--to", "csv", "-o", null], "null.csv", "character device")
    _refused(["simulate", "--brdf", "BRDF1", "--medium", "none", "-o", null],
             "character device")
    png = tmp_path / "null.png"
    os.mknod(png, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    _refused(["render", "--brdf", "BRDF1", "--size", "8", "-o", png], "character device")
    assert stat.S_ISCHR(os.stat(null).st_mode) and stat.S_ISCHR(os.stat(png).st_mode)


def test_the_library_writer_refuses_a_named_pipe(tmp_path):
    fifo = tmp_path / "pipe.txt"
    os.mkfifo(fifo)
    with pytest.raises(NotAFileError, match="named pipe"):
        write_text_atomic(fifo, "x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert os.listdir(tmp_path) == ["pipe.txt"]  # no temporary left


@pytest.mark.parametrize("how", ["export", "eval"])
def test_an_output_file_path_ending_in_a_slash_is_refused(plastic, tmp_path, monkeypatch, how):
    """``-o results/`` (a folder meant) wrote a file named results."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.csv").write_text("theta_i,theta_r\n30,30\n")
    args = {"export": ["export", plastic, "--to", "csv", "-o", "results/"],
            "eval": ["eval", "--brdf", "BRDF1", "--medium", "none", "--configs", "c.csv",
                     "-o", "results/"]}[how]
    _refused(args, "results/", "ends in '/'", "give a file name")
    assert not (tmp_path / "results").exists()


def test_ingest_output_ending_in_a_slash_is_refused(stack, tmp_path):
    photos, manifest = stack
    r = run_checked(["ingest", photos, "--manifest", manifest, "--roi", ROI,
                     "-o", f"{tmp_path}/table/"])
    assert r.exit_code == 2 and "ends in '/'" in r.output, r.output
    assert not (tmp_path / "table").exists()


# -- 2. the manifest ---------------------------------------------------------------------
def test_a_nul_byte_in_a_manifests_file_name_is_named_not_a_crash(stack, tmp_path):
    photos, manifest = stack
    manifest.write_text(manifest.read_text().replace("p1.png", "p1\x00.png"))
    before = manifest.read_bytes()
    r = _ingest(stack, tmp_path)
    assert r.exit_code == 2, r.output  # was 3: ValueError: embedded null byte
    assert "line 3 of" in r.output and "NUL byte" in r.output and "column 'file'" in r.output
    assert manifest.read_bytes() == before and not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("kind, said", [("dir", "is a directory"),
                                        ("fifo", "is a named pipe (FIFO)")])
def test_a_manifest_row_naming_no_photo_file_says_what_it_is(stack, tmp_path, kind, said):
    """Was "1 photo(s) listed in the manifest are not in photos": it is there, as a folder."""
    photos, _ = stack
    (photos / "p1.png").unlink()
    (os.mkdir if kind == "dir" else os.mkfifo)(photos / "p1.png")
    r = _ingest(stack, tmp_path)
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert "line 3 of" in text and f"'p1.png' {said}" in text and "not a photo file" in text
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("line, said", [
    ("p9.png,60,30,target,extra,more", "line 5 of"),  # was pandas' "C error: Expected 4 ..."
    ('"p9.png,60,30,target', "line 5 of"),  # was "EOF inside string starting at row 4"
])
def test_a_manifest_that_is_no_csv_names_the_line(stack, tmp_path, line, said):
    photos, manifest = stack
    manifest.write_text(manifest.read_text() + line + "\n")
    r = _ingest(stack, tmp_path)
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert said in text and "m.csv" in text and "C error" not in text and "row 4" not in text
    assert ("has 6 cells, but the header has 4 columns" in text
            or "opens a quoted cell" in text), text


def test_a_latin1_manifest_names_the_line_and_byte(stack, tmp_path):
    photos, manifest = stack
    manifest.write_bytes(manifest.read_bytes().replace(b"target", b"caf\xe9", 2))
    r = _ingest(stack, tmp_path)
    assert r.exit_code == 2, r.output
    text = _said(r)
    # was "('utf-8' codec can't decode byte 0xe9 in position 3: ...)"
    assert "m.csv is not UTF-8 text: line 2 holds the byte 0xe9" in text, text
    assert "position" not in text


def test_an_angle_beyond_float64_is_said_without_numpys_repr(stack, tmp_path):
    photos, manifest = stack
    manifest.write_text(manifest.read_text().replace("60.0,10.0", "60.0,1e400"))
    r = _ingest(stack, tmp_path)
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert "column 'rho'" in text and "line 4 of" in text and "float64" in text, text
    assert "np.float64" not in text  # was "np.float64(inf) is not a finite number"


# -- 3. ingest: a dark frame among the photos, a flat ROI ----------------------------------
def test_a_dark_frame_that_is_a_listed_photo_is_refused(stack, tmp_path):
    """It read 0 +- 0 for that photo, a table that veil fit then refused."""
    photos, _ = stack
    r = _ingest(stack, tmp_path, "--dark", photos / "p0.png")
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert "dark frame" in text and "'p0.png'" in text and "line 2 of" in text
    assert not (tmp_path / "out.csv").exists()


def test_a_flat_roi_warns_of_its_zero_sigma(stack, tmp_path):
    photos, _ = stack
    write_png(photos / "p1.png", np.full((H, W), 700, np.uint16))
    r = _ingest(stack, tmp_path)
    assert r.exit_code == 0, r.output
    text = _said(r)
    assert "1 row(s) have sigma 0" in text and "(p1.png)" in text, text
    assert (tmp_path / "out.csv").exists()


# -- 4. result files that hold nothing ---------------------------------------------------
@pytest.mark.parametrize("text, said", [("", "is empty:"),
                                        (" " * 100_000, "is empty (only 100000 characters")])
@pytest.mark.parametrize("command", ["export", "render", "explore"])
def test_an_empty_result_file_says_it_is_empty(tmp_path, text, said, command):
    """Was "not valid JSON at line 1, column 100001: Expecting value"."""
    empty = tmp_path / "e.json"
    empty.write_text(text)
    out = tmp_path / "x.out"
    args = {"export": ["export", empty, "--to", "csv", "-o", out],
            "render": ["render", "--brdf", empty, "--size", "8", "-o", out.with_suffix(".png")],
            "explore": ["explore", empty, "--static", "-o", out.with_suffix(".html")]}[command]
    r = _refused(args, "e.json", said, "fit result")
    assert "not valid JSON" not in r.output
    assert sorted(os.listdir(tmp_path)) == ["e.json"]


def test_a_manifest_given_as_a_pipe_is_read_once(stack, tmp_path):
    """``--manifest <(grep ... m.csv)``: the manifest was read twice (its header again), the
    second time from an emptied pipe: status 3 (EmptyDataError)."""
    photos, manifest = stack
    read, write = os.pipe()
    try:
        os.write(write, manifest.read_bytes())
        os.close(write)
        r = run_checked(["ingest", photos, "--manifest", f"/dev/fd/{read}", "--roi", ROI,
                         "-o", tmp_path / "out.csv"])
    finally:
        os.close(read)
    assert r.exit_code == 0, r.output
    assert "3 measurement(s) written" in r.output
    assert len((tmp_path / "out.csv").read_text().splitlines()) == 4


def test_a_manifest_with_a_repeated_byte_order_mark_says_so(stack, tmp_path):
    photos, manifest = stack
    manifest.write_bytes(b"\xef\xbb\xbf\xef\xbb\xbf" + manifest.read_bytes())
    r = _ingest(stack, tmp_path)
    assert r.exit_code == 2, r.output
    assert "no column 'file'" in r.output and "repeated byte-order mark" in r.output, r.output


# -- 5. result files: a key twice, a model option of a bad value -------------------------
def _edited(path, out, old: str, new: str):
    text = path.read_text()
    assert old in text
    out.write_text(text.replace(old, new, 1))
    return out


def test_a_result_naming_a_key_twice_is_refused_naming_it(plastic, tmp_path):
    """JSON keeps the last of two values silently; was "key 'params' must map exactly rho,
    alpha, eta, ks (in this order)", or accepted where the order held."""
    twice = _edited(plastic, tmp_path / "twice.json", '"params": {', '"params": {"rho": 0.9, ')
    r = _refused(["export", twice, "--to", "csv", "-o", tmp_path / "x.csv"],
                 "twice.json", "key 'params'", "naming 'rho' twice")
    assert "in this order" not in r.output and not (tmp_path / "x.csv").exists()


def test_a_bad_model_option_in_a_result_names_the_family(tmp_path):
    """Was "HenyeyGreenstein.variant = 'zzz'", the Python class."""
    from veil.models import model_class

    hg = model_class("henyey-greenstein")
    medium = _result(hg(Td=0.001, Tt=0.1, g=0.9, eta=1.3), tmp_path / "m.json")
    bad = _edited(medium, tmp_path / "bad.json", '"variant": "paper"', '"variant": "zzz"')
    r = _refused(["render", "--brdf", "BRDF1", "--medium", bad, "--size", "8",
                  "-o", tmp_path / "x.png"], "bad.json", "henyey-greenstein variant = 'zzz'")
    assert "HenyeyGreenstein" not in r.output and not (tmp_path / "x.png").exists()


# -- 6. --black that is the data itself -------------------------------------------------
TABLE = "psi,rho,value,sigma\n" + "".join(
    f"{psi},{rho},{1.0 + 0.01 * rho},0.01\n" for psi in (30, 90) for rho in (-20, -5, 0, 5, 20)
)


@pytest.mark.parametrize("args, said", [
    (lambda t, p: ["fit", "reference", t, "--black", t], "is the measurement TABLE"),
    (lambda t, p: ["fit", "target", t, "--medium", "BTDF2", "--black", t],
     "is the measurement TABLE"),
    (lambda t, p: ["fit", "pipeline", "--reference-clear", p, "--reference-medium", p,
                   "--target-medium", t, "--black", t, "-o", t.parent / "results"],
     "is --target-medium"),
])
def test_black_that_is_the_data_itself_is_refused(tmp_path, args, said):
    """Subtracted from itself the data were all zero: the fit ran and ended with status 1,
    "session ... has no positive value"."""
    table, other = tmp_path / "t.csv", tmp_path / "o.csv"
    table.write_text(TABLE)
    other.write_text(TABLE)
    out = tmp_path / "x.json"
    cmd = args(table, other)
    r = _refused(cmd if cmd[1] == "pipeline" else [*cmd, "-o", out], said, "t.csv", "all zero")
    assert not out.exists() and not (tmp_path / "results").exists()
    assert table.read_text() == TABLE


def test_diagnose_with_black_that_is_its_data_is_refused(tmp_path):
    """Was status 0: diagnostics of data less themselves."""
    from veil.fitting.result import FitResult
    from veil.fitting.result_fields import model_entry
    from veil.models import model_class

    ts, hg = model_class("torrance-sparrow"), model_class("henyey-greenstein")
    medium = hg(Td=0.001, Tt=0.1, g=0.9, eta=1.3)
    result = tmp_path / "medium.json"
    FitResult(model=medium.NAME, params=medium.as_dict(),
              stderr={k: None for k in medium.as_dict()}, correlation={}, residuals=(0.0,),
              chi2_reduced=1.0, rms_relative=0.01, n_points=10, converged=True, message="",
              options=medium.options(), step="medium",
              given=model_entry(ts(Pd=200, Ps=5e5, n=0.8, eta=1.55))).to_json(result)
    table = tmp_path / "t.csv"
    table.write_text(TABLE)
    _refused(["diagnose", result, "--data", table, "--black", table, "-o", tmp_path / "d"],
             "--black", "is --data", "all zero")
    assert not (tmp_path / "d").exists()


# -- '-' as an output ------------------------------------------------------------------------
def test_a_dash_as_an_output_is_refused_not_a_file_named_dash(plastic, tmp_path, monkeypatch):
    """``-o -`` wrote a file named '-' (click's standard output is not what veil writes:
    each output whole or not at all); ``veil eval``, which writes to standard output
    without -o, takes it as that."""
    monkeypatch.chdir(tmp_path)
    _refused(["export", plastic, "--to", "csv", "-o", "-"], "'-'", "not standard output")
    _refused(["simulate", "--brdf", "BRDF1", "--medium", "none", "-o", "-"], "'-'")
    _refused(["fit", "reference", plastic, "-o", "-"], "'-'")
    assert not (tmp_path / "-").exists()
    r = run_checked(["eval", "--brdf", "BRDF1", "--medium", "none", "--theta-i", "30",
                     "--theta-r", "30", "-o", "-"])
    assert r.exit_code == 0 and "apparent" in r.output and not (tmp_path / "-").exists()
