"""Colour channels through a medium (issue 30, second slice; docs/channels.md):
steps 1 and 2 fit every channel of a table at once, the medium's and the BRDF's parameters
declared per channel one per channel and the shared ones tied, each channel through the
given fit's model of that channel, its covariance propagated per channel; the pipeline over
channels; a one-channel table exactly as the table without the column."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import re

import matplotlib.colors
import matplotlib.image
import numpy as np
import pytest
from support.cli import run

import veil
from veil.data.measurements import save_measurements
from veil.data.simulate import simulate_channels
from veil.errors import FitError
from veil.fitting import FitResult, fit_medium, fit_reference, fit_target
from veil.viz.explore import CHANNEL_COLOURS

#: The paper's medium BTDF2 with T_d and T_t scaled per channel (water that dims red); the
#: reference BRDF2 and the target BRDF1 with their diffuse albedo per channel.
MEDIUM = {"r": 0.6, "g": 1.0, "b": 1.5}
REF_PD = {"r": 800.0, "g": 1000.0, "b": 1200.0}
TGT_PD = {"r": 100.0, "g": 200.0, "b": 400.0}
FAST = "fast"


def _medium(c: str):
    m = veil.BTDF2
    return m.replace(Td=m.Td * MEDIUM[c], Tt=m.Tt * MEDIUM[c])


def _sessions() -> dict:
    """{session: (table, black or None)} simulated at the fast quadrature, the medium's glow
    in the black cloth."""
    ref = {c: veil.BRDF2.replace(Pd=REF_PD[c]) for c in MEDIUM}
    tgt = {c: veil.BRDF1.replace(Pd=TGT_PD[c]) for c in MEDIUM}
    clear = simulate_channels({c: (ref[c], None) for c in MEDIUM}, noise=0.01, seed=1,
                              accuracy=FAST)
    ref_m, black_r = simulate_channels({c: (ref[c], _medium(c)) for c in MEDIUM},
                                       noise=0.01, seed=2, black=True, accuracy=FAST)
    tgt_m, black_t = simulate_channels({c: (tgt[c], _medium(c)) for c in MEDIUM},
                                       noise=0.01, seed=3, black=True, accuracy=FAST)
    tgt_clear = simulate_channels({c: (tgt[c], None) for c in MEDIUM}, noise=0.01, seed=4,
                                  accuracy=FAST)
    return {"clear": (clear, None), "ref_m": (ref_m, black_r), "tgt_m": (tgt_m, black_t),
            "tgt_clear": (tgt_clear, None)}


@pytest.fixture(scope="module")
def fits():
    s = _sessions()
    ref = fit_reference(s["clear"][0])
    med = fit_medium(s["ref_m"][0], ref, black=s["ref_m"][1], accuracy=FAST)
    tgt = fit_target(s["tgt_m"][0], med, black=s["tgt_m"][1], accuracy=FAST)
    return s, ref, med, tgt


def _z(result: FitResult, name: str, truth: float) -> float:
    return (result.params[name] - truth) / result.stderr_total[name]


def test_the_medium_per_channel_and_its_shared_parameters_once(fits):
    _, ref, med, _ = fits
    assert med.converged and med.channel_names == ("r", "g", "b")
    for c in MEDIUM:
        truth = _medium(c)
        for p in ("Td", "Tt"):
            assert abs(_z(med, f"{p}[{c}]", getattr(truth, p))) < 3, (c, p)
    assert [n for n in med.params if not n.endswith("]")] == ["g", "eta_u"]
    assert abs(_z(med, "g", veil.BTDF2.g)) < 3 and abs(_z(med, "eta_u", veil.BTDF2.eta)) < 3
    # the reference's covariance propagated per channel: the totals exceed the noise's
    assert all(med.stderr_total[n] > med.stderr[n] for n in med.free)
    assert med.stats["propagation"]["method"] in ("linear", "sigma-points")
    red = med.as_model(channel="r")
    assert red.Td == med.params["Td[r]"] and red.g == med.params["g"]
    assert med.given_model(channel="b") == ref.as_model(channel="b")


def test_the_target_per_channel_through_each_channels_medium(fits):
    _, _, med, tgt = fits
    assert tgt.converged and tgt.channel_names == ("r", "g", "b")
    for c, pd_ in TGT_PD.items():
        assert abs(_z(tgt, f"Pd[{c}]", pd_)) < 3, c
        assert abs(_z(tgt, f"Ps[{c}]", veil.BRDF1.Ps)) < 3, c
    assert abs(_z(tgt, "n", veil.BRDF1.n)) < 3 and abs(_z(tgt, "eta", veil.BRDF1.eta)) < 3
    assert tgt.as_model(channel="g").Pd == tgt.params["Pd[g]"]
    assert tgt.given_model(channel="r") == med.as_model(channel="r")
    text = tgt.report()
    assert "tied across them: n, eta" in text and "Pd[b]" in text


def test_results_of_several_channels_round_trip_with_their_given_fit(fits, tmp_path):
    _, _, med, tgt = fits
    for result in (med, tgt):
        result.to_json(tmp_path / "x.json")
        back = FitResult.from_json(tmp_path / "x.json")
        assert back.to_dict() == result.to_dict()
        assert json.loads((tmp_path / "x.json").read_text())["given"]["channels"]
        every = back.as_model()  # every channel at once; one model needs a channel named
        assert isinstance(every, veil.ChannelModel) and every["g"] == back.as_model(channel="g")
        with pytest.raises(FitError, match="fits channels r, g, b at once"):
            back.one_model()


def test_the_models_of_every_channel_evaluate_through_each_other(fits):
    """as_model() of a target and a medium fitted over r, g, b: the apparent reflectance of
    every channel at once, channel by channel bit for bit each one-channel pair's."""
    _, _, med, tgt = fits
    values = veil.apparent(tgt.as_model(), med.as_model(), 40, [30, 45], accuracy=FAST)
    each = [veil.apparent(tgt.as_model(channel=c), med.as_model(channel=c), 40, [30, 45],
                          accuracy=FAST) for c in "rgb"]
    assert values.shape == (2, 3) and values.tobytes() == np.stack(each, -1).tobytes()


