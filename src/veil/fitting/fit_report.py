"""The text report of a fit result (like lmfit's; :meth:`veil.fitting.result.FitResult.report`):
one layout for a step fit and a joint fit - a header, the statistics, the sessions of a joint
fit, the variables with their standard errors, and the strongest correlations."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, cast

from ..numbers import format_number
from .propagation import RELATIVE_LIMIT

if TYPE_CHECKING:  # the results import this module to write their report, not this them
    from ..models import Medium
    from .result import FitResult, JointResult

#: What each step of docs/model.md sec. 7 estimates, for the report's header.
STEP_WORDS = {
    "reference": "step 0, reference object in a clear medium (f_r directly)",
    "medium": "step 1, medium through the reference object (f_r fixed)",
    "target": "step 2, target object through the medium (f_t fixed)",
    "direct": "target object in a clear medium (f_r directly)",
}


def _layout(result: FitResult) -> dict:
    """The layout of a joint fit's result (``result.JOINT``)."""
    return cast("JointResult", result).layout


def _header(result: FitResult) -> str:
    if result.JOINT:
        models = _layout(result).get("models") or {}
        family = f", models {models['brdf']} / {models['medium']}" if models else ""
        variant = f", variant {result.variant}" if result.variant else ""
        # a fit over channels lists each session once per channel
        per = len(result.channels or ()) or 1
        sessions = len(_layout(result).get("sessions", [])) // per
        channels = f" in {per} channels" if result.channels else ""
        return (
            f"[[Joint fit: {sessions} sessions{channels}, "
            f"{len(cast('JointResult', result).media_labels)} media{variant}{family}]]"
        )
    what = STEP_WORDS.get(result.step or "", "")
    opts = ", ".join(f"{k} {v}" for k, v in result.options.items())
    return (
        f"[[Fit: {result.model}"
        + (f", variant {result.variant}" if result.variant else "")
        + (f" ({opts})" if opts and not result.variant else "")
        + (f" - {what}" if what else "")
        + "]]"
    )


def _tied(result: FitResult) -> list[str]:
    """The names a fit over several channels ties across them (of a joint fit, every
    object's and medium's), in the order of ``params``."""
    channels = result.channels or {}
    if result.JOINT:
        by_channel = _layout(result)["channels"]
        names = {
            c: {n for part in ("objects", "media") for m in maps[part].values() for n in m.values()}
            for c, maps in by_channel.items()
        }
    else:
        names = {c: set(m.values()) for c, m in channels.items()}
    return [n for n in result.params if all(n in own for own in names.values())]


def _over_starts(starts: int) -> str:
    """The end of a fit's evaluations line: over N starts, or from 1 start."""
    return " from 1 start" if starts == 1 else f" over {starts} starts"


def _evaluations(stats: dict, fixed: dict) -> str:
    """A linear fit's engine calls for its columns (``stats["columns_at_rule"]``: the columns
    made at each rule; each nonzero ``fixed`` coefficient's part made once at each rule;
    the given fit's propagation makes calls of its own, not counted here)."""
    rules = stats.get("columns_at_rule")
    if not isinstance(rules, dict) or not rules:  # (a file written before that key)
        return f"{stats['columns']} columns, one engine call each"
    part = sum(1 for v in fixed.values() if v != 0.0)
    calls = sum(rules.values()) + part * len(rules)
    (first, n), *rest = rules.items()
    text = f"{calls} engine calls for the columns: {n} at the {first!r} rule" + "".join(
        f", {m} again at {rule!r}" for rule, m in rest
    )
    if part:
        each = " at each rule" if rest else ""
        text += f", {part} for the fixed coefficients' part{each}"
    return text


def _free(result: FitResult) -> list[str]:
    """The free parameters' line, naming those the user fixed; a linear fit's coefficients
    the solve holds at 0 on a line of their own (a count, not 40 names)."""
    fixed = [n for n in result.fixed if n not in result.at_bound]
    lines = [
        f"    free parameters    = {len(result.free)}"
        + (
            f" ({result.dof:.1f} effective: a regularized linear fit)"
            if "effective_dof" in result.stats
            else ""
        )
        + (f"  (fixed: {', '.join(fixed)})" if fixed else "")
    ]
    if result.at_bound:
        lines.append(
            f"    at their bound     = {len(result.at_bound)} coefficients at 0, held there by "
            f"the non-negative solve"
        )
    return lines


