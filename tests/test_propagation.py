"""How a given fit's covariance enters the next step's (veil.fitting.propagation).

The sigma points are checked against their definition (their second moment in the relative
coordinates is the covariance there; they never leave the bounds), the refits against the
first order where that holds (a well-determined medium: the two must agree, and a wrong
spread of the points or a wrong weight would miss by a factor), and "auto" against its rule.
The evidence that sigma points cover where the first order does not is the path-traced
m01 session (docs/validity.md, benchmarks/bench_validity.py --propagation).
"""

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import veil
from support.chain import small_chain
from veil.analysis.uncertainty import propagate
from veil.fitting import FitError, fit_target
from veil.fitting.propagation import (
    RELATIVE_LIMIT,
    Axis,
    check_method,
    choose,
    how_of,
    relative_uncertainty,
    sigma_points,
)
from veil.fitting.result import FitResult
from veil.models import model_class

FS = model_class("forward-series", "medium")
HG = model_class("henyey-greenstein", "medium")


def test_axes_follow_the_declared_error_scale():
    tau, omega = FS.param("tau"), FS.param("omega")
    g = HG.param("g")  # open at both ends (the forward series' g is closed at 0)
    assert Axis.of(tau, 0.1).kind == "log"            # stderr / value
    assert Axis.of(g, 0.95).kind == "upper"           # stderr / (1 - g)
    assert Axis.of(FS.param("g"), 0.95).kind == "upper"
    assert Axis.of(g, -0.9).kind == "lower"
    assert Axis.of(omega, 1.0).kind == "log"
    assert Axis.of(HG.param("Td"), 1e-3).kind == "log"  # log_scale
    for axis, x in ((Axis.of(tau, 0.1), 0.37), (Axis.of(g, 0.95), 0.999),
                    (Axis.of(g, -0.9), -0.2)):
        assert axis.to_x(axis.to_u(x)) == pytest.approx(x, rel=1e-12)
        h = 1e-6
        fd = (axis.to_u(x + h) - axis.to_u(x - h)) / (2 * h)
        assert axis.du_dx(x) == pytest.approx(fd, rel=1e-5)
    # back inside the bounds: omega's closed bound 1, g's open one kept a margin away
    assert not Axis.of(omega, 1.0).inside(Axis.of(omega, 1.0).to_x(0.3))
    assert Axis.of(omega, 1.0).inside(1.0)
    assert Axis.of(g, -0.9).inside(Axis.of(g, -0.9).to_x(-5.0))
    assert not Axis.of(g, -0.9).inside(-1.0)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-0.9, 0.9), min_size=3, max_size=3),
       st.lists(st.floats(0.01, 0.3), min_size=3, max_size=3))
def test_sigma_points_carry_the_covariance_in_relative_coordinates(corr, rel):
    """Points far inside the bounds: their second moment about u0 is the covariance in u,
    D Cov D^T with D = du/dx, and they come in pairs symmetric about u0."""
    specs = [FS.param("tau"), FS.param("g"), HG.param("Tt")]
    values = np.array([0.5, 0.9, 0.1])
    c = np.eye(3)
    c[0, 1] = c[1, 0] = corr[0] * 0.5
    c[0, 2] = c[2, 0] = corr[1] * 0.5
    c[1, 2] = c[2, 1] = corr[2] * 0.5
    scale = np.array([rel[0] * 0.5, rel[1] * 0.1, rel[2] * 0.1]) / 3
    cov = c * np.outer(scale, scale)
    pts, reach = sigma_points(specs, values, cov)
    assert pts.shape == (6, 3) and np.all(reach == 1.0)
    axes = [Axis.of(p, v) for p, v in zip(specs, values)]
    u = np.array([[a.to_u(x) for a, x in zip(axes, row)] for row in pts])
    u0 = np.array([a.to_u(v) for a, v in zip(axes, values)])
    d = np.array([a.du_dx(v) for a, v in zip(axes, values)])
    moment = (u - u0).T @ (u - u0) / len(u)
    assert np.allclose(moment, cov * np.outer(d, d), rtol=1e-9, atol=1e-15)
    assert np.allclose(u[0::2] - u0, -(u[1::2] - u0), rtol=1e-9, atol=1e-15)