def test_channels_of_the_given_fit_must_be_the_tables(fits):
    s, ref, med, _ = fits
    table, black = s["ref_m"]
    two = table[table["channel"] != "b"].copy()
    with pytest.raises(FitError, match=r"fit of channels r, g, b but .* has channels r, g"):
        fit_medium(two, ref, black=black[black["channel"] != "b"], accuracy=FAST)
    with pytest.raises(FitError, match="a fit of one channel"):
        one = dataclasses.replace(med, channels=None, params=dict(veil.BTDF2.as_dict()))
        fit_target(s["tgt_m"][0], one, black=s["tgt_m"][1], accuracy=FAST)


def test_a_one_channel_table_gives_the_result_of_the_table_without_the_column(fits):
    s, ref, _, _ = fits
    table, black = s["ref_m"]
    one, one_black = (t[t["channel"] == "g"].reset_index(drop=True) for t in (table, black))
    plain, plain_black = (t.drop(columns="channel") for t in (one, one_black))
    given = ref.as_model(channel="g")
    a = fit_medium(one, given, black=one_black, accuracy=FAST)
    b = fit_medium(plain, given, black=plain_black, accuracy=FAST)
    assert a.to_dict() == b.to_dict()


def _write_sessions(tmp_path) -> dict:
    paths = {}
    for key, (table, black) in _sessions().items():
        paths[key] = tmp_path / f"{key}.csv"
        save_measurements(table, paths[key])
        if black is not None:
            save_measurements(black, tmp_path / f"{key}_black.csv")
    return paths


