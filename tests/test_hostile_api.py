"""Hostile (or careless) use of the Python API: arguments of the wrong type or form given to
the public functions - an accuracy in a list, options or a start that is no dict, parameter
names as a number or one string, a path that is None or a table, a simulated channel that is
no channel, a progress callback that cannot be called, a psi in radians. Each is refused
where it enters with an :class:`veil.errors.InputError` naming the argument (it was a bare
TypeError or ValueError from deep inside, or a silent wrong answer), or now does what was
meant (a float32 noise, one parameter name given as a string)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

import veil
from veil.errors import FitError, InputError, InputTypeError

STEP = {"fine_step": 10, "coarse_step": 20}


@pytest.fixture(scope="module")
def clear():
    """A small clear-water session of BRDF1 (19 configurations)."""
    return veil.simulate(veil.BRDF1, None, seed=1, **STEP)


def _refused(error, call, *said):
    with pytest.raises(error) as info:
        call()
    for words in said:
        assert words in str(info.value), (words, str(info.value))
    return info.value


# -- accuracy that is no string (was TypeError: unhashable type: 'list') -----------------
def test_accuracy_in_a_list_is_refused_by_simulate_and_the_fits(clear):
    said = "accuracy = ['fast']; expected one of fast, default, high"
    _refused(InputError, lambda: veil.simulate(veil.BRDF1, veil.BTDF2, accuracy=["fast"],
                                               **STEP), said)
    _refused(FitError, lambda: veil.fit_medium(clear, veil.BRDF1, accuracy=["fast"]), said)
    _refused(FitError, lambda: veil.fit_target(clear, veil.BTDF2, accuracy=["fast"]), said)
    _refused(FitError, lambda: veil.fit_joint({"low": clear}, reference=veil.BRDF1,
                                              accuracy=["fast"]), said)
    # veil.apparent reads the same check (was TypeError: unhashable type: 'list')
    _refused(InputError, lambda: veil.apparent(veil.BRDF1, veil.BTDF2, 45, 45,
                                               accuracy=["fast"]), said)


# -- options that are no dict (was ValueError: dictionary update sequence ...) ------------
@pytest.mark.parametrize("fit", [
    lambda t: veil.fit_reference(t, options="ggx"),
    lambda t: veil.fit_medium(t, veil.BRDF1, options="ggx"),
    lambda t: veil.fit_target(t, veil.BTDF2, options="ggx"),
])
def test_options_that_are_no_dict_are_refused(clear, fit):
    _refused(FitError, lambda: fit(clear), "options = 'ggx'; expected a dict")


@pytest.mark.parametrize("keyword", ["brdf_options", "medium_options"])
def test_joint_options_that_are_no_dict_are_refused(clear, keyword):
    _refused(FitError, lambda: veil.fit_joint({"low": clear}, reference=veil.BRDF1,
                                              **{keyword: "x"}), f"{keyword} = 'x'")


# -- parameter names: a number refused, one string one name ------------------------------
def test_free_as_a_number_is_refused(clear):
    # was TypeError: 'int' object is not iterable
    _refused(FitError, lambda: veil.fit_reference(clear, free=3), "free = 3; expected a list")
    _refused(FitError, lambda: veil.fit_reference(clear, free=[3]), "free lists 3")


def test_free_as_one_string_is_one_name(clear):
    # was "cannot free 'q', 'P'": the string's characters taken as names
    error = _refused(FitError, lambda: veil.fit_reference(clear, free="Pq"), "cannot free 'Pq'")
    assert "'P'" not in str(error)


@pytest.mark.parametrize("keyword", ["shared", "per_medium", "free"])
def test_joint_names_as_a_number_are_refused(clear, keyword):
    # was TypeError: 'int' object is not iterable
    _refused(FitError, lambda: veil.fit_joint({"low": clear}, reference=veil.BRDF1,
                                              **{keyword: 3}), f"{keyword} = 3")


# -- a start given as {name: value} -------------------------------------------------------
@pytest.mark.parametrize("start, said", [
    ("BRDF2", "start = 'BRDF2'; expected a fit result of torrance-sparrow or a dict"),
    ([1, 2, 3, 4], "start = [1, 2, 3, 4]; expected"),  # both were TypeError/ValueError
    (veil.BRDF2, "expected a fit result of torrance-sparrow or a dict"),
    ({**veil.BRDF1.as_dict(), "n": "x"}, "start n = 'x' is not a finite number"),
    ({**veil.BRDF1.as_dict(), "Q": 1.0}, "start names 'Q': torrance-sparrow has parameters"),
])
def test_a_start_that_is_no_dict_of_numbers_is_refused(clear, start, said):
    _refused(FitError, lambda: veil.fit_reference(clear, start=start), said)


# -- paths that are no path (was TypeError: expected str, bytes or os.PathLike) -----------
def test_paths_of_the_wrong_type_name_the_argument(clear, tmp_path):
    _refused(InputTypeError, lambda: veil.load_measurements(None),
             "path = None: expected a path")
    _refused(InputTypeError, lambda: veil.load_measurements(clear), "got DataFrame")
    _refused(InputTypeError, lambda: veil.save_measurements(clear, None), "path = None")
    _refused(InputTypeError, lambda: veil.FitResult.from_json({"model": "x"}), "got dict")
    _refused(InputTypeError, lambda: veil.run_pipeline(clear, clear, clear, outdir=None),
             "outdir = None: expected a path")
    assert not list(tmp_path.iterdir())


def test_maps_paths_of_the_wrong_type_name_the_argument(tmp_path):
    pytest.importorskip("zarr")
    _refused(InputTypeError, lambda: veil.open_maps(None), "store = None: expected a path")
    _refused(InputTypeError, lambda: veil.fit_maps(tmp_path, tmp_path / "m.csv", veil.BTDF2,
                                                   3), "output = 3: expected a path")
    _refused(InputTypeError, lambda: veil.fit_maps(None, tmp_path / "m.csv", veil.BTDF2,
                                                   tmp_path / "o.zarr"), "photo_dir = None")


# -- simulate's channels ------------------------------------------------------------------
@pytest.mark.parametrize("channels, said", [
    ({"r": veil.BRDF1}, "channels['r'] = TorranceSparrow("),  # was TypeError: cannot unpack
    ({"r": (veil.BRDF1,)}, "expected a pair (brdf, medium)"),  # was ValueError: not enough
    # these made tables that veil itself then refused to read
    ({"": (veil.BRDF1, None)}, "channels: '' is not a channel"),
    ({"nan": (veil.BRDF1, None)}, "channels: 'nan' is not a channel"),
    ({3: (veil.BRDF1, None)}, "channels: 3 is not a channel"),
    ({"r": (veil.BRDF1, None), "R": (veil.BRDF2, None)}, "'r', 'R' name one channel"),
    ({"r": (veil.BRDF1, None), 650: (veil.BRDF2, None)}, "mix colour channels and wavelengths"),
])
def test_simulated_channels_that_are_no_channels_are_refused(channels, said):
    _refused(InputError, lambda: veil.simulate(channels, None, **STEP), said)


def test_simulated_channels_read_back(tmp_path):
    table = veil.simulate({"R": (veil.BRDF1, None), "g": (veil.BRDF2, None)}, None, **STEP)
    veil.save_measurements(table, tmp_path / "t.csv")
    assert veil.load_measurements(tmp_path / "t.csv").shape == table.shape


# -- callbacks, numbers of numpy, radians -------------------------------------------------
def test_progress_that_cannot_be_called_is_refused(clear):
    # was TypeError: 'int' object is not callable, after the work had begun
    said = "progress = 3: expected a function to call, or None"
    _refused(InputError, lambda: veil.simulate(veil.BRDF1, None, progress=3, **STEP), said)
    _refused(InputError, lambda: veil.fit_reference(clear, progress=3), said)
    _refused(InputError, lambda: veil.fit_target(clear, veil.BTDF2, progress=3), said)
    _refused(InputError, lambda: veil.fit_joint({"low": clear}, reference=veil.BRDF1,
                                                progress=3), said)


def test_a_numpy_float32_noise_is_a_number():
    # was "noise = np.float32(0.01): expected a finite number >= 0 (relative)"
    a = veil.simulate(veil.BRDF1, None, noise=np.float32(0.25), glow=np.float64(0.0), **STEP)
    b = veil.simulate(veil.BRDF1, None, noise=float(np.float32(0.25)), glow=0.0, **STEP)
    pd.testing.assert_frame_equal(a, b, check_exact=True)


def test_psi_in_radians_warns():
    from veil.data.table_angles import LikelyRadiansWarning

    # was simulated silently at psi = 0.52, 1.05 and 1.57 degrees
    with pytest.warns(LikelyRadiansWarning, match="were they written in radians"):
        veil.simulate(veil.BRDF1, None, psi=(np.pi / 6, np.pi / 3, np.pi / 2), **STEP)


def test_psi_zero_is_refused_without_being_taken_for_radians():
    """psi = 0 is 0 in either unit: its error alone, no "written in radians?" before it."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"psi = 0 deg: expected a relative angle"):
            veil.simulate(veil.BRDF1, None, psi=(0.0,), **STEP)


def test_results_still_read_and_fit_as_before(clear, tmp_path):
    """The checks refuse nothing veil writes or the documented forms."""
    result = veil.fit_reference(clear, free=["eta"], options={}, start=veil.BRDF1.as_dict())
    path = tmp_path / "r.json"
    result.to_json(path)
    assert veil.FitResult.from_json(str(path)).params == json.loads(path.read_text())["params"]