def test_sigma_points_stay_inside_the_bounds():
    """tau 0.1 +- 0.2 (m01's step 1): the points spread over decades of tau, never below 0;
    omega at its bound 1 stays at most 1; g never reaches 1."""
    specs = [FS.param("tau"), FS.param("omega"), FS.param("g")]
    values = np.array([0.1, 1.0, 0.98])
    cov = np.diag([0.2, 0.01, 0.01]) ** 2
    cov[0, 2] = cov[2, 0] = 0.5 * 0.2 * 0.01
    pts, reach = sigma_points(specs, values, cov)
    assert np.all(pts[:, 0] > 0) and np.all(pts[:, 1] <= 1.0) and np.all(pts[:, 2] < 1.0)
    # the directions that raise omega above 1 are pulled back to it, their twins whole
    short = np.flatnonzero(reach < 1.0)
    assert len(short) >= 1 and np.allclose(pts[short, 1], 1.0)
    assert all(reach[k + 1 if k % 2 == 0 else k - 1] == 1.0 for k in short)
    assert pts[:, 0].max() / pts[:, 0].min() > 100
    assert all(FS.param(n).contains(float(v)) for row in pts
               for n, v in zip(("tau", "omega", "g"), row))


def test_auto_chooses_by_the_relative_uncertainty():
    specs = [FS.param("tau"), FS.param("g")]
    small = relative_uncertainty(specs, [0.5, 0.9], np.diag([0.02, 0.01]) ** 2)
    assert small["tau"] == pytest.approx(0.04) and small["g"] == pytest.approx(0.1)
    assert choose("auto", small) == "linear"
    large = relative_uncertainty(specs, [0.1, 0.9], np.diag([0.18, 0.01]) ** 2)
    assert large["tau"] == pytest.approx(1.8) and choose("auto", large) == "sigma-points"
    at_limit = {"tau": RELATIVE_LIMIT}
    assert choose("auto", at_limit) == "linear"
    # beyond RELATIVE_MAX (or not finite) the parameter is not determined: first order, noted
    assert choose("auto", {"tau": 3.5}) == "linear" == choose("auto", {"tau": None})
    assert choose("auto", {"tau": 2.9}) == "sigma-points"
    assert "not determined" in how_of("auto", {"tau": None, "g": 0.1})["fallback"]
    assert "fallback" not in how_of("auto", large) and "fallback" not in how_of("linear", {"tau": None})
    assert choose("linear", large) == "linear"
    assert check_method(None) == "auto"
    with pytest.raises(FitError, match="propagation = 'cubic'; expected one of auto"):
        check_method("cubic")


@pytest.fixture(scope="module")
def chain():
    """The paper's chain on small sessions at 0.3 % noise: the medium well determined."""
    return small_chain()


def test_sigma_points_agree_with_the_first_order_where_it_holds(chain):
    r1, target = chain["r1"], chain["target"]
    auto = fit_target(target, r1, accuracy="fast")
    assert auto.stats["propagation"]["method"] == "linear"
    assert max(auto.stats["propagation"]["relative_uncertainty"].values()) <= RELATIVE_LIMIT
    forced = fit_target(target, r1, accuracy="fast", propagation="sigma-points")
    assert forced.params == auto.params and forced.stderr == auto.stderr
    how = forced.stats["propagation"]
    assert how["method"] == "sigma-points" and how["points"] == 2 * len(r1.free)
    assert how["converged"] == how["refits"] == how["points"]
    assert f"through {how['refits']} refits at {how['points']} sigma points" in forced.message
    for name in auto.free:
        own, lin, sig = auto.stderr[name], auto.stderr_total[name], forced.stderr_total[name]
        # the medium's share of the variance, each way: within 15 % of each other (points
        # at +-1 sd instead of +-sqrt(n) sd, or weights 1/n, would miss by 3x or 2x)
        assert (sig ** 2 - own ** 2) == pytest.approx(lin ** 2 - own ** 2, rel=0.15), name
    # the analysis budget follows the fit's method and reproduces its total
    p = propagate(forced, r1, target)
    assert "through sigma-point refits" in p.message
    for name in forced.free:
        assert p.stderr_total[name] == pytest.approx(forced.stderr_total[name], rel=1e-6)
    # report.md says which way each step's total came
    from veil.viz.pipeline_report import _stats_lines
    assert (f"through {how['refits']} refits at {how['points']} sigma points"
            in "\n".join(_stats_lines(forced)))
    assert "\"stderr incl. given model\": to first order" in "\n".join(_stats_lines(auto))
    # the record survives JSON
    back = FitResult.from_dict(json.loads(json.dumps(forced.to_dict())))
    assert back.stats["propagation"]["method"] == "sigma-points"
    assert back.stderr_total == forced.stderr_total