def test_the_pipeline_over_three_channels_and_one_of_them(tmp_path):
    p = _write_sessions(tmp_path)
    base = ["fit", "pipeline", "--reference-clear", p["clear"], "--reference-medium",
            p["ref_m"], "--target-medium", p["tgt_m"], "--black",
            tmp_path / "ref_m_black.csv", "--accuracy", FAST]
    out = run(*base, "--target-clear", p["tgt_clear"], "-o", tmp_path / "rgb")
    assert out.exit_code == 0, out.output
    med = FitResult.from_json(tmp_path / "rgb" / "medium.json")
    tgt = FitResult.from_json(tmp_path / "rgb" / "target.json")
    assert med.channel_names == tgt.channel_names == ("r", "g", "b")
    for c in MEDIUM:
        assert abs(_z(med, f"Tt[{c}]", _medium(c).Tt)) < 3
        assert abs(_z(tgt, f"Pd[{c}]", TGT_PD[c])) < 3
    report = (tmp_path / "rgb" / "report.md").read_text()
    assert "## Channels" in report and "every channel in its colour" in report
    # the estimate against the direct fit, per channel: close (1 % noise), each listed
    rms = {c: float(re.search(rf"\| {c} \| ([0-9.e+-]+) \|", report).group(1)) for c in MEDIUM}
    assert all(0.0 < v < 5.0 for v in rms.values()), rms
    # four figures, each drawing the three channels in their colours
    figures = sorted(f.name for f in (tmp_path / "rgb").glob("*.png"))
    assert len(figures) == 4, figures
    for name in figures:
        pixels = matplotlib.image.imread(tmp_path / "rgb" / name)[..., :3]
        for c in MEDIUM:
            colour = np.array(matplotlib.colors.to_rgb(CHANNEL_COLOURS[c]))
            near = np.all(np.abs(pixels - colour) < 0.02, axis=-1).sum()
            assert near > 200, (name, c, near)
    out = run(*base, "--channel", "g", "--no-figures", "-o", tmp_path / "g")
    assert out.exit_code == 0, out.output
    green = FitResult.from_json(tmp_path / "g" / "medium.json")
    assert green.channels is None and abs(green.params["Tt"] - _medium("g").Tt) \
        < 3 * green.stderr_total["Tt"]


def _channel_problem(medium_by_channel: dict, medium_template):
    """The step-1 problem over channels r, g, b of a reference BRDF2 through the given media
    (fast rule; psi = 60 deg alone, one engine chunk), and its data by channel."""
    from veil.fitting.channel_steps import through_problem
    from veil.fitting.session_data import channels_of, prepare

    ref = {c: veil.BRDF2.replace(Pd=REF_PD[c]) for c in MEDIUM}
    table = simulate_channels({c: (ref[c], medium_by_channel[c]) for c in MEDIUM},
                              psi=(60.0,), noise=0.01, seed=5, accuracy=FAST)
    loaded, channels = channels_of(table, "reference")
    datas = {c: prepare(loaded, None, "reference", channel=c) for c in channels}
    problem = through_problem(datas, medium_template, veil.BRDF2, {}, (), "medium",
                              "the reference", "the table")[0]
    return problem, datas


@contextlib.contextmanager
def _counted_runs():
    """The engine programs run inside the block, in order."""
    from veil.engine import forward

    runs = []
    original = forward.Forward._run

    def counted(self, fn, vb, vm):
        runs.append(fn)
        return original(self, fn, vb, vm)

    forward.Forward._run = counted
    try:
        yield runs
    finally:
        forward.Forward._run = original


def _runs_and_values(problem, x, every=False):
    """(engine program runs, model values) of one evaluation of ``problem`` at ``x``
    (``every``: the programs run, not their number)."""
    with _counted_runs() as runs:
        values = problem.model_values(x, FAST)
    return (runs if every else len(runs)), values


def _waters() -> dict:
    """Forward-series waters whose tau and omega differ per channel (those of
    tests/test_maps_channels.py: the same programs)."""
    from veil.models import model_class

    series = model_class("forward-series")
    return {c: series(tau=t, omega=w, g=0.9, path_length=15.0, plate_width=5.0)
            for c, t, w in zip(MEDIUM, (0.45, 0.3, 0.15), (0.95, 0.97, 0.99))}


def _separately(problem, datas, x):
    """Each channel's values by an engine of its own (no sharing)."""
    from veil.fitting.problem import SessionModel

    out = []
    for b, data in zip(problem.blocks, datas.values()):
        own = SessionModel(b.brdf, b.medium, data.angles, FAST)
        out.append(own.values(*problem.split(b, x)))
    return np.concatenate(out)


