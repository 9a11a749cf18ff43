"""``FitResult.as_model()`` of a fit over several channels (issue 30; docs/fitting.md,
"Channels"): a :class:`veil.ChannelModel` that ``veil.reflectance`` and ``veil.apparent``
evaluate in every channel at once, a trailing channel axis, each channel bit for bit its
one-channel model's values; a one-channel result's ``as_model()`` as before."""

from __future__ import annotations

import numpy as np
import pytest

import veil
from veil.data.simulate import simulate_channels
from veil.errors import FitError, InputError, InputTypeError
from veil.fitting import FitResult, fit_reference

ALBEDO = {"r": 400.0, "g": 1000.0, "b": 2500.0}
THETA_I = np.array([[10.0, 30.0, 45.0], [20.0, 40.0, 60.0]])
THETA_R = np.array([25.0, 35.0, 50.0])


@pytest.fixture(scope="module")
def rgb_table():
    return simulate_channels(
        {c: (veil.BRDF1.replace(Pd=p), None) for c, p in ALBEDO.items()}, noise=0.01, seed=7
    )


@pytest.fixture(scope="module")
def rgb_json(rgb_table, tmp_path_factory):
    """A fit over r, g, b written to JSON (as ``veil fit reference -o``)."""
    path = tmp_path_factory.mktemp("rgb") / "rgb.json"
    fit_reference(rgb_table).to_json(path)
    return path


def stacked(fn, result, *args, **kwargs):
    """``fn`` of each channel's one-channel model, stacked along a trailing axis."""
    return np.stack(
        [fn(result.as_model(channel=c), *args, **kwargs) for c in result.channel_names], -1
    )


def same_bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_as_model_without_a_channel_is_every_channel(rgb_json):
    result = FitResult.from_json(rgb_json)
    model = result.as_model()
    assert isinstance(model, veil.ChannelModel)
    assert model.channels == ("r", "g", "b") == result.channel_names
    assert model.KIND == "brdf" and model.NAME == result.model and len(model) == 3
    for c in model:
        assert model[c] == result.as_model(channel=c)
        assert model[c].Pd == result.params[f"Pd[{c}]"] and model[c].n == result.params["n"]
    assert model == FitResult.from_json(rgb_json).as_model()
    assert "ChannelModel(r=" in repr(model)
    with pytest.raises(InputError, match="no channel 'x'; the channels are r, g, b"):
        model["x"]


def test_reflectance_of_every_channel_is_the_stack_of_each_bit_for_bit(rgb_json):
    result = FitResult.from_json(rgb_json)
    model = result.as_model()
    values = veil.reflectance(model, THETA_I, THETA_R)
    assert values.shape == (2, 3, 3)
    assert same_bits(values, stacked(veil.reflectance, result, THETA_I, THETA_R))
    assert veil.reflectance(model, 45, 45, 0, 180).shape == (3,)
    # the albedos tell the channels apart where the diffuse part dominates
    assert np.all(np.diff(values[0, 0]) > 0)
    assert veil.reflectance(model, [], []).shape == (0, 3)


def test_apparent_of_every_channel_is_the_stack_of_each_bit_for_bit(rgb_json):
    result = FitResult.from_json(rgb_json)
    model = result.as_model()
    # out of the plane of incidence (phi_r 20 deg): the value and error-estimate programs of
    # tests/test_cli_eval.py's azimuths, none of this test's own
    args = (veil.BTDF1, THETA_I, THETA_R, 180.0, 20.0)
    values = veil.apparent(model, *args, accuracy="fast")
    assert values.shape == (2, 3, 3)
    assert same_bits(values, stacked(veil.apparent, result, *args, accuracy="fast"))
    value, error = veil.apparent(model, *args, accuracy="fast", return_error=True)
    each = [
        veil.apparent(result.as_model(channel=c), *args, accuracy="fast", return_error=True)
        for c in result.channel_names
    ]
    assert same_bits(value, np.stack([v for v, _ in each], -1))
    assert same_bits(error, np.stack([e for _, e in each], -1))
    # a clear medium: the reflectance
    assert same_bits(
        veil.apparent(model, None, THETA_I, THETA_R), veil.reflectance(model, THETA_I, THETA_R)
    )


def test_a_medium_of_every_channel_beside_a_brdf_of_every_channel_or_one(rgb_json):
    """A medium per channel (its scales and, in b, its shape differ): each channel through
    its own medium, bit for bit; a BRDF of one channel is every channel's."""
    result = FitResult.from_json(rgb_json)
    media = veil.ChannelModel(
        {
            "r": veil.BTDF1.replace(Td=veil.BTDF1.Td * 0.5),
            "g": veil.BTDF1,
            "b": veil.BTDF1.replace(g=0.8),
        }
    )
    brdfs = result.as_model()
    values = veil.apparent(brdfs, media, 30, [20, 40], accuracy="fast")
    each = [veil.apparent(brdfs[c], media[c], 30, [20, 40], accuracy="fast") for c in "rgb"]
    assert values.shape == (2, 3) and same_bits(values, np.stack(each, -1))
    grey = veil.apparent(veil.BRDF1, media, 30, [20, 40], accuracy="fast")
    each = [veil.apparent(veil.BRDF1, media[c], 30, [20, 40], accuracy="fast") for c in "rgb"]
    assert same_bits(grey, np.stack(each, -1))


def test_channel_models_that_do_not_go_together_are_refused(rgb_json):
    model = FitResult.from_json(rgb_json).as_model()
    two = veil.ChannelModel({"r": veil.BTDF1, "g": veil.BTDF1})
    with pytest.raises(InputError, match="channels r, g, b and r, g"):
        veil.apparent(model, two, 30, 30)
    with pytest.raises(InputTypeError, match="expected a BRDF"):
        veil.reflectance(two, 30, 30)
    with pytest.raises(InputError, match="one family with the same options"):
        veil.ChannelModel({"r": veil.BRDF1, "g": veil.BTDF1})
    with pytest.raises(InputTypeError, match="at least one channel"):
        veil.ChannelModel({})


def test_a_one_channel_result_as_before(rgb_table, rgb_json, tmp_path):
    fit_reference(rgb_table, channel="r").to_json(tmp_path / "r.json")
    one = FitResult.from_json(tmp_path / "r.json")
    model = one.as_model()
    assert type(model) is type(veil.BRDF1)
    assert model == type(veil.BRDF1).from_params(one.params, one.options) == one.one_model()
    assert same_bits(
        veil.reflectance(model, THETA_I, THETA_R),
        veil.reflectance(one.one_model(), THETA_I, THETA_R),
    )
    with pytest.raises(FitError, match="is a fit of one channel"):
        one.as_model(channel="r")
    # what needs the model of one channel still names the channels of a fit of several
    with pytest.raises(FitError, match="fits channels r, g, b at once"):
        FitResult.from_json(rgb_json).one_model()


def test_a_step_of_one_channel_given_a_fit_of_several_names_its_channels(rgb_json):
    """The model a step of one channel holds fixed is one channel's: a fit of several
    given without a channel is an error naming them (not a ChannelModel taken as a BRDF)."""
    table = veil.simulate(veil.BRDF1, None, noise=0.01, seed=1)
    with pytest.raises(FitError, match="fits channels r, g, b at once"):
        veil.fit_medium(table, FitResult.from_json(rgb_json))
