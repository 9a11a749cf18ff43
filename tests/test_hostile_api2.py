"""Hostile use of the Python API, second round: angles that are no angles given to
``veil.apparent`` and ``veil.reflectance`` (shapes that do not broadcast, strings, None, a
list holding a string, NaN or inf, a ragged nested list, a bool), a preset of an unknown
kind, ``register`` given something that is no model class, an on/off flag given as "no"
or 2, and the pipeline's hint to hold parameters (it said ``--fix NAME=VALUE``; the
pipeline's ``--fix`` takes ``STEP.NAME=VALUE``). Each is refused where it enters with an
:class:`veil.errors.InputError` naming the argument and what was expected (they were raw
numpy ValueErrors and TypeErrors, an AttributeError, a silent ``True``-as-1-degree or an
empty list of known kinds); valid calls keep their numbers bit for bit."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import veil
from support.cli import run
from test_hostile_api import STEP, _refused
from veil.errors import FitError, InputError, InputTypeError


@pytest.fixture(scope="module")
def clear():
    """A small clear-water session of BRDF1 (19 configurations)."""
    return veil.simulate(veil.BRDF1, None, seed=1, **STEP)


# -- angles that are no angles -------------------------------------------------------------
FORWARD = {
    "reflectance": lambda *angles: veil.reflectance(veil.BRDF1, *angles),
    "apparent": lambda *angles: veil.apparent(veil.BRDF1, veil.BTDF2, *angles, accuracy="fast"),
}
EXPECTED = "expected angles in degrees (a number or an array of numbers)"


@pytest.mark.parametrize("forward", FORWARD.values(), ids=list(FORWARD))
@pytest.mark.parametrize("angles, error, said", [
    # was ValueError: shape mismatch: objects cannot be broadcast to a single shape
    (([10, 20, 30], [10, 20, 30, 40]), InputError,
     ["theta_r has shape (4,), which does not broadcast with theta_i of shape (3,)",
      "expected angles of one shape, or of shapes that broadcast together"]),
    ((10, [10, 20, 30], [180, 0]), InputError,
     ["phi_i has shape (2,), which does not broadcast with theta_i of shape () and "
      "theta_r of shape (3,)"]),
    # was ValueError: could not convert string to float: 'abc'
    (("abc", 10), InputTypeError, ["theta_i = 'abc': " + EXPECTED, "got str"]),
    ((10, 10, 180, "a"), InputTypeError, ["phi_r = 'a': " + EXPECTED]),
    # was "theta_r = np.float64(nan) is not a finite number"
    ((10, None), InputTypeError, ["theta_r = None: " + EXPECTED, "got NoneType"]),
    # was ValueError: could not convert string to float: 'x'
    (([10, "x"], 10), InputTypeError, ["theta_i = [10, 'x']", "it holds 'x' (str)"]),
    ((np.nan, 10), InputError, ["theta_i = nan is not a finite number", EXPECTED]),
    ((10, [20, np.inf]), InputError, ["theta_r[1] = inf is not a finite number"]),
    ((10, 10, [[0, 1], [2, -np.inf]]), InputError, ["phi_i[1, 1] = -inf is not a finite"]),
    # was ValueError: setting an array element with a sequence ... inhomogeneous shape
    (([[10, 20], [30]], 10), InputError,
     ["theta_i = [[10, 20], [30]]: nested lists of different lengths",
      "expected a number or a rectangular array of numbers"]),
    # were TypeError: float() argument must be a string or a real number
    ((10 + 1j, 10), InputTypeError, ["theta_i = (10+1j): " + EXPECTED, "got complex"]),
    (({"a": 1}, 10), InputTypeError, ["theta_i = {'a': 1}", "got dict"]),
    # was taken as 1 degree
    ((True, 10), InputTypeError, ["theta_i = True: " + EXPECTED, "got bool"]),
    ((10, np.array([True, False])), InputTypeError, ["it holds True (bool)"]),
])
def test_angles_that_are_no_angles_are_refused(forward, angles, error, said):
    _refused(error, lambda: forward(*angles), *said)


def test_angle_errors_are_value_errors():
    """An InputError is a ValueError (and an InputTypeError a TypeError) for a caller who
    catches the built-in exceptions."""
    with pytest.raises(ValueError):
        veil.reflectance(veil.BRDF1, [1, 2, 3], [1, 2])
    with pytest.raises(TypeError):
        veil.reflectance(veil.BRDF1, "45", 10)


def test_broadcast_angles_give_the_numbers_of_matched_shapes():
    """Numbers, lists, numpy scalars of other types, a pandas Series and shapes that
    broadcast work as before: bit for bit the values of the same angles given in one
    shape as float arrays."""
    ti, tr = np.array([[15.0], [45.0]]), np.array([0.0, 30.0, 60.0])
    matched = [np.broadcast_to(a, (2, 3)).copy() for a in (ti, tr, 180.0, 0.0)]
    expected = veil.reflectance(veil.BRDF1, *matched)
    assert expected.shape == (2, 3) and np.all(np.isfinite(expected))
    for call in (
        lambda: veil.reflectance(veil.BRDF1, [[15], [45]], [0, 30, 60]),
        lambda: veil.reflectance(veil.BRDF1, ti, pd.Series(tr), np.int32(180), np.float32(0)),
        lambda: veil.reflectance(veil.BRDF1, ti, tr.astype(object)),
    ):
        assert np.array_equal(call(), expected)
        assert call().tobytes() == expected.tobytes()
    one = veil.reflectance(veil.BRDF1, 45, 30)
    assert one.shape == () and one.tobytes() == expected[1, 1].tobytes()
    assert veil.reflectance(veil.BRDF1, [], []).shape == (0,)


def test_apparent_of_broadcast_angles_gives_the_numbers_of_matched_shapes():
    tr = [10.0, 40.0, 70.0]
    value = veil.apparent(veil.BRDF1, veil.BTDF2, 30, tr, accuracy="fast")
    matched = veil.apparent(veil.BRDF1, veil.BTDF2, [30.0] * 3, tr, [180.0] * 3, [0.0] * 3,
                            accuracy="fast")
    assert value.shape == (3,) and value.tobytes() == matched.tobytes()


# -- a preset of an unknown kind (was "unknown preset 'BRDF1'; known: " - nothing) ---------
def test_a_preset_of_an_unknown_kind_names_the_kinds():
    _refused(InputError, lambda: veil.preset("BRDF1", kind="zzz"),
             "preset kind = 'zzz'; expected one of 'brdf', 'medium', or None")
    _refused(InputError, lambda: veil.preset("BRDF1", kind="medium"),
             "unknown medium preset 'BRDF1' ('BRDF1' is a brdf preset); known: BTDF1, BTDF2, "
             "BTDF3")
    _refused(InputError, lambda: veil.preset("zzz"), "known: BRDF1, BRDF2, BTDF1")
    assert veil.preset("btdf2", kind="medium") is veil.BTDF2
    assert veil.preset("BRDF1") is veil.BRDF1


# -- register(something that is no model class) (was AttributeError: '__name__') ---------
@pytest.mark.parametrize("given, said", [
    (3, "register(3): expected a model class, a subclass of veil.BRDF or veil.Medium, "
        "got int (an object, not a class)"),
    ("torrance-sparrow", "register('torrance-sparrow'): expected a model class"),
    (veil.BRDF1, "got TorranceSparrow (an object, not a class)"),
    (int, "register(int): expected a model class, a subclass of veil.BRDF or veil.Medium; "
          "int is neither"),  # was ValueError: int.NAME = None
])
def test_register_takes_a_model_class_only(given, said):
    before = dict(veil.REGISTRY)
    error = _refused(InputTypeError, lambda: veil.register(given), said)
    assert isinstance(error, TypeError)
    assert veil.REGISTRY == before


# -- on/off flags given as something else (a truthy "no" or 2 was taken as True) ----------
def test_flags_of_the_forward_model_and_simulate_are_bools(clear):
    said = "return_error = 'no': expected True or False (an on/off flag), got str"
    _refused(InputError, lambda: veil.apparent(veil.BRDF1, None, 45, 45, return_error="no"),
             said)
    _refused(InputError, lambda: veil.simulate(veil.BRDF1, None, black=2, **STEP),
             "black = 2: expected True or False (an on/off flag), got int")
    _refused(InputError, lambda: veil.simulate(veil.BRDF1, None, black=None, **STEP),
             "black = None")
    # numpy's bools are bools
    value, error = veil.apparent(veil.BRDF1, None, 45, 45, return_error=np.True_)
    assert error == 0 and value == veil.reflectance(veil.BRDF1, 45, 45)
    table = veil.simulate(veil.BRDF1, None, seed=1, black=np.False_, **STEP)
    pd.testing.assert_frame_equal(table, clear, check_exact=True)


@pytest.mark.parametrize("fit", [
    lambda t: veil.fit_reference(t, screen="no"),
    lambda t: veil.fit_medium(t, veil.BRDF1, screen="no"),
    lambda t: veil.fit_target(t, veil.BTDF2, screen="no"),
    lambda t: veil.fit_joint({"low": t}, reference=veil.BRDF1, screen="no"),
])
def test_screen_is_a_bool(clear, fit):
    _refused(FitError, lambda: fit(clear),
             "screen = 'no': expected True or False (an on/off flag), got str")


@pytest.mark.parametrize("keyword", ["figures", "keep_candidates"])
def test_pipeline_flags_are_bools(clear, tmp_path, keyword):
    out = tmp_path / "out"
    _refused(FitError, lambda: veil.run_pipeline(clear, clear, clear, outdir=out,
                                                 **{keyword: 2}),
             f"{keyword} = 2: expected True or False (an on/off flag), got int")
    assert not out.exists()


def test_maps_near_field_is_a_bool(tmp_path):
    pytest.importorskip("zarr")
    _refused(InputError, lambda: veil.fit_maps(tmp_path, tmp_path / "m.csv", veil.BTDF2,
                                               tmp_path / "o.zarr", near_field="yes"),
             "near_field = 'yes': expected True or False")


# -- the pipeline's hint to hold parameters names the step ----------------------------------
def test_the_pipeline_says_how_its_fixed_takes_a_parameter(clear, tmp_path):
    # was "fix some with fixed={'NAME': VALUE} (--fix NAME=VALUE)": run_pipeline's fixed
    # is by step, and the pipeline's --fix is STEP.NAME=VALUE
    few = clear.iloc[:3]
    error = _refused(FitError, lambda: veil.run_pipeline(few, clear, clear,
                                                         outdir=tmp_path / "out"),
                     "have 3 point(s) but the fit has 4 free parameter(s)",
                     "fix some with fixed={'reference': {'NAME': VALUE}} "
                     "(--fix reference.NAME=VALUE)")
    assert "--fix NAME" not in str(error)


def test_the_step_fits_keep_their_own_hint(clear):
    _refused(FitError, lambda: veil.fit_reference(clear.iloc[:3]),
             "fix some with fixed={'NAME': VALUE} (--fix NAME=VALUE)")


def test_a_hint_of_holding_parameters_names_the_step():
    from veil.cli._errors import option_words
    from veil.fitting.step_fit import fixes_of_step

    with pytest.raises(FitError) as info, fixes_of_step("medium"):
        raise FitError("fix them at smaller values (--fix NAME=VALUE, fixed={...} in Python)")
    said = "fix them at smaller values (--fix medium.NAME=VALUE, fixed={'medium': {...}} in Python)"
    assert str(info.value) == said
    assert option_words(said, {"fixed": "--fix"}) == said
    text = "fix some with fixed={'medium': {'NAME': VALUE}} (--fix medium.NAME=VALUE), or more"
    said = "fix some with --fix medium.NAME=VALUE, or more"
    assert option_words(text, {"fixed": "--fix"}) == said


def test_the_pipeline_command_says_step_name_value(clear, tmp_path):
    paths = {}
    for name, table in (("clear", clear), ("medium", clear.iloc[:3]), ("target", clear)):
        paths[name] = tmp_path / f"{name}.csv"
        veil.save_measurements(table, paths[name])
    result = run("fit", "pipeline", "--reference-clear", paths["clear"], "--reference-medium",
                 paths["medium"], "--target-medium", paths["target"], "-o", tmp_path / "out",
                 "--no-figures", "--accuracy", "fast")
    assert result.exit_code == 2, result.output
    assert "the medium data have 3 point(s)" in result.output
    assert "(fix some with --fix medium.NAME=VALUE, or measure more" in result.output
    assert "fixed=" not in result.output