def test_channels_jacobians_run_together_beside_a_clear_session():
    """A problem of the three waters' channels and a clear-water session (as a joint fit
    has): each Jacobian call runs the channels' Jacobian program, not each channel's own,
    also when a second call at the same point adds the other model's derivatives."""
    from veil.engine import channel_programs
    from veil.fitting.problem import Block, Problem

    waters = _waters()
    channels, _ = _channel_problem(waters, waters["g"])
    first = channels.blocks[0]
    clear = Block(first.session, first.data, first.ib, None, first.brdf, None)
    problem = Problem([clear, *channels.blocks], channels.params, channels.values,
                      channels.free, channels.weighted)
    x = problem.values.copy()
    for c, t in zip(MEDIUM, (0.45, 0.3, 0.15)):
        x[problem.index(f"tau[{c}]")] = t
    medium = [problem.index(f"tau[{c}]") for c in MEDIUM]
    brdf = list(first.ib)
    with _counted_runs() as runs:
        problem.value_and_jacobian(x, FAST, medium)
        _, jac = problem.value_and_jacobian(x, FAST, medium + brdf)
    chunks = len(first.model(FAST)._engine.parts)
    assert len(runs) == 2 * chunks
    assert all(channel_programs.is_channel_program(fn) for fn in runs)
    assert np.all(np.isfinite(jac[:, medium + brdf]))


def test_channels_differing_in_scales_run_the_engine_once():
    """The paper medium's per-channel T_d and T_t are scales: the three channels' blocks
    share one engine and its programs run once per evaluation, the values exactly those of
    three separate engines (docs/channels.md, "Cost")."""
    problem, datas = _channel_problem({c: _medium(c) for c in MEDIUM}, veil.BTDF2)
    chunks = len(problem.blocks[0].model(FAST)._engine.parts)
    assert len({id(b.models) for b in problem.blocks}) == 1
    x = problem.values.copy()
    x[problem.index("Td[b]")] *= 1.7  # the channels' scales differ
    runs, values = _runs_and_values(problem, x)
    assert runs == chunks
    np.testing.assert_array_equal(values, _separately(problem, datas, x))
    # a shared, non-scale parameter moved: the programs run again, once
    x[problem.index("g")] = 0.5
    runs, values = _runs_and_values(problem, x)
    assert runs == chunks
    np.testing.assert_array_equal(values, _separately(problem, datas, x))


def test_channels_differing_in_a_non_scale_parameter_run_one_program_together():
    """forward-series' optical depth is per channel and not a scale: the channels' program
    (veil.engine.channel_programs) runs once per evaluation for all three, on phase grids of
    one sampling law, and each channel's values are its own within the fast rule's error,
    not another channel's."""
    from veil.engine import channel_programs

    waters = _waters()
    problem, datas = _channel_problem(waters, waters["g"])
    chunks = len(problem.blocks[0].model(FAST)._engine.parts)
    x = problem.values.copy()
    for c, t in zip(MEDIUM, (0.45, 0.3, 0.15)):
        x[problem.index(f"tau[{c}]")] = t
    runs, values = _runs_and_values(problem, x, every=True)
    assert len(runs) == chunks
    assert all(channel_programs.is_channel_program(fn) for fn in runs)
    alone = _separately(problem, datas, x)
    assert np.max(np.abs(values / alone - 1)) < 2e-3
    sizes = [b.size for b in problem.blocks]
    per_channel = np.split(alone, np.cumsum(sizes)[:-1])
    assert min(np.max(np.abs(a / b - 1)) for a, b in zip(per_channel, per_channel[1:])) > 0.02
    # two channels at the same water (a fit's channels may start from one grid point): the
    # same three channels' program, not one compiled for two
    x[problem.index("tau[r]")] = x[problem.index("tau[g]")]
    x[problem.index("omega[r]")] = x[problem.index("omega[g]")]
    again, values = _runs_and_values(problem, x, every=True)
    assert again == runs
    assert np.max(np.abs(values / _separately(problem, datas, x) - 1)) < 2e-3
