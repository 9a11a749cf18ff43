"""Identifiability diagnostics of a fit (docs/model.md sec. 7, the paper's sec. 5.2.4 failure).

A fit can converge, pass its chi-square and still be meaningless: a smooth object through a
strongly scattering medium and a rough one through a weak medium fit the same data. For any
fit result (a step of :mod:`veil.fitting` or a joint fit) and its data this module reports

- the correlation matrix and the parameters that trade off (|r| > ``max_correlation``);
- the condition number of the weighted Jacobian with columns scaled by the parameter values
  (relative sensitivities) and by the standard errors (= sqrt of the correlation matrix's
  condition number), and the weakest direction (the combination the data barely constrain);
- relative standard errors (stderr / |value|; for g: stderr / (1 - |g|), the lobe's width
  scale) above ``max_relative``;
- optionally profile likelihoods (:mod:`veil.analysis.profiles`): one parameter held on a
  grid, all others refitted; the rise of chi-square, Delta chi^2, against the held value. A
  profile that stays below 1 over the grid's range is flat: the data do not determine that
  parameter.

With the previous step's result (``medium=`` for a target fit, ``reference=`` for a medium
fit) its parameters become free but tied to that result by a Gaussian prior from its
covariance: the diagnostics then include what the previous step left uncertain, which is
where the paper's failure hides. Without it the given model is taken as exact.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from ..errors import FitError, InputTypeError
from ..fitting.joint import build, shareable
from ..fitting.problem import ITERATION_ACCURACY, Problem, session_problem
from ..fitting.result import FitResult, JointResult, unfinished
from ..fitting.solver import covariance, solve, weighted_jacobian
from ..models import BRDF, REGISTRY, Medium, Model
from ..numbers import format_number, format_percent
from .profiles import FLAT, PROFILE_POINTS, LinearRefit, Profile, profile_likelihood, profiles

#: Default thresholds.
MAX_RELATIVE = 0.25
MAX_CORRELATION = 0.9


@dataclass
class Diagnosis:
    """The diagnostics of one fit (module docstring); :meth:`report` prints them."""

    names: list
    values: dict
    stderr: dict
    relative: dict
    correlation: np.ndarray
    condition: dict
    weakest: dict
    profiles: dict = field(default_factory=dict)
    poorly_determined: list = field(default_factory=list)
    tradeoffs: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    thresholds: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.poorly_determined and not self.tradeoffs

    def to_dict(self) -> dict:
        """JSON-ready (non-finite numbers become None)."""
        return _finite(
            {
                "parameters": self.names,
                "values": self.values,
                "stderr": self.stderr,
                "relative_stderr": self.relative,
                "correlation": {
                    a: {b: float(self.correlation[i, j]) for j, b in enumerate(self.names)}
                    for i, a in enumerate(self.names)
                },
                "condition": self.condition,
                "weakest_direction": self.weakest,
                "profiles": {k: p.to_dict() for k, p in self.profiles.items()},
                "poorly_determined": [
                    {"parameter": n, "reason": r} for n, r in self.poorly_determined
                ],
                "tradeoffs": [{"a": a, "b": b, "correlation": r} for a, b, r in self.tradeoffs],
                "notes": self.notes,
                "thresholds": self.thresholds,
                "ok": self.ok,
            }
        )

    def report(self) -> str:
        lines = ["[[Identifiability]]"]
        for n in self.names:
            se, rel = self.stderr[n], self.relative[n]
            prof = self.profiles.get(n)
            extra = ""
            if prof is not None:
                lo, hi = prof.interval
                extra = f"  profile 1-sigma [{_f(lo)}, {_f(hi)}]" + (
                    f" FLAT ({', '.join(prof.flat)})" if prof.flat else ""
                )
            lines.append(
                f"    {n:<10} {_f(self.values[n])} +/- {_f(se)} (relative {_pct(rel)}){extra}"
            )
        lines.append(f"    condition number (columns x values) = {_f(self.condition['values'])}")
        lines.append(f"    condition number (columns x stderr) = {_f(self.condition['stderr'])}")
        w = ", ".join(f"{c:+.2f} {n}" for n, c in self.weakest.items() if abs(c) >= 0.1)
        lines.append(f"    weakest direction (relative units): {w}")
        if self.poorly_determined:
            lines.append("[[Poorly determined]]")
            lines += [f"    {n}: {r}" for n, r in self.poorly_determined]
        if self.tradeoffs:
            lines.append("[[Trade-offs]]")
            lines += [f"    {a} <-> {b}: r = {r:+.3f}" for a, b, r in self.tradeoffs]
        if self.ok:
            lines.append("    no parameter poorly determined, no trade-off above the thresholds")
        for note in self.notes:
            lines.append(f"    note: {note}")
        return "\n".join(lines)


def _finite(obj):
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


def _f(x) -> str:
    return format_number(x, 4, "-")


_pct = format_percent


def relative_error(name: str, value: float, stderr, spec=None) -> float:
    """stderr relative to the value, or to the distance to the nearer bound for parameters
    whose declaration says so (g: 1 - |g|, the lobe's width scale). ``spec`` is the declared
    parameter; without it the name (``g``, ``g[low]``, ``ref.n``) is looked up among the
    registered models."""
    if spec is None:
        base = name.split("[")[0].split(".")[-1]
        spec = next((p for cls in REGISTRY.values() for p in cls.PARAMS if p.key == base), None)
    if spec is None:
        if stderr is None:
            return math.inf
        return stderr / abs(value) if value != 0 else math.inf
    return spec.relative_error(value, stderr)


# --------------------------------------------------------------------------------------
# the problem behind a result
# --------------------------------------------------------------------------------------
def _as_model(obj, kind):
    if obj is None:
        return None, None
    if isinstance(obj, JointResult):
        raise FitError(f"expected a {kind} fit result or model, got a joint fit result")
    if isinstance(obj, FitResult):
        if obj.kind != kind:
            raise FitError(f"expected a {kind} fit result, got a {obj.model} ({obj.kind}) result")
        return obj.one_model(), obj
    if isinstance(obj, Model) and obj.KIND == kind:
        return obj, None
    raise FitError(f"expected a FitResult or a {kind} model, got {type(obj).__name__}")


def problem_for(
    result: FitResult, data, *, medium=None, reference=None, black=None
) -> tuple[Problem, list[str]]:
    """The least-squares problem a result solved, at its estimate: (problem, notes).

    data : the table of a step result (DataFrame or path), or for a joint result its sessions
        (a list as for :func:`veil.fit_joint`).
    medium / reference : the previous step (FitResult: its parameters join as free with a
        Gaussian prior from its covariance; a model: held exact). Default: the result's
        ``given`` model, exact.
    """
    notes: list[str] = []
    if isinstance(result, JointResult):
        if result.channels is not None:
            raise FitError(
                f"the joint fit fits channels {', '.join(result.channel_names)} at once: the "
                f"diagnostics take a joint fit of one channel (veil fit joint --channel NAME)"
            )
        layout = result.layout
        ref = None
        if layout.get("reference_given"):
            if not result.given:
                raise FitError(
                    "the joint result held the reference fixed but does not say which (key 'given')"
                )
            ref = result.given_model()
        ref_names = set(layout["objects"].get("reference", {}).values()) if ref else set()
        fixed = {k: v for k, v in result.fixed.items() if k not in ref_names}
        mcls = result._family("medium")
        problem, _ = build(
            data,
            reference=ref,
            shared=layout.get("shared", []),
            per_medium=[p for p in shareable(mcls) if p not in layout.get("shared", [])],
            fixed=fixed,
            brdf_model=result._family("brdf").NAME,
            medium_model=mcls.NAME,
            brdf_options=result._options("brdf"),
            medium_options=result._options("medium"),
        )
        if problem.names != list(result.params):
            raise FitError(
                "the sessions given do not make up the joint fit's parameters "
                f"({', '.join(result.params)}); give the same sessions (media "
                f"labels and objects) as the fit"
            )
        _check_points(problem, result, "the sessions given", layout.get("sessions") or ())
        problem.values = np.array([result.params[n] for n in problem.names])
        return problem, notes
    step = result.step
    model = result.one_model()
    free = [result.model_class.param(n).key for n in result.free]
    if step in ("reference", "direct"):
        if medium is not None or reference is not None:
            raise FitError(f"a {step} fit (clear water) has no medium or reference to include")
        problem = session_problem(
            data, cast(BRDF, model), None, free=free, black=black, what=f"{step} (clear medium)"
        )
    elif step in _THROUGH_MEDIUM:
        problem = _through_medium(
            result, data, step, {"medium": medium, "reference": reference}, free, black, notes
        )
    else:
        raise FitError(f"cannot diagnose a result of step {step!r}")
    where = f"the table {_name(data)}" + (
        "" if black is None else f" less the black cloth {_name(black)}"
    )
    _check_points(problem, result, where)
    _check_black(result, black, where)
    return problem, notes


def _check_black(result: FitResult, black, where: str) -> None:
    """A FitError when the fit subtracted a black-cloth session and none is given, or the
    other way round (``stats["black_subtracted"]``; results of earlier veils do not say):
    the same number of points, other data, and the diagnostics of another problem."""
    subtracted = result.stats.get("black_subtracted")
    if not isinstance(subtracted, bool) or subtracted == (black is not None):
        return
    said = (
        "subtracted a black-cloth session and none is given: give it (--black FILE, black=)"
        if subtracted
        else "subtracted no black-cloth session and one is given: leave it out"
    )
    raise FitError(
        f"{where}: the fit {said}; diagnose reads the data the fit was made from, and "
        f"other data would give the diagnostics of another problem"
    )


def _name(table) -> str:
    return os.fspath(table) if isinstance(table, (str, os.PathLike)) else "(a DataFrame)"


def _check_points(problem: Problem, result: FitResult, where: str, sessions=()) -> None:
    """A FitError when the data are not the fit's: another number of points in all (``where``
    names the data) or, of a joint fit, in a session (``sessions``: the fit's layout's)."""
    fitted: dict = {}
    for s in sessions:  # the fit's sessions by object and medium, in order
        fitted.setdefault((s.get("object"), s.get("medium")), []).append(s.get("n_points"))
    counts = []
    for b in problem.blocks:
        used = fitted.get((b.session.object, b.session.medium)) or [None]
        counts.append((f"{where}: session {b.session.name!r}", b.size, used.pop(0)))
    for what, got, used in counts + [(where, problem.n_points, result.n_points)]:
        if used is not None and got != used:
            raise FitError(
                f"{what} has {got} points but the fit used {used}: diagnose reads the data "
                f"the fit was made from; give the same table(s) (and black cloth), not others"
            )


#: The steps through the medium by their name in a result: (the step's number, the argument
#: naming the model held, that model's kind and words, the argument the step does not take,
#: what the table holds).
_THROUGH_MEDIUM = {
    "target": (2, "medium", "medium", "the medium", "reference", "target (in the medium)"),
    "medium": (
        1,
        "reference",
        "brdf",
        "the reference's f_r",
        "medium",
        "reference (in the medium)",
    ),
}


def _through_medium(
    result: FitResult, data, step: str, given: dict, free, black, notes: list
) -> Problem:
    """The problem of step 1 or 2: the fitted model through (or of) the model held, which
    ``given`` names (a FitResult joins with its prior, a model is exact) or else the
    result's own ``given`` model, exact (said in ``notes``)."""
    number, name, kind, words, other_name, what = _THROUGH_MEDIUM[step]
    if given[other_name] is not None:
        raise FitError(f"a {step} fit (step {number}) takes --{name}, not --{other_name}")
    other, other_result = _as_model(given[name], kind)
    if other is None:
        other = result.given_model()
        if other is None:
            raise FitError(f"the {step} result does not name its {name}: give {name}=")
        notes.append(
            f"{words} is taken as exact (give the {name}'s fit result to include its uncertainty)"
        )
    model = result.one_model()
    brdf, medium = (other, model) if kind == "brdf" else (model, other)
    problem = session_problem(
        data, cast(BRDF, brdf), cast(Medium, medium), free=free, black=black, what=what
    )
    if other_result is not None:
        _add_prior(problem, other_result, name)
    return problem