def _uncertain_tt(r1):
    """The medium result ``r1`` with Tt uncertain by half its value."""
    names, cov = r1.covariance(total=False)
    k = names.index("Tt")
    factor = 0.5 * r1.params["Tt"] / math.sqrt(cov[k, k])
    return dataclasses.replace(
        r1, stderr={n: (s * factor if n == "Tt" else s) for n, s in r1.stderr.items()},
        stderr_total=None, correlation_total=None)


def test_an_uncertain_medium_goes_through_sigma_points(chain):
    """A medium result whose Tt is uncertain by half its value: "auto" refits at the sigma
    points, and the target's totals differ from the first order's."""
    target, wide = chain["target"], _uncertain_tt(chain["r1"])
    auto = fit_target(target, wide, accuracy="fast")
    lin = fit_target(target, wide, accuracy="fast", propagation="linear")
    assert auto.stats["propagation"]["method"] == "sigma-points"
    assert auto.stats["propagation"]["relative_uncertainty"]["Tt"] == pytest.approx(0.5)
    assert lin.stats["propagation"]["method"] == "linear"
    assert auto.params == lin.params
    ratios = [auto.stderr_total[n] / lin.stderr_total[n] for n in auto.free]
    assert all(np.isfinite(ratios)) and max(abs(r - 1) for r in ratios) > 0.02


def test_a_fit_that_did_not_converge_keeps_the_first_order_and_says_so(chain):
    """The same uncertain medium with the target's fit cut short (max_nfev 1): "auto" makes
    no refits about a point that is not an optimum; the totals are the first order's and the
    record and the message say why. Asked for by name, sigma points are still made."""
    target, wide = chain["target"], _uncertain_tt(chain["r1"])
    short = dict(accuracy="fast", max_nfev=1)
    auto = fit_target(target, wide, **short)
    assert not auto.converged
    how = auto.stats["propagation"]
    assert how["method"] == "linear" and "optimum the fit has not reached" in how["fallback"]
    assert how["fallback"] in auto.message and "refits" not in how
    assert auto.stderr_total == fit_target(target, wide, propagation="linear", **short).stderr_total
    forced = fit_target(target, wide, propagation="sigma-points", **short)
    assert forced.stats["propagation"]["method"] == "sigma-points"
    assert "has not reached" not in forced.stats["propagation"].get("fallback", "")
    assert how_of("auto", {"tau": 1.8}, converged=False)["method"] == "linear"
    assert how_of("auto", {"tau": 0.01}, converged=False) == how_of("auto", {"tau": 0.01})


def test_command_line_propagation(chain, tmp_path):
    """`veil fit target --propagation`: the choices are the module's, a bad one exits 2
    naming the option, and sigma points are recorded in the JSON and the report."""
    from click.testing import CliRunner

    from veil.cli import main
    from veil.cli.fit_cmd import medium_command, pipeline_command, target_command
    from veil.fitting.propagation import METHODS

    for command in (medium_command, target_command, pipeline_command):
        option = next(p for p in command.params if p.name == "propagation")
        assert tuple(option.type.choices) == METHODS and option.default == "auto"
    table, medium = tmp_path / "target.csv", tmp_path / "medium.json"
    chain["target"].to_csv(table, index=False)
    chain["r1"].to_json(medium)
    base = ["fit", "target", str(table), "--medium", str(medium), "--accuracy", "fast"]
    bad = CliRunner().invoke(main, base + ["-o", str(tmp_path / "x.json"),
                                           "--propagation", "cubic"])
    assert bad.exit_code == 2 and "--propagation" in bad.output
    assert not (tmp_path / "x.json").exists()
    out = tmp_path / "t.json"
    run = CliRunner().invoke(main, base + ["-o", str(out), "--propagation", "sigma-points"])
    assert run.exit_code == 0, run.output
    k = 2 * len(chain["r1"].free)
    assert f"sigma points: {k} refits at {k} points, {k} converged" in run.output
    saved = json.loads(out.read_text())
    assert saved["stats"]["propagation"]["method"] == "sigma-points"


