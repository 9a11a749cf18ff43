"""What `veil explore` shows of a fit (docs/explore.md): a result checked for its kind, the
models it holds, and :class:`FitView` - its data, the model's curves through them with an
uncertainty band, and the residuals."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from .explore import LIVE_ACCURACY, State

if TYPE_CHECKING:
    from ..fitting.result import FitResult

#: Parameter draws of the uncertainty band, and the band's quantiles (a 95 % band).
BAND_DRAWS = 24
BAND_QUANTILES = (2.5, 97.5)
#: Largest |recomputed - stored| of the residuals, relative to their rms (plus an absolute
#: 1e-6), for a table to count as the fit's data.
RESIDUAL_TOLERANCE = 0.02


def check_result_kind(result, source: str) -> FitResult:
    """The result if ``veil explore`` can show it: a step fit (reference, medium or target);
    an InputError saying what the file is otherwise."""
    from ..fitting.result import JointResult

    if isinstance(result, JointResult):
        raise InputError(
            f"{source} is a joint fit result; veil explore shows step results "
            f"('veil fit reference', 'veil fit medium', 'veil fit target')"
        )
    if result.kind == "medium" and result.given is None:
        raise InputError(
            f"{source}: a medium fit result that does not name its reference "
            f"object; veil explore needs both models"
        )
    return result


def ranking_lines(result) -> list[str]:
    """The candidates a fit with ``--brdf-model auto`` / ``--models auto`` was chosen from
    (its ``stats["selection"]``, :mod:`veil.fitting.selection`) as a compact Markdown table,
    best first, the chosen one marked; [] for a fit without a ranking."""
    ranking = (getattr(result, "stats", None) or {}).get("selection")
    if not ranking or not ranking.get("candidates"):
        return []

    def num(v, fmt):
        return "-" if v is None else format(v, fmt)

    lines = [
        "",
        f"**Chosen from {len(ranking['candidates'])} candidates** (BIC, * chosen)",
        "",
        "| candidate | RMS % | dBIC | weight |",
        "|---|---:|---:|---:|",
    ]
    for row in ranking["candidates"]:
        mark = "*" if row["label"] == ranking.get("chosen") else ""
        rms = None if row.get("rms_relative") is None else 100 * row["rms_relative"]
        if row.get("screened"):
            state = " (screened out)"
        elif row.get("converged"):
            state = ""
        else:
            state = " (failed)" if row.get("chi2") is None else " (not converged)"
        lines.append(
            f"| {row['label']}{mark}{state} | {num(rms, '.3g')} | "
            f"{num(row.get('delta_bic'), '.1f')} | {num(row.get('weight'), '.3f')} |"
        )
    if ranking.get("close_call"):
        lines += [
            "",
            f"Close call: {', '.join(ranking['close'])} within dBIC "
            f"{ranking['close_delta_bic']:g}.",
        ]
    return lines


def result_channels(results, sources) -> tuple:
    """The channels of results fitted over several (docs/channels.md), the same in each
    such result; () when every result is of one channel."""
    found = [(s, tuple(getattr(r, "channel_names", ()) or ())) for r, s in zip(results, sources)]
    found = [(s, c) for s, c in found if c]
    for s, c in found[1:]:
        if sorted(c) != sorted(found[0][1]):
            raise InputError(
                f"{found[0][0]} is a fit of channels {', '.join(found[0][1])} and "
                f"{s} of channels {', '.join(c)}: give results of the same "
                f"channels"
            )
    return found[0][1] if found else ()


def models_of(results, sources, channel: str | None = None) -> tuple:
    """(brdf, medium) of fit results: each result sets the model of its kind, the models
    it held fixed fill in the rest (the first result's first); of ``channel`` for results
    fitted over several channels (a result of one channel is every channel's)."""
    brdf = medium = None
    given_b = given_m = None
    clear = False
    for result, source in zip(results, sources):
        check_result_kind(result, source)
        several = bool(getattr(result, "channel_names", ()))
        model = result.as_model(channel=channel) if several else result.as_model()
        given = result.given_model(channel)
        if model.KIND == "brdf":
            if brdf is not None:
                raise InputError(
                    f"{source}: a second BRDF fit result; give at most one result "
                    f"per kind (a BRDF fit and a medium fit)"
                )
            brdf = model
            if result.step == "reference" and given is None:
                clear = True
            if given is not None and given_m is None:
                given_m = given
        else:
            if medium is not None:
                raise InputError(
                    f"{source}: a second medium fit result; give at most one "
                    f"result per kind (a BRDF fit and a medium fit)"
                )
            medium = model
            if given is not None and given_b is None:
                given_b = given
    brdf = brdf or given_b
    medium = medium or given_m
    if brdf is None:
        brdf = State.default().brdf
    if medium is None and not clear:
        medium = State.default().medium
    return brdf, medium


class FitView:
    """A fit result with its measurement table: what the fit's data panel draws.

    The table must be the fit's own: as many points as the fit used, and the residuals
    recomputed at the fitted parameters equal to the ones the result stores
    (:data:`RESIDUAL_TOLERANCE`); otherwise an InputError says it does not belong."""

    def __init__(
        self,
        result,
        table,
        black=None,
        source: str = "the result",
        table_name: str = "the table",
        draws: int = BAND_DRAWS,
        seed: int = 20110901,
    ):
        from ..fitting.session_data import prepare

        self.result, self.source = result, source
        check_result_kind(result, source)
        self.data = prepare(table, black, what=f"{table_name}")
        model, given = result.one_model(), result.given_model()
        if model.KIND == "brdf":
            self.brdf, self.medium = model, given
        else:
            self.brdf, self.medium = given, model
        if given is None and result.step != "reference":
            raise InputError(f"{source}: the result does not name the model it held fixed")
        if self.data.size != result.n_points:
            raise InputError(
                f"{table_name} does not belong to {source}: it has "
                f"{self.data.size} points, the fit used {result.n_points} (give "
                f"the fit's own table{' and black cloth' if black is None else ''})"
            )
        ti, pi_, tr, pr = self.data.angles
        self.x, self.group, self.xlabel, self.group_label = _data_axes(*self.data.angles)
        self.order = np.lexsort((self.x, self.group))
        self.fitted = self.model_values(self.brdf, self.medium, result.accuracy or "default")
        resid = (self.data.y - self.fitted) * (self.data.w if result.weighted else 1.0)
        stored = np.asarray(result.residuals, dtype=float)
        if stored.shape == resid.shape:
            scale = float(np.sqrt(np.mean(stored**2))) if stored.size else 0.0
            gap = float(np.max(np.abs(resid - stored))) if stored.size else 0.0
            if gap > RESIDUAL_TOLERANCE * scale + 1e-6 * (1.0 + float(np.max(np.abs(self.data.y)))):
                raise InputError(
                    f"{table_name} does not belong to {source}: the fitted model "
                    f"misses its points by residuals up to {gap:.3g} where the fit "
                    f"reported rms {scale:.3g} (another session's table, or a "
                    f"black cloth missing or different)"
                )
        self.residuals = resid
        self.band = self._band(draws, seed)

    # -- engine ----------------------------------------------------------------------------
    def model_values(self, brdf, medium, accuracy: str = LIVE_ACCURACY) -> np.ndarray:
        from ..engine.evaluator import evaluate

        ti, pi_, tr, pr = self.data.angles
        return np.asarray(evaluate(brdf, medium, ti, pi_, tr, pr, accuracy=accuracy), dtype=float)

    def _band(self, draws: int, seed: int):
        """(low, high) of the model over parameters drawn from the fit's covariance (normal
        in the declared fit coordinates: log for log_scale parameters), or None when the
        fit reports no covariance."""
        found = self.result.covariance(total=True)
        if found is None or draws <= 0:
            return None
        names, cov = found
        cls = self.result.model_class
        mean = np.array([self.result.params[n] for n in names], dtype=float)
        logs = np.array([cls.param(n).log_scale and mean[k] > 0 for k, n in enumerate(names)])
        # covariance of log values to first order: divide by the values
        jac = np.where(logs, 1.0 / np.where(logs, mean, 1.0), 1.0)
        cov_u = cov * np.outer(jac, jac)
        mean_u = np.where(logs, np.log(np.where(logs, mean, 1.0)), mean)
        rng = np.random.default_rng(seed)
        try:
            root = np.linalg.cholesky(cov_u + 1e-300 * np.eye(len(names)))
        except np.linalg.LinAlgError:
            w, v = np.linalg.eigh(cov_u)
            root = v * np.sqrt(np.clip(w, 0.0, None))
        base = self.result.one_model()
        accepted: list = []
        tries = 0
        while len(accepted) < draws and tries < 20 * draws:
            tries += 1
            u = mean_u + root @ rng.standard_normal(len(names))
            x = np.where(logs, np.exp(u), u)
            if cls.LINEAR:  # a coefficient drawn below 0 is held at 0, as its fit holds it
                x = np.maximum(x, 0.0)
            if all(cls.param(n).contains(float(v)) for n, v in zip(names, x)):
                accepted.append(x)
        if len(accepted) < 2:
            return None
        if cls.LINEAR:
            curves = self._linear_curves(base, names, np.array(accepted))
        else:
            curves = np.array([self.model_values(*self._with(base, names, x)) for x in accepted])
        lo, hi = np.percentile(curves, BAND_QUANTILES, axis=0)
        return lo, hi

    def _with(self, base, names, x) -> tuple:
        """(BRDF, medium) with the fitted model's ``names`` at values ``x``."""
        params = dict(base.as_dict())
        params.update({n: float(v) for n, v in zip(names, x)})
        model = type(base).from_params(params, base.options())
        return (model, self.medium) if model.KIND == "brdf" else (self.brdf, model)

    def _linear_curves(self, base, names, xs) -> np.ndarray:
        """A linear family's curves at coefficient draws ``xs`` (K, len(names)): each curve
        the sum of its coefficients times their columns (the column model's values of one
        basis function, as the fit's design; docs/nonparametric.md), so the engine runs
        once per coefficient drawn or held at a non-zero value, not once per draw."""
        column_cls, vectors = type(base).columns()
        template = column_cls.template()

        def column(name: str) -> np.ndarray:
            basis = template.replace(**dict(zip(column_cls.param_names(), vectors[name])))
            return self.model_values(basis, self.medium)

        held = np.zeros(self.data.size)
        for name, value in base.as_dict().items():
            if name not in names and value != 0.0:
                held = held + value * column(name)
        drawn = np.stack([column(n) for n in names], axis=1)
        return held[None, :] + np.asarray(xs, dtype=float) @ drawn.T

    def param_rows(self) -> list[dict]:
        """One row per parameter: name, value, stderr (None when fixed or undetermined)."""
        se = self.result.stderr_total or self.result.stderr
        return [
            {
                "parameter": n,
                "value": float(v),
                "stderr": None if n in self.result.fixed else se.get(n),
                "fixed": n in self.result.fixed,
            }
            for n, v in self.result.params.items()
        ]


def _data_axes(ti, pi_, tr, pr):
    """(x, group, x name, group name) of measurements: rho within psi groups for in-plane
    data (the paper's protocol), theta_r within theta_i groups otherwise."""
    from ..engine.angles import to_goniometer, to_signed_inplane

    try:
        sti, stw = to_signed_inplane(ti, pi_, tr, pr)
    except InputError:
        return np.asarray(tr, float), np.round(np.asarray(ti, float), 3), "theta_r (deg)", "theta_i"
    psi, rho = to_goniometer(sti, stw)
    return rho, np.round(psi, 3), "rho (deg)", "psi"


__all__ = [
    "BAND_DRAWS",
    "BAND_QUANTILES",
    "RESIDUAL_TOLERANCE",
    "check_result_kind",
    "models_of",
    "ranking_lines",
    "FitView",
]