def _add_prior(problem, other: FitResult, what):
    found = other.covariance(total=True)
    if found is None:
        raise FitError(f"the {what} result has no uncertainties: it cannot be included")
    onames, cov = found
    cls = other.model_class
    mapped = [cls.param(n).key for n in onames]
    for n in mapped:
        problem.free[problem.index(n)] = True
    problem.set_prior(mapped, [other.params[n] for n in onames], cov)


# --------------------------------------------------------------------------------------
# the diagnostics
# --------------------------------------------------------------------------------------
def diagnose(
    result: FitResult,
    data,
    *,
    medium=None,
    reference=None,
    black=None,
    profile=False,
    points: int = PROFILE_POINTS,
    max_relative: float = MAX_RELATIVE,
    max_correlation: float = MAX_CORRELATION,
    accuracy: str = ITERATION_ACCURACY,
    progress=None,
) -> Diagnosis:
    """Diagnostics of ``result`` on its ``data`` (module docstring; arguments as
    :func:`problem_for`; data other than the fit's are a FitError before any evaluation).
    ``profile``: False, True (every free parameter) or a list of names. Names are the
    problem's: a medium's index is ``eta_u`` (the BRDF has ``eta``). ``progress(stage,
    done, total)`` is told each stage and each refit of the profiles, the stage naming the
    parameter profiled. A linear family's covariance and profiles are those of the
    penalized objective its fit minimized (:func:`_linear_refits`)."""
    _check_arguments(result, points, max_relative, max_correlation)
    problem, notes = problem_for(result, data, medium=medium, reference=reference, black=black)
    what = unfinished(result)
    if what is not None:  # the diagnostics are at its last point, not at an optimum
        notes.append(f"the result is {what}: the diagnostics are at its last point")
    _linear_alone(problem)
    names = problem.free_names
    say = progress or (lambda stage, done, total: None)
    say(f"{problem.n_points} points, {len(names)} free parameters: the estimate", None, None)
    x = _optimum(problem, notes, accuracy)
    linear = _linear_refits(result, problem, accuracy, notes, say)
    say("the covariance and the weighted Jacobian at the estimate", None, None)
    cov: np.ndarray | None = (
        covariance(problem, x, accuracy)
        if (linear is None or linear.smoothness is None)
        else linear.covariance(x)[0]
    )  # a linear fit's own (penalized), not the unpenalized one
    if cov is None:
        raise FitError(
            "the Jacobian is singular at the estimate: at least one combination of "
            "the parameters is not determined at all (fix one of them)"
        )
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.outer(se, se)
    jw = weighted_jacobian(problem, x, accuracy)
    vals = x[problem.free]
    cond_values = _cond(jw * np.where(vals != 0, np.abs(vals), 1.0)[None, :])
    cond_stderr = _cond(jw * se[None, :])
    # weakest direction in relative units (columns scaled by stderr -> unit correlation)
    _, s, vt = np.linalg.svd(jw * se[None, :], full_matrices=False)
    weak = vt[-1] / np.max(np.abs(vt[-1]))
    weak = weak * np.sign(weak[np.argmax(np.abs(weak))])
    values = {n: float(v) for n, v in zip(names, vals)}
    stderr = {n: float(v) for n, v in zip(names, se)}
    relative = {
        n: relative_error(n, values[n], stderr[n], problem.params[problem.index(n)].spec)
        for n in names
    }
    diag = Diagnosis(
        names=names,
        values=values,
        stderr=stderr,
        relative=relative,
        correlation=corr,
        condition={"values": cond_values, "stderr": cond_stderr},
        weakest={n: float(c) for n, c in zip(names, weak)},
        notes=notes,
        thresholds={"max_relative": max_relative, "max_correlation": max_correlation, "flat": FLAT},
    )
    if profile:
        which = names if profile is True else list(profile)
        diag.profiles.update(
            profiles(problem, x, which, stderr, points, accuracy, progress, refits=linear)
        )
    _verdicts(diag, max_relative, max_correlation)
    return diag