def test_off_moves_nothing_but_the_totals(chain):
    """propagation="off" (how `--models auto` fits the candidates it ranks): the estimate,
    chi-square, residuals, own standard errors and model-discrepancy term bit for bit those
    of "auto", no total, no record; the BIC of the ranking therefore cannot change."""
    on = fit_target(chain["target"], chain["r1"], accuracy="fast")
    off = fit_target(chain["target"], chain["r1"], accuracy="fast", propagation="off")
    assert on.stderr_total is not None and "propagation" in on.stats
    assert off.stderr_total is None and "propagation" not in off.stats
    assert off.params == on.params and off.stderr == on.stderr
    assert off.residuals == on.residuals and off.chi2_reduced == on.chi2_reduced
    assert off.model_error == on.model_error


def test_auto_propagates_into_the_chosen_candidate_only():
    """veil.fitting.auto.rank_step: every candidate fitted once by the screening fit, the
    chosen one (and only it) fitted again by ``propagated``, from its estimate, whose
    result replaces it."""
    from veil.fitting.auto import rank_step
    from veil.fitting.selection import candidates

    cands = [c for c in candidates("brdf") if c.family in ("torrance-sparrow", "rough-plastic")]
    assert len(cands) >= 2
    data = SimpleNamespace(y=np.ones(6), sigma=None, angles=np.zeros((6, 4)))
    rss = {c.label: 1.0 + i for i, c in enumerate(cands)}      # the first one is the best

    def result(label, step):
        return FitResult(model=label.split("[")[0], params={}, stderr={}, correlation={},
                         residuals=(np.sqrt(rss[label] / 6),) * 6, chi2_reduced=1.0,
                         rms_relative=0.0, n_points=6, converged=True, message="",
                         step=step, weighted=False)

    calls = []

    firsts = {}

    def screened(c):
        calls.append(("screen", c.label))
        firsts[c.label] = result(c.label, "screened")
        return firsts[c.label]

    def propagated(c, start):
        assert start is firsts[c.label]  # the refit starts from the candidate's estimate
        calls.append(("again", c.label))
        return result(c.label, "propagated")

    ranking, results = rank_step("target", cands, data, screened, None, None, "target",
                                  propagated)
    assert ranking.chosen == cands[0].label
    assert sorted(calls) == sorted([("screen", c.label) for c in cands]
                                   + [("again", cands[0].label)])
    assert results[cands[0].label].step == "propagated"
    assert all(results[c.label].step == "screened" for c in cands[1:])


class _LinearInU:
    """A stand-in for a fit whose estimate moves linearly in the given parameters' relative
    coordinates u (sigma_part's refits replaced by x_free = x0 + M (u - u0)): the sigma-point
    moment must then be M Cov_u M^T exactly, whatever the covariance's rank and whether
    points had to be pulled back inside the bounds."""

    def __init__(self, names, values, free, axes, u0, m):
        self.names, self.values, self.free = list(names), np.array(values, float), np.array(free)
        self.axes, self.u0, self.m = axes, u0, m

    @property
    def free_index(self):
        return np.flatnonzero(self.free)

    def with_fixed(self, fixed):
        out = _LinearInU(self.names, self.values, self.free, self.axes, self.u0, self.m)
        for n, v in fixed.items():
            out.values[self.names.index(n)] = v
            out.free[self.names.index(n)] = False
        return out

    def solve(self, problem, x0, **_):
        x = np.array(x0, dtype=float)
        given = [k for k in range(len(self.names)) if not self.free[k]]
        u = np.array([a.to_u(x[k]) for a, k in zip(self.axes, given)])
        x[self.free_index] = 1.0 + self.m @ (u - self.u0)
        return SimpleNamespace(x=x, status=1, cost=0.0)


@pytest.mark.parametrize("case", ["inside", "singular", "at the bound"])
def test_sigma_part_reproduces_a_response_linear_in_u(case, monkeypatch):
    import veil.fitting.propagation as prop

    specs = [FS.param("tau"), FS.param("omega"), FS.param("g")]
    values = np.array([0.5, 1.0 if case == "at the bound" else 0.9, 0.9])
    se = np.array([0.05, 0.02, 0.01])
    corr = np.array([[1.0, 0.6, -0.3], [0.6, 1.0, 0.2], [-0.3, 0.2, 1.0]])
    if case == "singular":
        corr = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    cov = corr * np.outer(se, se)
    axes = [Axis.of(p, v) for p, v in zip(specs, values)]
    u0 = np.array([a.to_u(v) for a, v in zip(axes, values)])
    d = np.array([a.du_dx(v) for a, v in zip(axes, values)])
    m = np.array([[1.0, -2.0, 0.5], [0.3, 0.0, 4.0]])
    names = ["rho", "ks", "tau", "omega", "g"]
    fake = _LinearInU(names, [1.0, 1.0, *values], [True, True, False, False, False], axes,
                      u0, m)
    monkeypatch.setattr(prop, "solve", fake.solve)
    out = prop.sigma_part(fake, fake.values, [2, 3, 4], specs, cov)
    want = m @ (cov * np.outer(d, d)) @ m.T
    np.testing.assert_allclose(out.covariance, want, rtol=1e-9, atol=1e-15)
    if case == "at the bound":      # omega cannot rise above 1: mirrored, not refitted
        assert out.refits < len(out.points) and np.all(out.points[:, 1] <= 1.0)
    if case == "singular":          # one direction carries no spread: four points, not six
        assert len(out.points) == 4