def _statistics(result: FitResult) -> list[str]:
    lines = [
        f"    data points        = {result.n_points}"
        + (
            "  (weighted by sigma)"
            if result.weighted
            else "  (UNWEIGHTED: no sigma column; errors scaled by reduced chi-square)"
        ),
        *_free(result),
    ]
    if result.JOINT:
        shared = ", ".join(_layout(result).get("shared", [])) or "-"
        lines.append(f"    shared by the media = {shared}")
    if result.channels:
        tied = _tied(result)
        lines.append(
            f"    channels           = {', '.join(result.channels)} (one fit; tied "
            f"across them: {', '.join(dict.fromkeys(tied)) or '-'})"
        )
    lines += [
        f"    reduced chi-square = {format_number(result.chi2_reduced, 5)}",
        f"    rms relative resid = {format_number(100 * result.rms_relative, 4)} %",
    ]
    if result.aic is not None:
        lines.append(
            f"    AIC, BIC           = {format_number(result.aic, 6)}, "
            f"{format_number(result.bic, 6)}"
        )
    lines.append(
        f"    converged          = {'yes' if result.converged else 'NO'} ({result.message})"
    )
    if result.accuracy:
        lines.append(f"    accuracy           = {result.accuracy}")
    stats = result.stats
    if stats and "columns" in stats:
        lines.append(f"    evaluations        = {_evaluations(stats, result.fixed)}")
    elif stats and not result.JOINT:
        lines.append(
            f"    evaluations        = {stats.get('nfev', 0)} function, "
            f"{stats.get('njev', 0)} Jacobian"
            + (_over_starts(stats["starts"]) if stats.get("starts") else "")
        )
    how = (stats or {}).get("propagation")
    if how and result.stderr_total is not None:
        lines.append(
            "    propagation        = "
            + (
                "first order (linear)"
                if how.get("method") == "linear"
                else f"sigma points: {how.get('refits')} refits at {how.get('points')} points, "
                f"{how.get('converged')} converged"
            )
        )
    me = getattr(result, "model_error", None)
    if me is not None:
        lines.append(
            f"    model error        = {format_number(100 * me.sigma, 3)} % relative"
            + (f", correlation length {format_number(me.length, 3)} deg" if me.length else "")
            + f" ({me.source}; chi-square limit {format_number(me.chi2_threshold, 4)}; in the "
            f"standard errors)"
            if me.sigma > 0
            else f"    model error        = none (reduced chi-square <= "
            f"{format_number(me.chi2_threshold, 4)})"
        )
        if me.session_correlation is not None:
            lines.append(
                f"    shared with step 1 = {format_number(me.session_correlation, 3)} "
                f"(correlation of the two sessions' model errors)"
            )
    if result.given:
        gp = ", ".join(f"{k}={format_number(v)}" for k, v in result.given.get("params", {}).items())
        lines.append(f"    given (fixed) model = {result.given.get('model')}({gp})")
    return lines


def _sessions(result: FitResult) -> list[str]:
    if not result.JOINT:
        return []
    lines = ["[[Sessions]]"]
    for s in _layout(result).get("sessions", []):
        rms = s.get("rms_relative")
        lines.append(
            f"    {s['name']}: {s['n_points']} points, chi2/N "
            f"{format_number(s['chi2'], 4)}, rms rel "
            f"{format_number(None if rms is None else 100 * rms, 3)} %"
        )
    return lines


def _variables(result: FitResult) -> list[str]:
    lines = ["[[Variables]]"]
    width = max(len(n) for n in result.params)
    units = {}
    if not result.JOINT:
        units = {p.name: f" {p.unit}" if p.unit else "" for p in result.model_class.PARAMS}
    for name, v in result.params.items():
        unit = units.get(name, "")
        if name in result.fixed:
            how = "at its bound" if name in result.at_bound else "fixed"
            lines.append(f"    {name:<{width}}: {format_number(v)}{unit} ({how})")
            continue
        se = result.stderr.get(name)
        if se is None or not math.isfinite(se):
            lines.append(f"    {name:<{width}}: {format_number(v)}{unit} +/- (not determined)")
            continue
        rel = f" ({100 * se / abs(v):.2f}%)" if v != 0 else ""
        total = ""
        if result.stderr_total is not None and result.stderr_total.get(name) is not None:
            # a joint fit's total: the reference's and, where the propagation line says
            # sigma points, the media's beyond first order
            what = "total" if result.JOINT else "with the given model's uncertainty"
            total = f"; {what} +/- {format_number(result.stderr_total[name], 3)}"
        lines.append(
            f"    {name:<{width}}: {format_number(v)}{unit} +/- {format_number(se, 3)}{rel}{total}"
        )
    return lines


def _hints(result: FitResult) -> list[str]:
    """Advice on the design where a step-1 medium with an unscattered beam is left uncertain
    by more than RELATIVE_LIMIT of its scale (tau at optical depth 0.1 through a broad
    reference): a reference whose specular peak is narrower than the medium's forward lobe
    measures the unscattered beam e^{-2 tau} at its peak (docs/validity.md: tau within 1 %
    from 0.1 to 1.5 with one)."""
    if result.JOINT or result.step != "medium":
        return []
    cls = cast("type[Medium]", result.model_class)  # a medium: step 1 fits one
    if not cls.has("delta"):
        return []
    se = result.stderr_total or result.stderr
    # parameters measured against their value (the optical depth, what the unscattered
    # beam's e^{-2 tau} pins); one measured against its room to a bound (g near 1) is loose
    # there for other reasons
    # a fit over channels names a parameter per channel NAME[channel]: its family's NAME
    loose = [
        n
        for n, v in result.params.items()
        if n not in result.fixed
        and n in se
        and cls.param(n.partition("[")[0]).error_scale != "bound"
        and cls.param(n.partition("[")[0]).relative_error(v, se[n]) > RELATIVE_LIMIT
    ]
    if not loose:
        return []
    return [
        "[[Hint]]",
        f"    {', '.join(loose)} uncertain by more than {RELATIVE_LIMIT:g} of "
        f"{'its' if len(loose) == 1 else 'their'} scale: this reference does not show "
        f"the unscattered beam apart from the scattered light. A reference whose specular "
        f"peak is narrower than the medium's forward lobe (a glossy plate) measures it at "
        f"the peak and determines the medium (docs/validity.md).",
    ]


def fit_report(result: FitResult, min_correlation: float = 0.1) -> str:
    """The report of any fit result (module docstring); correlations of at least
    ``min_correlation`` (the 20 strongest of a joint fit); a hint on the design where a
    medium with an unscattered beam is left uncertain."""
    most = 20 if result.JOINT else None
    lines = [_header(result)] + _statistics(result) + _sessions(result) + _variables(result)
    lines += result.correlation_lines(min_correlation, most=most)
    lines += _hints(result)
    return "\n".join(lines)


__all__ = ["fit_report", "STEP_WORDS"]
