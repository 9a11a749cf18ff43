"""Hostile use of the command line, third round: messages that named the library's Python
keywords instead of the command's options, an empty output path of a command writing a
folder, an output path that is a symbolic link, a measurement table whose header has stray
bytes (a doubled byte-order mark), nan given to an option with a range; then the joint fit's
sessions said in the library's words, a step's ``fixed=``, nan and inf given to any number
option, a table saved as UTF-16. Each is refused with status 2 and a message naming the
option or the file, or (a link) written through."""

from __future__ import annotations

import os
import stat

import pytest

from support.cli import run_checked
from test_hostile_tools import _refused, plastic  # noqa: F401 (plastic: a fixture)

#: A small measurement table (goniometer form), enough for the checks before any fit.
TABLE = "psi,rho,value,sigma\n" + "".join(
    f"{psi},{rho},{1.0 + 0.01 * rho},0.01\n" for psi in (30, 90) for rho in (-20, -5, 0, 5, 20)
)


@pytest.fixture
def table(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text(TABLE)
    return path


def _said(r) -> str:
    return " ".join(r.output.split())


# -- 1. the command's options, not the library's Python keywords --------------------------
@pytest.mark.parametrize("args, option, keyword", [
    # was "fine_step = 0.0001 deg, coarse_step = 5 deg would make 6e+05 configurations"
    (["simulate", "--brdf", "BRDF1", "--medium", "none", "--fine-step", "0.0001"],
     "--fine-step 0.0001 deg, --coarse-step 5 deg", "fine_step"),
    (["simulate", "--brdf", "BRDF1", "--medium", "none", "--window", "-1"],  # "window = -1"
     "--window -1.0 deg", "window ="),
    (["design", "--brdf", "BRDF1", "--medium", "BTDF2", "--fine-step", "0.00001"],
     "--fine-step 1e-05 deg", "fine_step"),
    (["design", "--brdf", "BRDF1", "--medium", "BTDF2", "--noise", "inf"],  # "noise = inf"
     "--noise inf", "noise ="),
    (["design", "--brdf", "BRDF1", "--medium", "BTDF2", "--noise-floor", "inf"],
     "--noise-floor inf", "noise floor ="),
    (["render", "--brdf", "BRDF1", "--light-theta", "130"],  # was "light_theta = 130"
     "--light-theta 130", "light_theta"),
])
def test_library_checks_name_the_commands_options(tmp_path, args, option, keyword):
    out = tmp_path / ("x.png" if args[0] == "render" else "x.csv")
    r = _refused([*args, "-o", out], option)
    assert keyword not in r.output and not out.exists()


@pytest.mark.parametrize("option", ["--max-relative", "--max-correlation"])
def test_diagnose_thresholds_of_nan_name_the_option(plastic, table, tmp_path, option):
    # was "max_relative = nan; expected a number in (0, inf]" (nan passes click's FloatRange)
    r = _refused(["diagnose", plastic, "--data", table, option, "nan", "-o", tmp_path / "d"],
                 option, "not a number")
    assert "max_" not in r.output and not (tmp_path / "d").exists()


@pytest.mark.parametrize("option", ["--noise", "--noise-floor"])
def test_design_noise_of_nan_is_refused_by_the_option(tmp_path, option):
    _refused(["design", "--brdf", "BRDF1", "--medium", "BTDF2", option, "nan", "-o",
              tmp_path / "p.csv"], option, "not a number")
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("extra, said", [
    # was "reference= given but no session of the reference object"
    (["--reference", "BRDF2"], "--reference given but no session"),
    # was "... give reference= (the step-0 result or a BRDF model) ..."
    (["--reference-session", "low={table}"], "give --reference (the step-0 result"),
    # was "... give reference=, or fix one scale, e.g. fixed={'Td[label]': ...} (--fix ...)"
    ([], "give --reference, or fix one scale, e.g. --fix 'Td[label]=...'"),
])
def test_joint_says_its_reference_and_fix_options(table, tmp_path, extra, said):
    extra = [e.format(table=table) for e in extra]
    out = tmp_path / "j.json"
    r = _refused(["fit", "joint", "--session", f"low={table}", *extra, "--accuracy", "fast",
                  "-o", out])
    assert said in _said(r), r.output
    assert "reference=" not in r.output and "fixed=" not in r.output and not out.exists()


def test_option_words_keep_what_the_library_says_for_python():
    from veil.cli._errors import option_words

    names = {"channel": "--channel", "reference": "--reference"}
    text = "fit one channel with --channel NAME (channel= in Python); (reference=) given"
    assert option_words(text, names) == (
        "fit one channel with --channel NAME (channel= in Python); (--reference) given")


@pytest.mark.parametrize("args, said", [
    # was "--brdf '-1,1,1,1': TorranceSparrow.Pd = -1 is outside [0, inf]"
    (["simulate", "--brdf=-1,1,1,1", "--medium", "none"], "torrance-sparrow Pd = -1 is outside"),
    (["simulate", "--brdf", "BRDF1", "--medium=1,1,2,1"], "henyey-greenstein g = 2 is outside"),
])
def test_model_messages_name_the_family_not_its_python_class(tmp_path, args, said):
    r = _refused([*args, "-o", tmp_path / "x.csv"], said)
    assert "TorranceSparrow" not in r.output and "HenyeyGreenstein" not in r.output


def test_a_result_file_with_a_bad_parameter_names_the_family(plastic, tmp_path):
    import json

    data = json.loads(plastic.read_text())
    data["params"]["rho"] = -1
    plastic.write_text(json.dumps(data))
    r = _refused(["export", plastic, "--to", "csv", "-o", tmp_path / "x.csv"], "p.json",
                 "rough-plastic rho = -1")  # was "RoughPlastic.rho = -1"
    assert "RoughPlastic" not in r.output


# -- 2. an empty output path of a command writing a folder -------------------------------
@pytest.mark.parametrize("args", [
    ["fit", "pipeline", "--reference-clear", "{table}", "--reference-medium", "{table}",
     "--target-medium", "{table}", "--accuracy", "fast"],
    ["fit", "maps", "{table}", "{table}"],
    ["maps", "export", "{table}"],
    ["diagnose", "{plastic}", "--data", "{table}"],
    ["demo", "--accuracy", "fast"],
    ["reproduce", "--accuracy", "fast"],
])
def test_empty_output_folder_is_refused_up_front(tmp_path, monkeypatch, plastic, table, args):
    # each wrote its files into the current directory (fit pipeline, diagnose, demo,
    # reproduce: status 0, among the user's files)
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    args = [a.format(table=table, plastic=plastic) for a in args]
    r = _refused([*args, "-o", ""], "-o", "the path is empty; give a folder name")
    assert os.listdir(work) == [], r.output


def test_empty_output_file_says_empty_not_a_directory(plastic, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # was "output . is a directory; give a file name"
    _refused(["export", plastic, "--to", "csv", "-o", ""], "--output",
             "the path is empty; give a file name")


# -- 3. an output path that is a symbolic link: written through, the link kept -----------
def test_output_file_that_is_a_link_is_written_through(plastic, tmp_path):
    real = tmp_path / "real.csv"
    real.write_text("old\n")
    real.chmod(0o640)
    link = tmp_path / "link.csv"
    link.symlink_to("real.csv")
    r = run_checked(["export", plastic, "--to", "csv", "-o", link])
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and os.readlink(link) == "real.csv"  # was a regular file
    assert real.read_text().startswith("brdf_model,") and stat.S_IMODE(real.stat().st_mode) == 0o640


def test_output_file_that_is_a_dangling_link_creates_its_target(plastic, tmp_path):
    link = tmp_path / "link.csv"
    link.symlink_to("new.csv")
    r = run_checked(["export", plastic, "--to", "csv", "-o", link])
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and (tmp_path / "new.csv").read_text().startswith("brdf_model,")


def test_output_link_into_a_missing_directory_is_refused(plastic, tmp_path):
    link = tmp_path / "link.csv"
    link.symlink_to(tmp_path / "gone" / "x.csv")
    r = _refused(["export", plastic, "--to", "csv", "-o", link], "link.csv",
                 "a symbolic link to", "does not exist")
    assert link.is_symlink() and not (tmp_path / "gone").exists(), r.output


def test_output_link_to_an_input_is_refused(table, tmp_path):
    link = tmp_path / "out.json"
    link.symlink_to(table)
    _refused(["fit", "reference", table, "-o", link], "never overwrites an input")
    assert link.is_symlink() and table.read_text() == TABLE


@pytest.mark.parametrize("dangling", [False, True])
def test_output_folder_that_is_a_link_is_written_through(tmp_path, dangling):
    from veil.io import output_folder, write_text_atomic

    real = tmp_path / "real"
    if not dangling:
        real.mkdir()
        (real / "mine.txt").write_text("mine")
    link = tmp_path / "link"
    link.symlink_to("real")
    with output_folder(link, owned=["a.txt"]) as folder:  # dangling: was NotADirectoryError
        write_text_atomic(folder / "a.txt", "new")
    assert link.is_symlink() and (real / "a.txt").read_text() == "new"
    assert dangling or (real / "mine.txt").read_text() == "mine"


def test_output_folder_link_into_a_missing_directory_is_refused(tmp_path):
    from veil.errors import UnwritableError
    from veil.io import output_folder

    link = tmp_path / "link"
    link.symlink_to(tmp_path / "gone" / "d")
    with pytest.raises(UnwritableError, match="link.* is a symbolic link to .*does not exist"):
        with output_folder(link):
            pass


# -- 4. a header with stray bytes: a doubled byte-order mark, control bytes ---------------
@pytest.mark.parametrize("prefix, said", [
    (b"\xef\xbb\xbf\xef\xbb\xbf", "repeated byte-order mark"),  # was status 3 (KeyError)
    (b"\x00\x01", "bytes that are not text"),  # was "has column 'rho' but not 'psi'"
])
def test_header_with_stray_bytes_names_the_file(tmp_path, prefix, said):
    path = tmp_path / "bom.csv"
    path.write_bytes(prefix + TABLE.encode())
    r = _refused(["fit", "reference", path, "-o", tmp_path / "r.json"], "bom.csv",
                 "stray bytes in column 1", said, "psi,rho,value")
    assert not (tmp_path / "r.json").exists(), r.output
    _refused(["eval", "--brdf", "BRDF1", "--medium", "none", "--configs", path], "bom.csv",
             "stray bytes", said)


def test_header_with_stray_text_before_a_column_says_so(tmp_path):
    path = tmp_path / "x.csv"
    path.write_bytes(b"\xef\xbb\xbfxx" + TABLE.encode())
    _refused(["fit", "reference", path, "-o", tmp_path / "r.json"], "x.csv",
             "column 'xxpsi' looks like 'psi' with stray characters before it")


# -- 5. the joint fit's sessions, a step's --fix, a joint result's channel ----------------
@pytest.mark.parametrize("extra, said", [
    # was "(object 'reference', medium 'none')" and "for medium low, object target"
    ([], ["(--reference-session none=PATH)", "for medium low, the target (--session)"]),
    (["--reference-session", "low={table}"],
     ["add its clear-water session (--reference-session none=PATH)"]),
    # was "medium 'mid' has a reference session but no target session"
    (["--reference-session", "mid={table}", "--reference-session", "none={table}"],
     ["medium 'mid' has a session of the reference (--reference-session mid=PATH) but none "
      "of the target (--session mid=PATH)"]),
    (["--session", "low={table}"], ["two sessions of the target in medium 'low' "
                                    "(--session low=PATH)"]),
    (["--reference", "BRDF2"], ["its sessions (--reference-session LABEL=PATH)"]),
])
def test_joint_names_sessions_by_their_options(table, tmp_path, extra, said):
    extra = [e.format(table=table) for e in extra]
    out = tmp_path / "j.json"
    r = _refused(["fit", "joint", "--session", f"low={table}", *extra, "--accuracy", "fast",
                  "-o", out])
    for words in said:
        assert words in _said(r), r.output
    assert "object '" not in r.output and "object target" not in r.output and not out.exists()


def test_joint_in_python_keeps_the_sessions_python_form(table):
    from veil.errors import FitError
    from veil.fitting import Session, build

    with pytest.raises(FitError, match=r"\(object 'reference', medium 'none'\)"):
        build([Session(str(table), "low", "target")])


def test_a_step_short_of_points_says_fix_on_the_command_line(tmp_path):
    import veil
    from veil.errors import FitError

    path = tmp_path / "few.csv"
    path.write_text("psi,rho,value,sigma\n30,0,1,0.01\n30,5,0.9,0.01\n90,0,1,0.01\n")
    # was "fix some with fixed=... / --fix NAME=VALUE"
    r = _refused(["fit", "reference", path, "-o", tmp_path / "r.json"],
                 "fix some with --fix NAME=VALUE, or measure")
    assert "fixed=" not in r.output
    with pytest.raises(FitError, match=r"fixed=\{'NAME': VALUE\}"):
        veil.fitting.fit_reference(str(path))


def _joint_of_channels():
    """A joint result over channels r, g, b (the target and medium 'm'), made by hand."""
    import veil
    from veil.fitting import JointResult

    params, layout = {}, {}
    for c in "rgb":
        target = {p.key: f"{p.name}[{c}]" for p in type(veil.BRDF1).PARAMS}
        medium = {p.key: f"{p.name}[m][{c}]" for p in type(veil.BTDF2).PARAMS}
        params.update({f"{k}[{c}]": v for k, v in veil.BRDF1.as_dict().items()})
        params.update({f"{k}[m][{c}]": v for k, v in veil.BTDF2.as_dict().items()})
        layout[c] = {"objects": {"target": target}, "media": {"m": medium}}
    return JointResult(
        model="joint", params=params, stderr=dict.fromkeys(params), correlation={},
        residuals=(0.0,), chi2_reduced=1.0, rms_relative=0.01, n_points=10, converged=True,
        message="", options={}, step="joint", channels={c: m["objects"]["target"]
                                                         for c, m in layout.items()},
        layout={"models": {"brdf": veil.BRDF1.NAME, "medium": veil.BTDF2.NAME},
                "channels": layout})


def test_a_joint_result_of_channels_names_the_channel_option_and_keyword():
    from veil.errors import FitError

    # was "name one (channel='r')"
    with pytest.raises(FitError, match=r"name one \(--channel r at the command line, "
                                       r"channel='r' in Python\)"):
        _joint_of_channels().medium("m")


# -- 6. number options: finite numbers only, as the command line is read ------------------
#: Number options where nan or inf means something: none has a plain float type today (a
#: ranged option, veil.cli._common.FloatRange, refuses nan and says its own range).
FLOATS_MEANING_INF: set = set()


def _float_options():
    import click

    from veil.cli import main

    def walk(command, path):
        if isinstance(command, click.Group):
            for name in command.list_commands(None):
                yield from walk(command.get_command(None, name), [*path, name])
        else:
            for p in command.params:
                if isinstance(p.type, click.types.FloatParamType):
                    yield path, p

    return list(walk(main, []))


def test_every_number_option_refuses_nan_and_inf_by_its_name():
    from click import FloatRange

    options = _float_options()
    assert len(options) > 40  # every command's, the model options included
    for path, param in options:
        flag = param.opts[-1]
        if (" ".join(path), flag) in FLOATS_MEANING_INF:
            continue
        values = ("nan",) if isinstance(param.type, FloatRange) else ("nan", "inf", "-1e400")
        for value in values:
            r = run_checked([*path, f"{flag}={value}"])  # read before any missing argument
            assert r.exit_code == 2 and f"Invalid value for '{flag}'" in r.output, (path, r.output)
            assert ("not a finite number" if len(values) > 1 else "not a number") in r.output


# -- 7. a table saved as UTF-16 or UTF-32 -------------------------------------------------
@pytest.mark.parametrize("encoding, said", [("utf-16", "UTF-16"), ("utf-32", "UTF-32")])
def test_a_utf16_table_says_so_and_how_to_save_it(tmp_path, plastic, encoding, said):
    path = tmp_path / "t.csv"
    path.write_text(TABLE, encoding=encoding)
    # was "line 1 of t.csv is not UTF-8 text (byte 0); expected a CSV text file"
    text = f"is {said} text (it begins with the {said} byte-order mark), not UTF-8: save it"
    _refused(["fit", "reference", path, "-o", tmp_path / "r.json"], "t.csv", text)
    _refused(["eval", "--brdf", "BRDF1", "--medium", "none", "--configs", path], "t.csv", text)
    result = tmp_path / "u.json"
    result.write_text(plastic.read_text(), encoding=encoding)
    _refused(["export", result, "--to", "csv", "-o", tmp_path / "x.csv"], "u.json", text)


# -- review of the rewording: what it must leave alone, what it missed ---------------------
def test_rewording_leaves_paths_quotes_and_named_options_alone(tmp_path):
    """A file named after a family or a keyword keeps its name in a message, and a value
    whose option the library already names is not named twice."""
    import veil.models.registry  # noqa: F401  (the families the rewording knows)
    from veil.cli._errors import family_words, option_words

    assert option_words("data/reference= 1", {"reference": "--reference"}) == "data/reference= 1"
    assert option_words("file 'window = 3.csv'", {"window": "--window"}) == "file 'window = 3.csv'"
    named = "max_relative = 0.3 (--max-relative) must be"
    assert option_words(named, {"max_relative": "--max-relative"}) == named
    text = "line 2 of HenyeyGreenstein.csv: TorranceSparrow.Pd = -1; out/TorranceSparrow.csv"
    assert family_words(text) == (
        "line 2 of HenyeyGreenstein.csv: torrance-sparrow Pd = -1; out/TorranceSparrow.csv")
    table = tmp_path / "HenyeyGreenstein.csv"  # was "line 2 of henyey-greenstein csv"
    table.write_text("theta_i,theta_r\n10,abc\n")
    _refused(["eval", "--brdf", "BRDF1", "--medium", "none", "--configs", table],
             "HenyeyGreenstein.csv")


@pytest.mark.parametrize("args, option, keyword", [
    (["render", "--brdf", "BRDF1", "--size", "2"], "--size 2", "size ="),
    (["render", "--brdf", "BRDF1", "--samples", "20"], "--samples 20", "samples ="),
    (["simulate", "--brdf", "BRDF1", "--medium", "none", "--psi", "200"], "--psi 200", "psi ="),
])
def test_render_and_simulate_name_their_options_too(tmp_path, args, option, keyword):
    out = tmp_path / ("x.png" if args[0] == "render" else "x.csv")
    r = _refused([*args, "-o", out], option)
    assert keyword not in r.output and not out.exists()


def test_a_link_to_no_regular_file_or_a_loop_is_refused_before_any_work(tmp_path):
    device = tmp_path / "null.json"
    device.symlink_to(os.devnull)
    loop_a, loop_b = tmp_path / "a.json", tmp_path / "b.json"
    loop_a.symlink_to(loop_b)
    loop_b.symlink_to(loop_a)
    args = ["eval", "--brdf", "BRDF1", "--medium", "none", "--theta-i", "30", "--theta-r", "40",
            "--json", "-o"]
    _refused([*args, device], "null.json", "not a regular file")
    _refused([*args, loop_a], "a.json", "loop of symbolic links")


def test_a_maps_store_given_as_a_link_is_refused(tmp_path):
    from veil.errors import InputError
    from veil.maps.store import check_store_path

    link = tmp_path / "maps.zarr"
    link.symlink_to(tmp_path / "new.zarr")  # was "exists and is not a veil maps store"
    with pytest.raises(InputError, match="maps.zarr is a symbolic link"):
        check_store_path(link)


def test_a_column_of_its_own_is_not_taken_for_stray_text(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("theta_i,sigma_theta_r,value\n10,0.1,1\n")
    r = _refused(["eval", "--brdf", "BRDF1", "--medium", "none", "--configs", path],
                 "has column 'theta_i' but not 'theta_r'")
    assert "looks like" not in r.output
