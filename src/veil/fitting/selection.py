"""The data choose the model (issue 29): candidates from the registry, fitted side by side,
ranked by BIC with each fit's model-discrepancy term.

- **Candidates** (:func:`candidates`): every registered family of a kind with every value of
  its ranked options (:func:`veil.models.registry.candidates`: options with a finite set of
  values that do not describe the apparatus). Apparatus options (path length, plate width,
  Fresnel variant) are given once and go to every candidate that declares them; a ranked
  option given by the user pins its value.
- **Fitting** (:func:`fit_candidates`): one fit per candidate, in threads; a candidate whose
  fit raises is kept with its error, one that does not converge with its result; neither is
  ranked.
- **Ranking** (:func:`rank`): -2 ln L of each fit's weighted residuals r under the covariance
  its model-discrepancy term gives them, I + s^2 A R(ell) A (A = diag(f / sigma),
  :mod:`veil.fitting.model_error`; with s = 0 this is the chi-square), plus 2k (AIC) or
  k ln N (BIC), k the free parameters and the term's s (and ell) when the fit estimated them
  from its own residuals. A fit without sigma (clear water often has none) is scored as a
  Gaussian of unknown variance, N ln(RSS / N). Akaike weights exp(-dBIC / 2), normalized
  over the ranked candidates.
- **Close calls** (:func:`curve_spread`): candidates within dBIC 2 of the best are a close
  call; the spread of their curves (BIC-weighted standard deviation over the candidates'
  curves) widens the curves' reported uncertainty.
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..errors import FitError
from ..models import registry
from .model_error import _nll_independent, _nll_spectrum, _spectrum, correlation, distances
from .result import FitResult
from .steps import MisfitWarning

#: Candidates whose BIC is within this of the best are a close call (Kass and Raftery 1995:
#: "not worth more than a bare mention").
CLOSE_DELTA_BIC = 2.0
#: The values of ``--models`` besides FAMILY+MEDIUM.
MODES = registry.MODES


class NoCandidateError(FitError):
    """Every candidate of a step failed or did not converge; ``ranking`` lists them."""

    def __init__(self, step: str, ranking: Ranking):
        self.step, self.ranking = step, ranking
        super().__init__(
            f"{step}: every candidate failed or did not converge ({len(ranking.rows)} tried)"
        )


@dataclass(frozen=True)
class Candidate:
    """One family with its ranked options' values (``options``; apparatus options are
    added by :meth:`model_options`)."""

    family: str
    options: dict = field(default_factory=dict)
    #: other values of its ranked options that make the same model with the apparatus
    #: options given (``Model.same_model``): fitted once, as this one
    same: tuple = ()

    @property
    def kind(self) -> str:
        return registry.REGISTRY[self.family].KIND

    @property
    def label(self) -> str:
        if not self.options:
            return self.family
        return f"{self.family}[{','.join(f'{k}={v}' for k, v in self.options.items())}]"

    def model_options(self, given: dict | None = None) -> dict:
        """The options to fit with: ``given`` (apparatus) ones the family declares, then its
        own ranked values."""
        declared = registry.REGISTRY[self.family].option_names()
        out = {k: v for k, v in (given or {}).items() if k in declared}
        out.update(self.options)
        return out


def candidates(
    kind: str, given_options: dict | None = None, families=None, linear: bool = True
) -> list[Candidate]:
    """The candidates of ``kind`` ("brdf" or "medium"); ``given_options`` pin ranked options
    where a family declares them; ``families`` (names) restricts to those families;
    ``linear`` False leaves the linear families out (fits that iterate on every candidate:
    joint fits, several channels; docs/nonparametric.md). Values that make the same model
    with the apparatus options given are one candidate (``Candidate.same``)."""
    given = dict(given_options or {})
    pinned = {k: v for k, v in given.items() if k not in registry.APPARATUS_OPTIONS}
    found = _one_per_model(
        [
            Candidate(name, opts)
            for name, opts in registry.candidates(kind, pinned)
            if _constructible(name, opts)
        ],
        given,
    )
    # an option left with one value in a family (pinned, or the only one the model makes)
    # does not tell its candidates apart: out of their labels (model_options still sets it)
    out = []
    for c in found:
        same = [c2 for c2 in found if c2.family == c.family]
        keep = {
            k: v
            for k, v in c.options.items()
            if any(c2.options.get(k) != v for c2 in same)  # tells them apart
            or (v != _default(c.family, k) and k not in pinned)
        }  # nothing else sets it
        out.append(Candidate(c.family, keep, c.same))
    found = out
    if families is not None:
        wanted = [registry.model_class(f, kind).NAME for f in families]
        found = [c for c in found if c.family in wanted]
    if not linear:
        found = [c for c in found if not registry.REGISTRY[c.family].LINEAR]
    return found


def _one_per_model(found: list, given: dict) -> list:
    """``found`` with the candidates that make the same model as an earlier one (its
    family's ``same_model`` of every option, the ``given`` apparatus ones included) folded
    into it: the one whose options are that model's own spelling is kept."""
    groups: dict = {}
    for c in found:
        cls = registry.REGISTRY[c.family]
        full = {**cls.default_options(), **c.model_options(given)}
        key = (c.family, tuple(sorted(cls.same_model(full).items())))
        groups.setdefault(key, []).append((c, full == cls.same_model(full)))
    out = []
    for members in groups.values():
        keep = next((c for c, own in members if own), members[0][0])
        others = tuple(dict(c.options) for c, _ in members if c is not keep)
        out.append(Candidate(keep.family, keep.options, others))
    return out


def _default(name: str, option: str):
    return next(o.default for o in registry.REGISTRY[name].OPTIONS if o.name == option)


def _constructible(name: str, options: dict) -> bool:
    """Whether the family makes a model with these option values (a declared value the
    model refuses, such as rough-plastic's nonlinear = True, is no candidate)."""
    from ..errors import InputError

    try:
        registry.REGISTRY[name].template(**options)
    except (InputError, ValueError):
        return False
    return True


def parse_models(text) -> str | tuple[str, str]:
    """``--models`` / ``models=``: "auto", "paper" or ("brdf family", "medium family") from
    "FAMILY+MEDIUM"; an InputError listing the registered families otherwise."""
    from ..errors import InputError

    if text is None:
        return registry.PAPER
    if isinstance(text, tuple):
        text = "+".join(text)
    word = str(text).strip().lower()
    if word in MODES:
        return word
    brdf, plus, medium = word.partition("+")
    if not plus:
        raise InputError(
            f"models {text!r}: expected auto, paper or FAMILY+MEDIUM; BRDF "
            f"families: {', '.join(registry.names('brdf'))}; media: "
            f"{', '.join(registry.names('medium'))}"
        )
    return (
        registry.model_class(brdf.strip(), "brdf").NAME,
        registry.model_class(medium.strip(), "medium").NAME,
    )


# --------------------------------------------------------------------------------------
# fitting the candidates
# --------------------------------------------------------------------------------------
def workers(n: int) -> int:
    """Threads for ``n`` candidates: ``VEIL_CANDIDATE_THREADS`` or the cores, at most n."""
    env = os.environ.get("VEIL_CANDIDATE_THREADS", "").strip()
    try:
        most = int(env) if env else (os.cpu_count() or 1)
    except ValueError:
        raise FitError(f"VEIL_CANDIDATE_THREADS = {env!r}; expected a whole number") from None
    return max(1, min(n, most))


def teller(step: str, total: int, progress, what: str = "") -> Callable[[str, str], None]:
    """``tell(label, outcome)`` for :func:`fit_candidates`: ``progress(text, done, total)``
    with the count of candidates done (``what`` names the kind of fit)."""
    count = {"done": 0}

    def tell(label, outcome):
        count["done"] += 1
        if progress is not None:
            progress(f"{step}: {label} {what}{outcome}", count["done"], total)

    return tell


def fit_candidates(fit, cands, progress=None) -> dict:
    """{label: (FitResult or the exception it raised, seconds)}: ``fit(candidate)`` for every
    candidate, in threads (:func:`workers`); ``progress(label, what)`` is serialized."""
    lock = threading.Lock()
    out = {}

    def one(c):
        t0 = time.perf_counter()
        try:
            result = fit(c)
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as exc:  # a failing candidate is reported, not fatal
            result = exc
        seconds = time.perf_counter() - t0
        if progress is not None:
            with lock:
                progress(c.label, "failed" if isinstance(result, Exception) else "done")
        return c.label, result, seconds

    n = workers(len(cands))
    with warnings.catch_warnings():
        # a poor candidate misses the data by many sigma by design: the pipeline warns for
        # the chosen one only (veil.fitting.steps.warn_misfit)
        warnings.simplefilter("ignore", MisfitWarning)
        if n == 1:
            done = [one(c) for c in cands]
        else:
            with ThreadPoolExecutor(max_workers=n, thread_name_prefix="veil-candidate") as pool:
                done = list(pool.map(one, cands))
    for label, result, seconds in done:
        out[label] = (result, seconds)
    return out


# --------------------------------------------------------------------------------------
# ranking
# --------------------------------------------------------------------------------------
def deviance(result: FitResult, data) -> tuple[float, int]:
    """(-2 ln L up to a constant, number of parameters of the discrepancy term) of a fit to
    ``data`` (:class:`veil.fitting.FitData`), the module docstring's likelihood."""
    r = np.asarray(result.residuals, dtype=float)
    n = r.size
    if not result.weighted or data.sigma is None:
        rss = float(r @ r)
        return n * math.log(max(rss / max(n, 1), 1e-300)), 0
    term = result.model_error
    if term is None or term.sigma <= 0:
        return float(r @ r), 0
    f = data.y - r * data.sigma
    a = f / data.sigma
    t = term.sigma**2
    if term.length <= 0:
        nll = _nll_independent(r, a, t)
    else:
        corr = correlation(distances(data.angles), term.length)
        nll = _nll_spectrum(_spectrum(r, a, corr), t)
    extra = 0
    if term.source == "own residuals":
        extra = 1 + (term.length > 0)
    return 2.0 * nll, extra


@dataclass(frozen=True)
class Ranking:
    """One step's candidates, best first (``rows``: dicts with label, family, options,
    chi2, deviance, rms_relative, n_points, k, aic, bic, delta_bic, weight, converged,
    error, seconds (the fit's wall time: in the terminal's table, not in :meth:`to_dict`),
    same: the labels it stands for, ``Candidate.same``; a screened-out one
    also screened and note, :mod:`veil.fitting.screening`); ``chosen`` the best label (None
    when every candidate failed); ``close`` the labels within :data:`CLOSE_DELTA_BIC` of it
    (itself included);
    ``spread`` the close call's curve spread (:func:`curve_spread`) or None."""

    step: str
    rows: list
    chosen: str | None
    close: list
    spread: dict | None = None
    #: the data it was ranked on when not the step's own (step 2 on the target's clear data)
    on: str | None = None

    @property
    def close_call(self) -> bool:
        return len(self.close) > 1

    def row(self, label: str) -> dict:
        return next(r for r in self.rows if r["label"] == label)

    def to_dict(self) -> dict:
        def clean(v):
            if isinstance(v, float) and not math.isfinite(v):
                return None
            return v

        return {
            "step": self.step,
            "criterion": "BIC with the model-discrepancy term",
            "chosen": self.chosen,
            "close_call": self.close_call,
            "close": list(self.close),
            "close_delta_bic": CLOSE_DELTA_BIC,
            # the written record is the same run after run: no candidate's wall time
            "candidates": [
                {k: clean(v) for k, v in r.items() if k != "seconds"} for r in self.rows
            ],
            "spread": self.spread,
            "ranked_on": self.on,
        }

    def with_spread(self, spread: dict | None) -> Ranking:
        return dataclasses.replace(self, spread=spread)


def rank(step: str, fitted: dict, data, cands=None, screened=()) -> Ranking:
    """Rank ``fitted`` ({label: (FitResult or exception, seconds)}) on ``data`` (the
    FitData the fits saw). ``screened``: rows of candidates screened out
    (:mod:`veil.fitting.screening`), listed after the ranked ones with their dBIC, weight 0.
    Failed and unconverged candidates are listed last, unranked."""
    by_label = {c.label: c for c in (cands or [])}
    rows = []
    for label, (result, seconds) in fitted.items():
        cand = by_label.get(label)
        row = {
            "label": label,
            "family": cand.family if cand else None,
            "options": dict(cand.options) if cand else {},
            "chi2": None,
            "deviance": None,
            "rms_relative": None,
            "n_points": None,
            "k": None,
            "aic": None,
            "bic": None,
            "delta_bic": None,
            "weight": 0.0,
            "converged": False,
            "error": None,
            "seconds": round(seconds, 3),
            "same": [Candidate(cand.family, o).label for o in cand.same] if cand else [],
        }
        if isinstance(result, Exception):
            row["error"] = f"{type(result).__name__}: {result}"
        else:
            res = np.asarray(result.residuals, dtype=float)
            dev, extra = deviance(result, data)
            n, k = res.size, result.dof + extra
            row.update(
                family=result.model,
                options=dict(result.options) if cand is None else row["options"],
                chi2=float(res @ res),
                deviance=dev,
                rms_relative=float(result.rms_relative),
                n_points=n,
                k=k,
                aic=dev + 2 * k,
                bic=dev + k * math.log(max(n, 1)),
                converged=bool(result.converged),
            )
            if not result.converged:
                said = result.message or ""
                row["error"] = (
                    said if said.startswith("did not converge") else f"did not converge: {said}"
                )
            elif not math.isfinite(dev):
                row["error"] = "the likelihood is not finite"
        rows.append(row)
    ranked = [r for r in rows if r["error"] is None]
    if ranked:
        best = min(r["bic"] for r in ranked)
        weights = [math.exp(-0.5 * (r["bic"] - best)) for r in ranked]
        total = sum(weights)
        for r, w in zip(ranked, weights):
            r["delta_bic"] = r["bic"] - best
            r["weight"] = w / total
    ranked.sort(key=lambda r: r["bic"])
    others = [r for r in rows if r["error"] is not None]
    chosen = ranked[0]["label"] if ranked else None
    close = [r["label"] for r in ranked if r["delta_bic"] <= CLOSE_DELTA_BIC]
    out = [dict(r, delta_bic=r["bic"] - ranked[0]["bic"] if ranked else None) for r in screened]
    return Ranking(step, ranked + out + others, chosen, close)


def with_selection(result: FitResult, ranking: Ranking) -> FitResult:
    """``result`` with its step's ranking in ``stats["selection"]``."""
    return dataclasses.replace(result, stats={**result.stats, "selection": ranking.to_dict()})


def curve_spread(ranking: Ranking, curves: dict) -> dict | None:
    """The close call's spread: ``curves`` {label: values at common configurations} of at
    least the close candidates; their weights renormalized over them; returns
    {"labels", "spread": per-configuration weighted standard deviation, "mean",
    "rms_relative", "max_relative"} (relative to the chosen candidate's curve), or None
    without a close call."""
    if not ranking.close_call:
        return None
    labels = [lab for lab in ranking.close if lab in curves]
    w = np.array([ranking.row(lab)["weight"] for lab in labels])
    w = w / w.sum()
    f = np.array([np.asarray(curves[lab], dtype=float) for lab in labels])
    mean = w @ f
    spread = np.sqrt(np.maximum(w @ (f - mean) ** 2, 0.0))
    ref = np.abs(np.asarray(curves[ranking.chosen], dtype=float))
    rel = spread / np.where(ref > 0, ref, np.inf)
    return {
        "labels": labels,
        "weights": [float(v) for v in w],
        "spread": [float(v) for v in spread],
        "mean": [float(v) for v in mean],
        "rms_relative": float(np.sqrt(np.mean(rel**2))),
        "max_relative": float(np.max(rel)),
    }


def table_lines(ranking: Ranking, markdown: bool = False) -> list[str]:
    """The ranking as a table (text or markdown): chi-square, RMS residual, AIC, BIC,
    delta-BIC, weight, converged, one candidate a line, best first; the text adds each
    fit's wall time (the markdown goes into report.md, which is the same run after run)."""

    def num(v, fmt):
        return (
            "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)
        )

    head: tuple[str, ...] = (
        "candidate",
        "chi2",
        "RMS resid. %",
        "AIC",
        "BIC",
        "dBIC",
        "weight",
        "converged",
    )
    body: list[tuple[str, ...]] = []
    for r in ranking.rows:
        mark = "*" if r["label"] == ranking.chosen else ""
        rms = None if r["rms_relative"] is None else 100 * r["rms_relative"]
        body.append(
            (
                r["label"] + mark,
                num(r["chi2"], ".4g"),
                num(rms, ".3g"),
                num(r["aic"], ".2f"),
                num(r["bic"], ".2f"),
                num(r["delta_bic"], ".2f"),
                num(r["weight"], ".3f"),
                "screened"
                if r.get("screened")
                else ("yes" if r["converged"] else ("failed" if r["chi2"] is None else "no")),
            )
        )
    notes = [
        f"  {r['label']}: {r['error'] or r.get('note')}"
        for r in ranking.rows
        if r["error"] or r.get("note")
    ]
    notes += [
        f"  {r['label']}: the same model as {', '.join(r['same'])} with the options given; "
        "fitted once"
        for r in ranking.rows
        if r.get("same")
    ]
    if not markdown:
        head += ("s",)
        body = [b + (num(r.get("seconds"), ".1f"),) for b, r in zip(body, ranking.rows)]
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(b) + " |" for b in body]
        lines += [""] + [f"- {n.strip()}" for n in notes] if notes else []
    else:
        widths = [max(len(x[i]) for x in [head] + body) for i in range(len(head))]
        lines = [
            "  ".join(x.ljust(w) for x, w in zip(row, widths)).rstrip() for row in [head] + body
        ]
        lines += notes
    lines += close_call_lines(ranking)
    return lines


def close_call_lines(ranking: Ranking) -> list[str]:
    """A sentence for a close call (none otherwise), and one when every candidate failed."""
    if ranking.chosen is None:
        return ["every candidate failed: nothing was chosen"]
    if not ranking.close_call:
        return []
    others = [lab for lab in ranking.close if lab != ranking.chosen]
    text = (
        f"close call: {', '.join(others)} within delta-BIC {CLOSE_DELTA_BIC:g} of "
        f"{ranking.chosen}; the data do not decide between them"
    )
    if ranking.spread is not None:
        text += (
            f"; the curves' uncertainty is widened by their BIC-weighted spread "
            f"({100 * ranking.spread['rms_relative']:.3g} % RMS, "
            f"{100 * ranking.spread['max_relative']:.3g} % at most)"
        )
    return [text]


__all__ = [
    "CLOSE_DELTA_BIC",
    "MODES",
    "NoCandidateError",
    "Candidate",
    "candidates",
    "parse_models",
    "workers",
    "teller",
    "fit_candidates",
    "deviance",
    "Ranking",
    "rank",
    "curve_spread",
    "table_lines",
    "close_call_lines",
]
