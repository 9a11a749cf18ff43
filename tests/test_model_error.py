"""The model-discrepancy term (veil.fitting.model_error; docs/validity.md, docs/fitting.md).

The statistics on synthetic residuals (no fit); fits whose model is deliberately wrong - a
GGX rough plastic simulated and veil's Beckmann rough plastic fitted (clear water), the
paper's medium simulated with one Fresnel variant and steps 1-2 fitted with the other - where
the term must make the reported uncertainty cover the truth and the noise alone does not;
well-specified fits, unchanged bit for bit; the result file; bad input. Through a medium one
relative angle (31 configurations) at the "fast" rule, as tests/test_fitting.py.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

import veil
from veil.analysis.uncertainty import curve_stderr, propagate
from veil.cli import main
from veil.fitting import FitError, FitResult, fit_direct, model_values
from veil.fitting import model_error as me
from veil.fitting import shared_error as se
from veil.models import model_class

ANGLES = ("theta_i", "phi_i", "theta_r", "phi_r")


# -- the statistics ---------------------------------------------------------------------------

def _angles(n):
    rho = np.linspace(-60.0, 60.0, n)
    return (np.abs(rho), np.where(rho < 0, 180.0, 0.0), np.abs(rho) * 0 + 30.0,
            np.zeros(n))


def test_no_term_when_the_residuals_are_noise():
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(200):
        r = rng.standard_normal(111)
        s, ell = me.estimate(r, np.full(111, 100.0), 107, np.zeros((111, 111)), (0.0,))
        hits += s > 0
        assert ell == 0.0
    # the test's level: about 2.3 % of well-specified fits (one-sided, Z = 2)
    assert hits <= 12


def test_relative_error_is_recovered():
    rng = np.random.default_rng(1)
    a = rng.uniform(20, 400, 300)            # model / sigma
    r = rng.standard_normal(300) + 0.01 * a * rng.standard_normal(300)
    s, ell = me.estimate(r, a, 296, np.zeros((300, 300)), (0.0,))
    assert ell == 0.0 and 0.008 < s < 0.012


def test_correlated_error_is_recognised():
    rng = np.random.default_rng(2)
    ang = _angles(120)
    dist = me.distances(ang)
    corr = me.correlation(dist, 20.0)
    d = np.linalg.cholesky(corr + 1e-12 * np.eye(120)) @ rng.standard_normal(120)
    a = np.full(120, 300.0)
    r = rng.standard_normal(120) + 0.01 * a * d
    s, ell = me.estimate(r, a, 116, dist)
    assert ell > 0.0 and 0.005 < s < 0.02         # not mistaken for independent errors
    white, _ = me.estimate(r, a, 116, dist, (0.0,))
    assert white > 0


def test_restricted_likelihood_counts_the_error_the_fit_absorbs():
    """A smooth error (ell = 80 deg over 120 deg of configurations) that a fit with six
    smooth columns (powers of rho) partly absorbs: the residuals alone show less of it, so
    their likelihood under-estimates s; the restricted one (the fit's Jacobian given)
    recovers it. Residuals here are those of a least-squares fit, r = (I - H) e."""
    rng = np.random.default_rng(3)
    n, truth = 120, 0.01
    dist = me.distances(_angles(n))
    chol = np.linalg.cholesky(me.correlation(dist, 80.0) + 1e-12 * np.eye(n))
    rho = np.linspace(-1.0, 1.0, n)
    jw = np.stack([rho ** k for k in range(6)], axis=1) * 50.0
    hat = jw @ np.linalg.solve(jw.T @ jw, jw.T)
    a = np.full(n, 300.0)
    plain, restricted = [], []
    for _ in range(40):
        e = rng.standard_normal(n) + truth * a * (chol @ rng.standard_normal(n))
        r = e - hat @ e
        plain.append(me.estimate(r, a, n - 6, dist, (80.0,))[0])
        restricted.append(me.estimate(r, a, n - 6, dist, (80.0,), weighted_jacobian=jw)[0])
    # measured: medians 0.0074 (plain) and 0.0101 (restricted)
    assert np.median(plain) < 0.8 * truth
    assert 0.9 * truth < np.median(restricted) < 1.15 * truth
    assert all(q > p for p, q in zip(plain, restricted) if p > 0)


def test_sandwich_is_the_noise_covariance_without_term():
    cov = np.array([[2.0, 0.3], [0.3, 1.0]])
    jw = np.arange(12.0).reshape(6, 2)
    assert me.sandwich(cov, jw, np.ones(6), 0.0) is cov
    grown = me.sandwich(cov, jw, np.ones(6), 0.1)
    assert np.all(np.linalg.eigvalsh(grown - cov) >= -1e-12)
    assert np.allclose(grown, grown.T)


def test_step_two_takes_the_larger_of_its_own_and_the_medium_s():
    r = np.random.default_rng(3).standard_normal(50)
    given = me.ModelError(0.02, 10.0, 0.02, None, "own residuals", 1.4)
    term = me.step_term(r, np.full(50, 10.0), np.ones(50), 46, _angles(50), given)
    assert (term.sigma, term.length, term.source, term.given) == (0.02, 10.0, "given medium",
                                                                  0.02)
    alone = me.step_term(r, np.full(50, 10.0), np.ones(50), 46, _angles(50), None)
    assert alone.sigma == 0.0 and alone.source == "none"


def test_the_likelihood_mean_is_the_normalized_average():
    grid = np.linspace(0.0, 1.0, 41)
    # a likelihood exp(-nll) proportional to c: mean 2/3 (the trapezoid rule on a line is
    # exact for the mass; the first moment within h^2 / 6)
    nll = 1000.0 - np.log(np.maximum(grid, 1e-300))
    assert abs(se.likelihood_mean(grid, nll) - 2.0 / 3.0) < 1e-3
    flat = se.likelihood_mean(grid, np.full(41, 5.0))
    assert abs(flat - 0.5) < 1e-12
    # non-finite points weigh nothing; none finite: None
    half = np.where(grid <= 0.5, 7.0, np.inf)
    assert abs(se.likelihood_mean(grid, half) - 0.25) < 0.02
    assert se.likelihood_mean(grid, np.full(41, np.inf)) is None


def test_a_declared_floor_is_the_least_term():
    """A model's declared error (MODEL_ERROR_FLOOR) enters where the residuals show less
    (chi-square below the test's limit, or a smaller s), with its length only for the
    correlated kind; an own or given s above it wins."""
    from veil.fitting.reported_uncertainty import model_floor

    r = np.random.default_rng(3).standard_normal(50)
    args = (r, np.full(50, 10.0), np.ones(50), 46, _angles(50))
    term = me.step_term(*args, None, "correlated", None, (0.005, 40.0))
    assert (term.sigma, term.length, term.own, term.source) == (0.005, 40.0, 0.0,
                                                                "model's floor")
    assert me.step_term(*args, None, "independent", None, (0.005, 40.0)).length == 0.0
    given = me.ModelError(0.02, 10.0, 0.02, None, "own residuals", 1.4)
    above = me.step_term(*args, given, "correlated", None, (0.005, 40.0))
    # a larger s keeps its source, with at least the floor's reach
    assert (above.sigma, above.length, above.source) == (0.02, 40.0, "given medium")
    below = me.ModelError(0.003, 80.0, 0.003, None, "own residuals", 1.4)
    floor = me.step_term(*args, below, "correlated", None, (0.005, 40.0))
    assert (floor.sigma, floor.length, floor.source) == (0.005, 40.0, "model's floor")
    # residuals that show more than the floor (about 1.3 %, independent): their s, the
    # floor's length
    own = me.step_term(3.0 * r, *args[1:], None, "correlated", None, (0.005, 40.0))
    assert own.source == "own residuals" and own.sigma > 0.005 and own.length >= 40.0
    back = me.ModelError.from_dict(json.loads(json.dumps(term.to_dict())))
    assert back.source == "model's floor"
    # the physical medium declares one, the paper's models and the BRDFs none
    fs, hg = model_class("forward-series"), model_class("henyey-greenstein")
    assert model_floor(model_class("rough-plastic"), fs) == fs.MODEL_ERROR_FLOOR == (0.005, 40.0)
    assert model_floor(model_class("torrance-sparrow"), hg, None) is None


# -- fits ---------------------------------------------------------------------------------------

@functools.cache
def _ggx_plate():
    """A GGX rough plastic, 0.5 % noise, the paper's protocol; and its true f_r there."""
    truth = model_class("rough-plastic")(rho=0.2, alpha=0.2, eta=1.1178, ks=1.0,
                                         distribution="ggx")
    table = veil.simulate(truth, None, seed=1, noise=0.005)
    angles = tuple(table[c].to_numpy() for c in ANGLES)
    return table, angles, model_values(truth, None, angles)


def _coverage(result, angles, truth):
    f, se = curve_stderr(result, angles)
    return float(np.mean(np.abs(f - truth) / se <= 2.0))


def test_wrong_family_is_covered_only_with_the_term():
    """Beckmann fitted to a GGX plate: the noise's standard errors cover the true curve at
    a minority of the configurations; the correlated term at >= 85 % (the independent one
    helps less: a family's error is systematic, docs/validity.md)."""
    table, angles, truth = _ggx_plate()
    fits = {kind: fit_direct(table.copy(), brdf_model="rough-plastic", model_error=kind)
            for kind in ("off", "independent", "correlated")}
    cover = {kind: _coverage(r, angles, truth) for kind, r in fits.items()}
    assert cover["off"] < 0.5
    assert cover["correlated"] >= 0.85
    assert cover["off"] <= cover["independent"] <= cover["correlated"]
    term = fits["correlated"].model_error
    assert term.sigma > 0 and term.length > 0 and term.source == "own residuals"
    assert fits["correlated"].chi2_reduced > term.chi2_threshold
    # the estimate is not moved, only its uncertainty
    assert fits["correlated"].params == fits["off"].params
    assert fits["off"].model_error is None
    assert me.noise_only(fits["correlated"]).stderr == fits["off"].stderr


def test_mismatched_medium_is_covered_only_with_the_term():
    """The paper's medium simulated with the Fresnel variant "exit", fitted with "paper"
    (docs/model.md sec. 3), psi = 90 deg, the "fast" rule: steps 1 and 2 share the medium
    model's error. The target's estimated curve against its true f_r: a minority within two
    standard errors with the noise alone, all with the correlated term that step 2 takes
    from step 1."""
    medium = model_class("henyey-greenstein")(**veil.BTDF2.as_dict(), variant="exit")
    ref, ref_black = veil.simulate(veil.BRDF2, medium, psi=(90.0,), seed=0, black=True,
                                   accuracy="fast")
    tgt, tgt_black = veil.simulate(veil.BRDF1, medium, psi=(90.0,), seed=1, black=True,
                                   accuracy="fast")
    angles = tuple(tgt[c].to_numpy() for c in ANGLES)
    truth = model_values(veil.BRDF1, None, angles)
    cover = {}
    for kind in ("off", "independent", "correlated"):
        med = veil.fit_medium(ref.copy(), veil.BRDF2, black=ref_black.copy(), variant="paper",
                              accuracy="fast", model_error=kind)
        est = veil.fit_target(tgt.copy(), med, black=tgt_black.copy(), accuracy="fast",
                              model_error=kind)
        cover[kind] = _coverage(est, angles, truth)
        if kind == "correlated":
            assert med.model_error.sigma > 0 and med.model_error.length > 0
            assert est.model_error.sigma >= med.model_error.sigma
            assert est.model_error.source in ("given medium", "own residuals")
            # step 1 keeps what step 2 needs for the error the two share ...
            term = med.model_error
            assert set(term.influence) == set(med.free)
            assert {len(r) for r in term.influence.values()} == {len(ref)}
            assert len(term.angles) == 4 and len(term.angles[0]) == len(ref)
            assert len(term.residuals) == len(term.scaled) == len(ref)
            back = FitResult.from_dict(json.loads(json.dumps(med.to_dict())))
            assert back.model_error == term
            # ... whose cross term (first order: beside sigma points, which this poorly
            # determined medium gets by default, it is left out) is negative here: the
            # medium absorbed in step 1 the error it gives back in step 2
            assert est.stats["propagation"]["method"] == "sigma-points"
            lin = veil.fit_target(tgt.copy(), med, black=tgt_black.copy(), accuracy="fast",
                                  model_error=kind, propagation="linear")
            alone = dataclasses.replace(med, model_error=dataclasses.replace(
                term, influence=None, angles=None))
            apart = veil.fit_target(tgt.copy(), alone, black=tgt_black.copy(),
                                    accuracy="fast", model_error=kind, propagation="linear")
            # how far the two sessions' errors are one: estimated, reported, kept
            share = lin.model_error.session_correlation
            assert 0.0 <= share <= 1.0 and apart.model_error.session_correlation is None
            assert "shared with step 1" in lin.report()
            saved = json.loads(json.dumps(lin.to_dict()))
            assert FitResult.from_dict(saved).model_error.session_correlation == share
            saved["model_error"]["session_correlation"] = 1.5
            with pytest.raises(FitError, match=r"model_error.session_correlation = 1.5; "
                                               r"expected a number in"):
                FitResult.from_dict(saved)
            assert apart.params == lin.params and apart.stderr == lin.stderr
            assert all(lin.stderr_total[n] < apart.stderr_total[n] for n in lin.free)
            # the budget of veil.analysis.uncertainty counts it as its own part
            budget = propagate(lin, med, tgt.copy(), black=tgt_black.copy())
            for n in lin.free:
                entry = budget.stats["budget"][n]
                assert entry["shared"] < 0
                assert budget.stderr_total[n] == pytest.approx(lin.stderr_total[n], rel=0.02)
    assert cover["off"] < 0.5
    assert cover["correlated"] >= 0.9
    assert cover["off"] <= cover["independent"] <= cover["correlated"]


def test_shared_term_is_the_kernel_over_both_sessions_written_out():
    """s^2 (G_2 R_21 G_1^T S^T + transpose) is the off-diagonal part of the covariance of
    G_2 d_2 + S G_1 d_1 with d one process over the configurations of both sessions (the
    kernel built over their union), for random influences and sensitivity; none for an
    independent term or a fit without influence."""
    rng = np.random.default_rng(3)
    a1, a2 = _angles(20), _angles(15)
    a2 = (a2[0], a2[1], a2[2] + 10.0, a2[3])
    g1, g2, sens = (rng.standard_normal((3, 20)), rng.standard_normal((4, 15)),
                    rng.standard_normal((4, 3)))
    given = me.ModelError(0.01, 20.0, 0.01, None, "own residuals", 1.5,
                          influence={n: tuple(r) for n, r in zip("abc", g1)}, angles=a1)
    union = tuple(np.concatenate([x, y]) for x, y in zip(a2, a1))
    k = me.correlation(me.distances(union), 20.0)
    m = np.hstack([g2, sens @ g1])
    full = 0.01 ** 2 * m @ k @ m.T
    own = 0.01 ** 2 * (g2 @ k[:15, :15] @ g2.T + sens @ g1 @ k[15:, 15:] @ g1.T @ sens.T)
    got = se.shared(g2, a2, given, ["a", "b", "c"], sens)
    np.testing.assert_allclose(got, full - own, rtol=1e-10, atol=1e-14)
    assert se.shared(g2, a2, dataclasses.replace(given, length=0.0), "abc", sens) is None
    assert se.shared(g2, a2, dataclasses.replace(given, influence=None), "abc", sens) is None


@functools.cache
def _two_kernels(n1, n2, length):
    """The sessions' angles, the correlation over both and the factors :func:`_two_sessions`
    draws with: the same for every draw, so made once (read-only)."""
    ang1 = _angles(n1)
    base = _angles(n2)
    ang2 = (base[0], base[1], base[2] + 10.0, base[3])
    union = tuple(np.concatenate([x, y]) for x, y in zip(ang1, ang2))
    k = me.correlation(me.distances(union), length)
    chol = np.linalg.cholesky(k + 1e-10 * np.eye(n1 + n2))
    chol2 = np.linalg.cholesky(k[n1:, n1:] + 1e-10 * np.eye(n2))
    for a in (*ang1, *ang2, k, chol, chol2):
        a.setflags(write=False)
    return ang1, ang2, k, chol, chol2


def _two_sessions(rng, share, length=40.0, s=0.01):
    """Two steps on synthetic sessions: step 1 fits three "medium" parameters to 111
    configurations, step 2 four of its own to 90 others (other angles) through the medium
    step 1 estimated (J_m couples them). The model errors d_1 = s u_1 and d_2 = s (share u_2
    + sqrt(1 - share^2) v), (u_1, u_2) one process over both sessions' configurations and v
    an independent one, both with the correlation exp(-D / ell). Returns step 1's term (with
    its residuals) and step 2's residuals, scaled values, Jacobians, angles, error
    covariance and the medium's covariance."""
    n1, n2 = 111, 90
    ang1, ang2, k, chol, chol2 = _two_kernels(n1, n2, length)
    x1, x2 = np.linspace(-1.0, 1.0, n1), np.linspace(-1.0, 1.0, n2)
    j1 = np.stack([np.ones(n1), x1, x1 ** 2], axis=1) * 40.0
    j2 = np.stack([np.ones(n2), x2 ** 2, x2 ** 3, np.exp(-8.0 * x2 ** 2)], axis=1) * 40.0
    jm = np.stack([x2, np.sin(3.0 * x2), np.cos(5.0 * x2)], axis=1) * 60.0
    a1, a2 = np.linspace(150.0, 250.0, n1), np.linspace(100.0, 300.0, n2)
    u = chol @ rng.standard_normal(n1 + n2)
    v = chol2 @ rng.standard_normal(n2)
    e1 = rng.standard_normal(n1) + a1 * s * u[:n1]
    c1 = np.linalg.inv(j1.T @ j1)
    delta = c1 @ j1.T @ e1                     # step 1's medium estimate, off by this
    r1 = e1 - j1 @ delta
    e2 = rng.standard_normal(n2) + a2 * s * (share * u[n1:] + math.sqrt(1 - share ** 2) * v)
    seen = e2 - jm @ delta
    r2 = seen - j2 @ np.linalg.solve(j2.T @ j2, j2.T @ seen)
    g1 = c1 @ j1.T * a1[None, :]
    names = ["p0", "p1", "p2"]
    given = me.ModelError(s, length, s, None, "own residuals", 1.0,
                          influence={n: tuple(g) for n, g in zip(names, g1)}, angles=ang1,
                          residuals=tuple(r1), scaled=tuple(a1))
    cov_m = c1 + s ** 2 * g1 @ k[:n1, :n1] @ g1.T
    return given, names, r2, a2, j2, jm, ang2, s ** 2 * k[n1:, n1:], cov_m


def test_session_correlation_is_recovered():
    """How far step 2's error is step 1's, from both fits' residuals (the mean of c under the
    restricted likelihood of :func:`veil.fitting.model_error.session_correlation`, step 1's
    estimate seen through in step 2): ordered with the truth for independent, half-shared
    and shared errors over 30 draws each (measured medians 0.36, 0.49, 0.74: one draw holds
    little about c, so the mean stays inside (0, 1), where the likelihood's maximum gave
    0.05, 0.54, 1.00, at the bound 1 in 18 of the 30 shared draws and at 0 in many
    independent ones); None without the given fit's residuals (result files of earlier
    veils)."""
    rng = np.random.default_rng(0)
    medians, maxima = {}, {}
    for truth in (0.0, 0.5, 1.0):
        got, best = [], []
        for _ in range(30):
            given, names, r2, a2, j2, jm, ang2, cov, cov_m = _two_sessions(rng, truth)
            # session_correlation is this mean; the likelihood is computed once for both
            grid, nll = se.share_likelihood(r2, a2, j2, ang2, cov, given, names, jm, cov_m)
            got.append(se.likelihood_mean(grid, nll))
            best.append(grid[int(np.argmin(nll))])
        # a mean over a likelihood that is positive on [0, 1] never reaches a bound
        assert all(0.0 < g < 1.0 for g in got), got
        medians[truth], maxima[truth] = float(np.median(got)), float(np.median(best))
    assert medians[0.0] + 0.1 < medians[0.5] < medians[1.0] - 0.1, medians
    assert medians[0.0] < 0.45 and medians[1.0] > 0.65, medians
    # the likelihood itself locates c (its maximum: 0.05, 0.54, 1.00 measured; without the
    # coupling through step 1's estimate 0.00, 0.23, 0.74)
    assert maxima[0.0] < 0.15 and 0.4 < maxima[0.5] < 0.65 and maxima[1.0] > 0.95, maxima
    given, names, r2, a2, j2, jm, ang2, cov, cov_m = _two_sessions(rng, 1.0)
    grid, nll = se.share_likelihood(r2, a2, j2, ang2, cov, given, names, jm, cov_m)
    assert se.session_correlation(r2, a2, j2, ang2, cov, given, names, jm, cov_m) == \
        se.likelihood_mean(grid, nll)
    assert se.session_correlation(r2, a2, j2, ang2, cov, dataclasses.replace(
        given, residuals=None, scaled=None), names, jm, cov_m) is None
    # the cross term scales with it
    sens = rng.standard_normal((4, 3))
    g2 = rng.standard_normal((4, 90))
    np.testing.assert_allclose(se.shared(g2, ang2, given, names, sens, 0.25),
                               0.25 * se.shared(g2, ang2, given, names, sens))


def test_joint_fit_gets_its_own_term_and_the_reference_s_covariance():
    """The joint fit of steps 1 and 2 (reference and target in the medium, the reference's
    step-0 result held) on the mismatched medium of the test above: the term estimated over
    both sessions, the estimates those of ``model_error="off"`` exactly, the reference's
    covariance propagated into ``stderr_total``, and the target's curve against its truth
    covered only with the term."""
    medium = model_class("henyey-greenstein")(**veil.BTDF2.as_dict(), variant="exit")
    ref, ref_black = veil.simulate(veil.BRDF2, medium, psi=(90.0,), seed=0, black=True,
                                   accuracy="fast")
    tgt, tgt_black = veil.simulate(veil.BRDF1, medium, psi=(90.0,), seed=1, black=True,
                                   accuracy="fast")
    step0 = veil.fit_reference(veil.simulate(veil.BRDF2, None, seed=2))
    sessions = [(veil.fitting.prepare(ref, ref_black, "reference").table, "m", "reference"),
                (veil.fitting.prepare(tgt, tgt_black, "target").table, "m", "target")]
    angles = tuple(tgt[c].to_numpy() for c in ANGLES)
    truth = model_values(veil.BRDF1, None, angles)
    fits = {kind: veil.fit_joint(sessions, reference=step0, variant="paper", accuracy="fast",
                                 model_error=kind)
            for kind in ("off", "independent", "correlated")}
    off = fits["off"]
    assert off.model_error is None and off.stderr_total is not None
    assert all(off.stderr_total[n] > off.stderr[n] for n in off.free)
    for kind in ("independent", "correlated"):
        on = fits[kind]
        assert on.params == off.params                    # the estimates do not move
        assert on.model_error.source == "own residuals" and on.model_error.sigma > 0
        assert on.model_error.given is None
        assert me.noise_only(on).stderr == off.stderr
        assert me.noise_only(on).stderr_total == off.stderr_total
        assert all(on.stderr_total[n] > off.stderr_total[n] for n in off.free)
    assert fits["correlated"].model_error.length > 0
    cover = {kind: _coverage(r, angles, truth) for kind, r in fits.items()}
    assert cover["off"] < 0.5 and cover["correlated"] >= 0.9
    assert cover["off"] <= cover["independent"] <= cover["correlated"]
    back = veil.fitting.JointResult.from_dict(json.loads(json.dumps(
        fits["correlated"].to_dict())))
    assert back.model_error == fits["correlated"].model_error
    assert back.stderr_total == fits["correlated"].stderr_total


def test_well_specified_fit_is_unchanged_bit_for_bit():
    truth = model_class("rough-plastic")(rho=0.2, alpha=0.2, eta=1.1178, ks=1.0)
    table = veil.simulate(truth, None, seed=4, noise=0.01)
    off = fit_direct(table.copy(), brdf_model="rough-plastic", model_error="off")
    for kind in ("independent", "correlated"):
        on = fit_direct(table.copy(), brdf_model="rough-plastic", model_error=kind)
        assert on.chi2_reduced < on.model_error.chi2_threshold
        assert on.model_error.sigma == 0.0 and on.model_error.noise_only is None
        assert dataclasses.replace(on, model_error=None) == off
        a, b = on.to_dict(), off.to_dict()
        assert a.pop("model_error")["sigma"] == 0.0 and a == b
        assert "model_error" not in b           # files without the term keep their bytes


def test_well_specified_medium_fit_is_unchanged_bit_for_bit():
    """Step 1 of the paper's simulated protocol (BRDF2 in BTDF2, psi = 90 deg): chi-square
    about 1, no term, the result of ``model_error="off"`` exactly."""
    ref, black = veil.simulate(veil.BRDF2, veil.BTDF2, psi=(90.0,), seed=0, black=True,
                               accuracy="fast")
    off = veil.fit_medium(ref.copy(), veil.BRDF2, black=black.copy(), accuracy="fast",
                          model_error="off")
    on = veil.fit_medium(ref.copy(), veil.BRDF2, black=black.copy(), accuracy="fast")
    assert on.model_error.sigma == 0.0 and on.chi2_reduced < on.model_error.chi2_threshold
    assert dataclasses.replace(on, model_error=None) == off


def test_a_given_fit_s_term_is_kept_apart_when_this_fit_shows_none():
    """Step 1 on data its model fits (no term of its own) with a reference whose result
    carries a term: the propagated total includes the reference's term, the noise-only
    uncertainties (``noise_only``) and ``model_error="off"`` exclude it, and both equal the
    fit with the reference's noise-only result."""
    clear = veil.simulate(veil.BRDF2, None, seed=2)
    ref_off = veil.fit_reference(clear, model_error="off")
    noise = {"stderr": ref_off.stderr, "correlation": ref_off.correlation,
             "stderr_total": None, "correlation_total": None}
    ref_term = dataclasses.replace(
        ref_off, stderr={k: 3.0 * v for k, v in ref_off.stderr.items()},
        model_error=me.ModelError(0.05, 0.0, 0.05, None, "own residuals", 1.3, noise))
    table, black = veil.simulate(veil.BRDF2, veil.BTDF2, psi=(90.0,), seed=0, black=True,
                                 accuracy="fast")
    fits = {name: veil.fit_medium(table.copy(), ref, black=black.copy(), accuracy="fast",
                                  model_error=kind)
            for name, ref, kind in (("term", ref_term, None), ("off", ref_term, "off"),
                                    ("plain", ref_off, None))}
    term = fits["term"].model_error
    assert term.sigma == 0.0 and term.noise_only is not None
    plain = fits["plain"].stderr_total
    assert me.noise_only(fits["term"]).stderr_total == plain == fits["off"].stderr_total
    assert all(fits["term"].stderr_total[k] > plain[k] for k in plain)
    assert fits["plain"].model_error.noise_only is None


def test_sandwich_is_the_covariance_of_the_weighted_estimate():
    """C J_w^T (I + s^2 A R A) J_w C written out, for a random Jacobian, values and a
    correlation matrix; and the independent likelihood's closed form equals the general
    one at R = I."""
    rng = np.random.default_rng(7)
    jw = rng.standard_normal((30, 3))
    a = rng.uniform(5.0, 50.0, 30)
    dist = np.abs(np.subtract.outer(np.arange(30.0), np.arange(30.0))) * 3.0
    corr = me.correlation(dist, 10.0)
    c = np.linalg.inv(jw.T @ jw)
    want = c @ jw.T @ (np.eye(30) + 0.02 ** 2 * (a[:, None] * corr * a[None, :])) @ jw @ c
    np.testing.assert_allclose(me.sandwich(c, jw, a, 0.02, corr), want, rtol=1e-12)
    want_indep = c @ jw.T @ (np.eye(30) + 0.02 ** 2 * np.diag(a * a)) @ jw @ c
    np.testing.assert_allclose(me.sandwich(c, jw, a, 0.02), want_indep, rtol=1e-12)
    r = rng.standard_normal(30)
    general = me._nll(r, a, np.eye(30), 1e-4)
    assert abs(me._nll_independent(r, a, 1e-4) - general) < 1e-9 * abs(general)
    # the estimate's likelihood (one eigendecomposition per length) is the Cholesky one's
    spectrum = me._spectrum(r, a, corr)
    for t in (0.0, 1e-6, 1e-4, 1e-2):
        assert me._nll_spectrum(spectrum, t) - 0.0 == pytest.approx(
            me._nll(r, a, corr, t), rel=1e-10, abs=1e-10)


def test_unweighted_fit_has_no_term():
    table, _, _ = _ggx_plate()
    result = fit_direct(table.drop(columns=["sigma"]), brdf_model="rough-plastic")
    assert result.model_error is None


# -- the result file and bad input --------------------------------------------------------------

def test_result_file_round_trip(tmp_path):
    table, _, _ = _ggx_plate()
    result = fit_direct(table.copy(), brdf_model="rough-plastic", model_error="independent")
    assert result.model_error.sigma > 0 and result.model_error.length == 0.0
    path = tmp_path / "r.json"
    result.to_json(path)
    data = json.loads(path.read_text())
    assert set(data["model_error"]) == {"sigma", "length", "own", "given", "source",
                                        "chi2_threshold", "noise_only"}
    again = FitResult.from_json(path)
    assert again == result
    assert me.noise_only(again) == me.noise_only(result)
    assert "model error" in result.report()
    data["model_error"]["source"] = "guess"
    path.write_text(json.dumps(data))
    with pytest.raises(FitError, match="model_error.source"):
        FitResult.from_json(path)


def test_bad_kind():
    with pytest.raises(FitError, match="model_error = 'yes'"):
        fit_direct(_ggx_plate()[0].copy(), brdf_model="rough-plastic", model_error="yes")
    assert me.check_kind(None) == me.DEFAULT == "correlated"
    assert me.check_kind(False) == "off"


def test_cli_offers_the_declared_kinds():
    """The command line's --model-error (kept free of the fitting import, so that help stays
    fast) lists the module's kinds and default."""
    from veil.cli.fit_cmd import pipeline_command
    from veil.cli.joint_cmd import joint_command

    for command in (pipeline_command, joint_command):
        option = next(p for p in command.params if p.name == "model_error")
        assert tuple(option.type.choices) == me.KINDS and option.default == me.DEFAULT


def test_cli_bad_kind_exits_2(tmp_path):
    path = tmp_path / "t.csv"
    _ggx_plate()[0].to_csv(path, index=False)
    run = CliRunner().invoke(main, ["fit", "reference", str(path), "-o",
                                    str(tmp_path / "o.json"), "--model-error", "maybe"])
    assert run.exit_code == 2 and "--model-error" in run.output
