"""A step of one channel through a fit of several (docs/channels.md): the given fit's
covariance enters ``stderr_total`` through that channel's part of it
(``FitResult.of_channel``). Step 2 of one channel through a medium fitted over three
stopped with "henyey-greenstein has no parameter 'Td[r]'"; step 1 propagated nothing."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import veil
from veil.errors import FitError
from veil.fitting import fit_medium, fit_reference, fit_target

MEDIUM = veil.BTDF2
WATERS = {"r": MEDIUM.replace(Td=MEDIUM.Td * 0.8), "g": MEDIUM, "b": MEDIUM.replace(Td=MEDIUM.Td * 1.1)}


def _table(brdf, seed, medium=True):
    parts = []
    for c, m in WATERS.items():
        t = veil.simulate(brdf, m if medium else None, noise=0.01, seed=seed, glow=0.0)
        parts.append(t.assign(channel=c))
    return pd.concat(parts, ignore_index=True)


@pytest.fixture(scope="module")
def medium():
    return fit_medium(_table(veil.BRDF2, 1), veil.BRDF2, accuracy="fast")


def test_a_channels_part_is_its_block_of_the_covariance(medium):
    names, cov = medium.covariance()
    one = medium.of_channel("g")
    assert one.channels is None and set(one.params) == set(type(MEDIUM).param_names())
    own, sub = one.covariance()
    index = {n: names.index(medium.channels["g"][n]) for n in own}
    want = cov[np.ix_([index[n] for n in own], [index[n] for n in own])]
    np.testing.assert_allclose(sub, want, rtol=1e-12)
    assert one.params["Td"] == medium.params["Td[g]"] and one.params["eta"] == medium.params["eta_u"]
    with pytest.raises(FitError, match="no channel .x."):
        medium.of_channel("x")


def test_the_target_of_one_channel_propagates_that_channels_medium(medium):
    res = fit_target(_table(veil.BRDF1, 2), medium, channel="g", accuracy="fast")
    assert res.converged and res.stats["propagation"]["method"] in ("linear", "sigma-points")
    assert set(res.stats["propagation"]["relative_uncertainty"]) == {"Td", "Tt", "g", "eta"}
    assert all(res.stderr_total[n] >= res.stderr[n] for n in res.free)
    assert any(res.stderr_total[n] > 1.01 * res.stderr[n] for n in res.free)


def test_the_medium_of_one_channel_propagates_that_channels_reference():
    reference = fit_reference(_table(veil.BRDF2, 3, medium=False))
    assert reference.channels is not None
    res = fit_medium(_table(veil.BRDF2, 4), reference, channel="g", accuracy="fast")
    assert res.converged and "propagation" in res.stats
    assert all(res.stderr_total[n] >= res.stderr[n] for n in res.free)
