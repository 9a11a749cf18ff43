"""The paper's acquisition protocol (docs/model.md sec. 1, 7): rotations, spacing, limits."""

from __future__ import annotations

import signal

import numpy as np
import pytest

from veil.data.protocol import protocol, rho_values


def test_psi30_rho_list_by_hand():
    # |theta| < 85 with theta = 15 +- rho  <=>  |rho| < 70
    expected = ([-65, -60, -55, -50, -45, -40, -35, -30, -25, -20, -15]
                + list(range(-10, 11))
                + [15, 20, 25, 30, 35, 40, 45, 50, 55, 60, 65])
    rho = rho_values(30)
    assert rho.tolist() == [float(r) for r in expected]
    assert len(rho) == 43


def test_counts_per_psi_and_total():
    table = protocol()
    counts = table.groupby("psi", sort=False).size()
    assert counts.index.tolist() == [30.0, 60.0, 90.0]
    # psi=60: |rho| < 55 -> coarse 15..50 (8 a side); psi=90: |rho| < 40 -> 15..35 (5 a side)
    assert counts.tolist() == [43, 21 + 16, 21 + 10]
    assert len(table) == 111


@pytest.mark.parametrize("psi", [30.0, 60.0, 90.0])
def test_spacing_and_limits(psi):
    table = protocol([psi])
    rho = table["rho"].to_numpy()
    steps = np.diff(rho)
    inside = np.abs(rho[1:] + rho[:-1]) / 2 < 10
    assert np.all(steps[inside] == 1.0)
    assert np.all(steps[~inside] == 5.0)
    ti, tr = psi / 2 + rho, psi / 2 - rho
    assert np.all(np.abs(ti) < 85) and np.all(np.abs(tr) < 85)
    # one more coarse step would break the limit on one side
    assert psi / 2 + rho.max() + 5 >= 85 and psi / 2 - (rho.min() - 5) >= 85
    assert 0.0 in rho.tolist()


def test_canonical_columns():
    table = protocol([60])
    assert table.columns.tolist() == ["psi", "rho", "theta_i", "phi_i", "theta_r", "phi_r"]
    row = table[table["rho"] == -40].iloc[0]  # theta_i = -10 (camera side), theta_r = 70
    assert (row.theta_i, row.phi_i, row.theta_r, row.phi_r) == (10.0, 0.0, 70.0, 0.0)
    row = table[table["rho"] == 5].iloc[0]  # theta_i = 35, theta_r = 25
    assert (row.theta_i, row.phi_i, row.theta_r, row.phi_r) == (35.0, 180.0, 25.0, 0.0)
    assert set(table["phi_i"]) <= {0.0, 180.0} and set(table["phi_r"]) <= {0.0, 180.0}
    assert table["theta_i"].between(0, 90, inclusive="left").all()


def test_custom_steps_by_hand():
    # psi = 30, limit 40: |rho| < 25; fine 0.5 up to 3, then 3 + 2j: 5, 7, ..., 23
    rho = rho_values(30, fine_step=0.5, coarse_step=2.0, window=3.0, limit=40.0)
    pos = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0] + [float(x) for x in range(5, 24, 2)]
    assert rho.tolist() == [-x for x in reversed(pos)] + [0.0] + pos


def test_window_clipped_by_limit():
    # psi = 160, limit 85: |rho| < 5, only fine rotations
    assert rho_values(160).tolist() == [-4.0, -3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0]


def test_huge_window_is_clamped_to_the_limit():
    # a window past the limit makes the same rotations as one at the limit, at once
    # (it used to make a rotation per fine step of the window: 1e300 never returned)
    def late(*_):
        raise TimeoutError("rho_values iterated over the window")

    old = signal.signal(signal.SIGALRM, late)
    signal.alarm(10)
    try:
        for psi in (30, 90):
            assert rho_values(psi, window=1e300).tolist() == rho_values(psi, window=90).tolist()
        pd_huge, pd_90 = protocol(window=1e300), protocol(window=90)
        assert pd_huge.equals(pd_90) and len(pd_huge) == 327
        # fine rotations the limit allows are still counted (and refused when too many)
        with pytest.raises(ValueError, match="configurations"):
            rho_values(30, fine_step=1e-9, window=1e300)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def test_window_past_the_limit_keeps_results():
    # coarse steps smaller than fine ones: windows at and past the limit agree
    for window in (68, 70, 71, 72, 73, 75, 1e6):
        assert rho_values(30, fine_step=3, coarse_step=0.5, window=window).tolist() == [
            -x for x in reversed(_by_hand(window))] + [0.0] + _by_hand(window)


def _by_hand(window):
    # psi = 30: |rho| < 70; fine 3, 6, ..., then 0.5 apart from the last fine rotation
    n_fine = int(window // 3)
    pos = [3.0 * k for k in range(1, n_fine + 1) if 3 * k < 70]
    last = 3.0 * n_fine
    return pos + [last + 0.5 * j for j in range(1, 200) if last + 0.5 * j < 70]


@pytest.mark.parametrize("kwargs, message", [
    ({"psi": [180]}, "psi = 180"),
    ({"psi": [0]}, "psi = 0"),
    ({"psi": [170]}, "no configuration"),
    ({"psi": [30, 30]}, "repeated"),
    ({"psi": []}, "empty"),
    ({"psi": ["a"]}, "'a' is not a number"),
    ({"fine_step": 0}, "fine_step"),
    ({"coarse_step": -5}, "coarse_step"),
    ({"window": float("nan")}, "window"),
    ({"limit": 95}, "limit = 95"),
])
def test_bad_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        protocol(**kwargs)
