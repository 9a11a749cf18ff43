"""``fit_joint`` with the data choosing the model (issue 29; docs/choosing-models.md):
``--brdf-model auto`` and/or ``--medium-model auto`` of ``veil fit joint``.

Every candidate of the ranked kinds (:func:`veil.fitting.selection.candidates`; both
ranked: every pair) is one joint fit of all the sessions, screened first by its quick fit
(:mod:`veil.fitting.screening`), and ranked by BIC with the model-discrepancy term on the
stacked data of the joint problem (every session's points in the problem's row order).
A fixed, shared or per-medium name applies to the candidates whose families declare it;
one that no candidate declares is an error.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from ..errors import FitError
from ..models import model_class
from . import screening, selection
from .joint import fit_joint
from .joint_problem import build
from .result import FitResult, JointResult
from .session_data import FitData


@dataclass(frozen=True)
class JointCandidate:
    """One pair of a joint fit's families: the target's (and reference's) ``brdf`` and the
    ``medium``, each a :class:`veil.fitting.selection.Candidate`."""

    brdf: selection.Candidate
    medium: selection.Candidate

    @property
    def label(self) -> str:
        return f"{self.brdf.label} + {self.medium.label}"

    @property
    def family(self) -> str:
        return f"{self.brdf.family}+{self.medium.family}"

    @property
    def options(self) -> dict:
        return {**self.brdf.options, **self.medium.options}

    @property
    def same(self) -> tuple:
        return ()


def joint_candidates(
    ranked, brdf_model, medium_model, brdf_options, medium_options
) -> list[JointCandidate]:
    """The pairs to fit: every candidate of each kind in ``ranked`` ("brdf", "medium"), the
    named family (None: the paper's) of the other."""

    def of(kind, name, options):
        if kind in ranked:  # a linear family is not fitted jointly (docs/nonparametric.md)
            return selection.candidates(kind, options, linear=False)
        return [selection.Candidate(model_class(name or _paper(kind), kind).NAME)]

    brdfs = of("brdf", brdf_model, brdf_options)
    media = of("medium", medium_model, medium_options)
    return [JointCandidate(b, m) for b in brdfs for m in media]


def _paper(kind: str) -> str:
    from ..models import default_class

    return default_class(kind).NAME


def _base(name: str) -> str:
    """A joint fit's parameter name without its object prefix and its medium or channel
    subscripts: "ref.eta" -> "eta", "Td[low][r]" -> "Td"."""
    return re.sub(r"\[.*$", "", name.removeprefix("ref."))


def _declared(c: JointCandidate) -> set:
    """The parameter names a joint fit of the pair takes: each family's own and its slots'
    (the paper's medium's ``eta`` is ``eta_u`` there)."""
    out: set = set()
    for cls in (model_class(c.brdf.family), model_class(c.medium.family)):
        out |= set(cls.param_names()) | set(cls.keys())
    return out


def per_candidate(cands, names, what: str) -> dict:
    """{label: the entries of ``names`` (a dict or a list) its families declare}; one that no
    candidate declares is a FitError."""
    if not names:
        return {c.label: names for c in cands}
    out, used = {}, set()
    for c in cands:
        mine = [n for n in names if _base(n) in _declared(c)]
        used.update(mine)
        out[c.label] = {n: names[n] for n in mine} if isinstance(names, dict) else mine
    unused = [n for n in names if n not in used]
    if unused:
        raise FitError(f"{what} {', '.join(unused)}: no candidate model has such a parameter")
    return out


def ranking_data(sessions, **build_kw) -> FitData:
    """The stacked data every candidate's joint fit is ranked on: the joint problem's
    values, sigma and angles in its row order (the same for every family pair)."""
    problem, _ = build(sessions, **build_kw)
    sigma = 1.0 / problem.w if problem.weighted else None
    return FitData(problem.angles, problem.y, sigma, table=None)


def fit_joint_ranked(
    sessions,
    ranked,
    *,
    brdf_model=None,
    medium_model=None,
    brdf_options=None,
    medium_options=None,
    fixed=None,
    free=None,
    shared=None,
    per_medium=None,
    progress=None,
    **fit_kw: Any,
) -> tuple[FitResult, selection.Ranking]:
    """:func:`veil.fitting.joint.fit_joint` of every candidate (module docstring), ranked:
    (the chosen one's result, its ranking in ``stats["selection"]``; the ranking). A
    :class:`veil.fitting.selection.NoCandidateError` when every candidate failed."""
    brdf_options, medium_options = dict(brdf_options or {}), dict(medium_options or {})
    cands = joint_candidates(ranked, brdf_model, medium_model, brdf_options, medium_options)
    entries = {
        "fixed": per_candidate(cands, fixed, "fixed"),
        "free": per_candidate(cands, free, "free"),
        "shared": per_candidate(cands, shared, "shared"),
        "per_medium": per_candidate(cands, per_medium, "per-medium"),
    }
    reference, channel = fit_kw.get("reference"), fit_kw.get("channel")
    if channel is not None and isinstance(reference, FitResult) and reference.channels:
        reference = reference.one_model(channel)  # as fit_joint holds it
    data = None
    for c in cands:  # the stacked data, from the first pair whose problem builds
        try:
            data = ranking_data(
                sessions,
                reference=reference,
                brdf_model=c.brdf.family,
                medium_model=c.medium.family,
                brdf_options=c.brdf.model_options(brdf_options),
                medium_options=c.medium.model_options(medium_options),
                channel=channel,
                **{k: v[c.label] for k, v in entries.items()},
            )
            break
        except FitError:
            if c is cands[-1]:
                raise

    def one(c: JointCandidate, screen: bool = False, start=None) -> FitResult:
        # from ``start``, a joint fit of the family pair (its own quick fit, or a sibling's:
        # veil.fitting.screening), when given; else from the grid (and fit_kw's start)
        kw = dict(fit_kw, start=start) if isinstance(start, JointResult) else fit_kw
        return fit_joint(
            sessions,
            brdf_model=c.brdf.family,
            medium_model=c.medium.family,
            brdf_options=c.brdf.model_options(brdf_options),
            medium_options=c.medium.model_options(medium_options),
            screen=screen,
            **{k: v[c.label] for k, v in entries.items()},
            **kw,
        )

    ranking, results = screening.select(
        "joint", cands, data, one, "joint", progress, lambda c, start=None: one(c, True, start)
    )
    return selection.with_selection(results[ranking.chosen], ranking), ranking


__all__ = ["JointCandidate", "joint_candidates", "per_candidate", "fit_joint_ranked"]