def _linear_refits(
    result: FitResult, problem: Problem, accuracy: str, notes: list, say
) -> LinearRefit | None:
    """A linear family's columns at the fit's rule and smoothness, the coefficients its
    solve held at 0 free as in the fit (:class:`LinearRefit`; None for another problem):
    its covariance is the fit's (penalized), its profiles those of the objective the fit
    minimized. A result without its smoothness is said in ``notes``."""
    if not LinearRefit.of(problem):
        return None
    smoothness = (result.stats or {}).get("smoothness")
    if smoothness is None:
        notes.append(
            "the result records no smoothness (stats 'smoothness'): the linear family's "
            "covariance is the unpenalized least-squares one and its profiles are unpenalized, "
            "not those of the penalized objective the fit minimized; refit to diagnose them"
        )
    bound = [result.model_class.param(n).key for n in result.at_bound]
    rule = result.accuracy or accuracy  # the fit's own columns: its covariance exactly
    return LinearRefit(problem, rule, say, smoothness, bound)


def _linear_alone(problem: Problem) -> None:
    """A FitError for a linear family (docs/nonparametric.md) diagnosed with the previous
    step's parameters free (``--medium``, ``--reference``): its fit holds that model (its
    uncertainty is propagated into the fit's ``stderr_total``), and with it free the
    problem is neither linear nor the fit's penalized one; its estimate would be re-solved
    by the solver in every coefficient, minutes a step."""
    if problem.prior is not None and any(type(b.brdf).LINEAR for b in problem.blocks):
        raise FitError(
            "a linear family's fit holds the model it was fitted through (its uncertainty is "
            "in the fit's stderr_total): diagnose it without --medium / --reference"
        )