def test_joint_fit_carries_the_media_through_sigma_points(chain):
    """A joint fit estimates the medium with the target: forced sigma points agree with the
    first order where the medium is well determined (the conditional covariance plus the
    refits' spread), change only the objects' block of the totals, and are recorded; the
    command line offers the option."""
    from veil.cli.joint_cmd import joint_command
    from veil.fitting.propagation import METHODS

    option = next(p for p in joint_command.params if p.name == "propagation")
    assert tuple(option.type.choices) == METHODS
    sessions = [(chain["ref_medium"], "m", "reference"), (chain["target"], "m", "target")]
    lin = veil.fit_joint(sessions, reference=chain["r0"], accuracy="fast",
                         propagation="linear")
    sig = veil.fit_joint(sessions, reference=chain["r0"], accuracy="fast",
                         propagation="sigma-points")
    assert lin.stats["propagation"]["method"] == "linear"
    how = sig.stats["propagation"]
    assert how["method"] == "sigma-points" and how["points"] == 8 and how["converged"] == 8
    assert sig.params == lin.params and sig.stderr == lin.stderr
    media = [n for n in lin.free if n in set(lin.layout["media"]["m"].values())]
    objects = [n for n in lin.free if n not in media]
    assert media and objects
    for n in media:
        assert sig.stderr_total[n] == lin.stderr_total[n]
    for n in objects:
        assert sig.stderr_total[n] == pytest.approx(lin.stderr_total[n], rel=0.1), n
    # applied (not only computed), to the objects alone
    assert any(sig.stderr_total[n] != lin.stderr_total[n] for n in objects)
    assert "refits at 8 sigma points" in sig.message
    assert sig.stats["propagation_reference"]["method"] == "linear"   # the reference's
    # a reference given as a model has no covariance: the total is the media's alone
    alone = veil.fit_joint(sessions, reference=veil.BRDF2, accuracy="fast",
                           propagation="sigma-points")
    assert lin.stderr_total is not None and alone.stderr_total is not None
    assert "propagation_reference" not in alone.stats
    report = alone.report()
    assert "; total +/-" in report and "sigma points: 8 refits at 8 points" in report


def test_an_undetermined_medium_keeps_the_first_order_and_says_so(chain):
    """Td uncertain by 400 times its value (the paper's medium at optical depth 0.1): "auto"
    keeps the first order with a note; forced sigma points far out (Td ~ 1e300) do not
    crash the fit: the refits fail, the first order is used, and the message says so."""
    r1, target = chain["r1"], chain["target"]
    se = dict(r1.stderr, Td=400.0 * r1.params["Td"])
    wide = dataclasses.replace(r1, stderr=se, stderr_total=None, correlation_total=None)
    auto = fit_target(target, wide, accuracy="fast")
    how = auto.stats["propagation"]
    assert how["method"] == "linear" and "Td uncertain by 400 of its scale" in how["fallback"]
    assert how["fallback"] in auto.message
    forced = fit_target(target, wide, accuracy="fast", propagation="sigma-points")
    assert forced.params == auto.params
    assert all(np.isfinite(v) for v in forced.stderr_total.values() if v is not None)
    note = forced.stats["propagation"]["fallback"]      # the refits at Td ~ 1e300 overflow
    assert forced.stats["propagation"]["method"] == "linear"
    assert note.startswith("sigma points failed") and "overflows" in note
    assert note in forced.message
    assert forced.stderr_total == lin_of(target, wide)


def lin_of(target, medium):
    return fit_target(target, medium, accuracy="fast", propagation="linear").stderr_total