def _check_arguments(result, points, max_relative, max_correlation) -> None:
    if not isinstance(result, FitResult):
        raise InputTypeError(f"expected a FitResult, got {type(result).__name__}")
    for name, v, lo, hi in (
        ("max_relative", max_relative, 0, math.inf),
        ("max_correlation", max_correlation, 0, 1),
    ):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo < v <= hi):
            raise FitError(f"{name} = {v!r}; expected a number in ({lo}, {hi}]")
    if isinstance(points, bool) or not isinstance(points, int) or points < 3:
        raise FitError(f"points = {points!r}; expected an integer >= 3")


def _optimum(problem: Problem, notes: list, accuracy: str) -> np.ndarray:
    """The estimate: the result's, or where it moves when the previous step's parameters
    are free under their uncertainty (``notes`` says so)."""
    x = problem.values.copy()
    if problem.prior is None:
        return x
    names = problem.free_names
    sol = solve(problem, x, accuracy=accuracy)
    if sol.status <= 0:
        notes.append(
            f"with the previous step's parameters free under its uncertainty the refit did "
            f"not converge ({sol.message}): the diagnostics are at its last point"
        )
    moved = [
        f"{n} {_f(x[problem.index(n)])} -> {_f(sol.x[problem.index(n)])}"
        for n in names
        if not math.isclose(
            x[problem.index(n)], sol.x[problem.index(n)], rel_tol=1e-3, abs_tol=1e-12
        )
    ]
    if moved:
        notes.append(
            "with the previous step's parameters free under its uncertainty the "
            "optimum moves: " + ", ".join(moved)
        )
    return sol.x


def _verdicts(diag: Diagnosis, max_relative: float, max_correlation: float) -> None:
    """The poorly determined parameters (relative standard error, flat profile) and the
    trade-offs (correlation) of ``diag``, strongest first."""
    names, relative, corr = diag.names, diag.relative, diag.correlation
    for n in names:
        if relative[n] > max_relative:
            diag.poorly_determined.append(
                (n, f"relative standard error {_pct(relative[n])} > {_pct(max_relative)}")
            )
        prof = diag.profiles.get(n)
        if prof is not None and prof.flat:
            ends = {"lower": prof.values[0], "upper": prof.values[-1]}
            sides = "; ".join(f"{side} side out to {_f(ends[side])}" for side in prof.flat)
            diag.poorly_determined.append((n, f"flat profile (Delta chi^2 < {FLAT:g}: {sides})"))
    for i, a in enumerate(names):
        for j in range(i + 1, len(names)):
            if abs(corr[i, j]) > max_correlation:
                diag.tradeoffs.append((a, names[j], float(corr[i, j])))
    diag.tradeoffs.sort(key=lambda t: -abs(t[2]))


def _cond(a: np.ndarray) -> float:
    s = np.linalg.svd(a, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


__all__ = [
    "diagnose",
    "Diagnosis",
    "Profile",
    "profile_likelihood",
    "problem_for",
    "relative_error",
    "MAX_RELATIVE",
    "MAX_CORRELATION",
]
