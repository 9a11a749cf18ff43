"""The whole estimation of MODEL.md sec. 7 in one call: steps 0-2, result files, figures, report.

:func:`run_pipeline` fits the reference's f_r in a clear medium (step 0), the medium through
the reference (step 1) and the target through the medium (step 2), and writes into ``outdir``
(as one transaction, :func:`veil.io.output_folder`: a rerun replaces these files together,
an interrupted or failed run leaves the folder as it was):

- ``reference.json``, ``medium.json``, ``target.json``: :class:`veil.fitting.FitResult` files;
- ``reference.png``, ``medium.png``, ``target.png``: data against the fitted curves, value
  against the signed reflection angle theta_r, one curve per psi (like the paper's figs.
  15-17);
- with ``target_clear``: ``target_direct.json`` (the target fitted directly, no medium),
  ``target_direct.png`` and a comparison of the estimated f_r with it;
- ``report.md``: the parameter tables and the comparison.

Formats and the meaning of the uncertainties: docs/fitting.md.
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass, field

import numpy as np

from .io import check_output_folder, output_folder, write_bytes_atomic, write_text_atomic
from .engine.angles import to_goniometer, to_signed_inplane
from .fitting.steps import (FitError, FitResult, fit_direct, fit_medium, fit_reference, fit_target,
                      model_values, prepare)
from .models import PRESETS, Model
from .data.protocol import protocol

#: Output files, by role.
FILES = {"reference": "reference.json", "medium": "medium.json", "target": "target.json",
         "direct": "target_direct.json", "report": "report.md",
         "reference_fig": "reference.png", "medium_fig": "medium.png",
         "target_fig": "target.png", "direct_fig": "target_direct.png"}
#: A curve gets a logarithmic axis when its peak exceeds its median by this factor.
LOG_RATIO = 30.0
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#6a3d9a", "#8c564b")
STEP_KEYS = ("reference", "medium", "target")


@dataclass(frozen=True)
class PipelineResult:
    """The three fits (and the direct fit of the target), the comparison and the files."""

    reference: FitResult
    medium: FitResult
    target: FitResult
    direct: FitResult | None = None
    comparison: dict | None = None
    files: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        fits = [self.reference, self.medium, self.target] + ([self.direct] if self.direct else [])
        return all(f.converged for f in fits)


def _check_fixed(fixed) -> dict:
    if fixed is None:
        return {}
    if not isinstance(fixed, dict) or set(fixed) - set(STEP_KEYS):
        raise FitError(f"fixed = {fixed!r}; expected a dict by step, e.g. "
                       f"{{'medium': {{'eta': 1.33}}, 'target': {{'eta': 1.5}}}} (steps "
                       f"{', '.join(STEP_KEYS)})")
    return fixed


def _same(a, b) -> bool:
    a, b = os.fspath(a), os.fspath(b)
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.abspath(a) == os.path.abspath(b)


def _inside(path, folder) -> bool:
    path, folder = os.path.abspath(os.fspath(path)), os.path.abspath(os.fspath(folder))
    return path.startswith(folder + os.sep)


def _check_outputs(outdir: str, inputs: dict) -> None:
    check_output_folder(outdir)
    for role, name in FILES.items():
        out = os.path.join(outdir, name)
        for what, inp in inputs.items():
            if isinstance(inp, (str, os.PathLike)) and _same(out, inp):
                raise FitError(f"input {what} ({os.fspath(inp)}) would be overwritten by the "
                               f"output {out}; veil never overwrites an input: choose another "
                               f"output directory")


def run_pipeline(reference_clear, reference_medium, target_medium, black=None, target_clear=None,
                 outdir="veil-fit", *, variant: str = "paper", accuracy: str = "default",
                 fixed=None, max_nfev=None, progress=None, truth=None,
                 figures: bool = True) -> PipelineResult:
    """Steps 0-2 of MODEL.md sec. 7 with files, figures and report.md in ``outdir``.

    reference_clear, reference_medium, target_medium : sessions (DataFrames or CSV paths):
        the reference in a clear medium, the reference in the medium, the target in the medium.
    black : black-cloth session in the medium, subtracted from both medium sessions.
    target_clear : optional target in a clear medium: fitted directly and compared with the
        estimate (parameter differences in units of their combined standard error, rms of
        the f_r difference over the protocol's configurations).
    fixed : parameters held per step, e.g. ``{"medium": {"eta": 1.33}}``; the target's also
        apply to the direct fit.
    truth : optional true models {"reference": ..., "medium": ..., "target": ...} (simulated
        data) listed beside the estimates in report.md.
    Other arguments as :func:`veil.fit_medium`. Returns a :class:`PipelineResult`.
    """
    fixed = _check_fixed(fixed)
    outdir = os.fspath(outdir)
    inputs = {"reference_clear": reference_clear, "reference_medium": reference_medium,
              "target_medium": target_medium, "black": black, "target_clear": target_clear}
    _check_outputs(outdir, inputs)

    def stage(name):
        """The callback of one step; announces the step at once."""
        if progress is None:
            return None
        progress(f"{name}: starting", None, None)
        return lambda what, done, total: progress(f"{name}: {what}", done, total)

    # read and check every input before the first (long) fit
    data = {"reference_clear": prepare(reference_clear, None, "reference (clear medium)"),
            "reference_medium": prepare(reference_medium, black, "reference (in the medium)"),
            "target_medium": prepare(target_medium, black, "target (in the medium)")}
    if target_clear is not None:
        data["target_clear"] = prepare(target_clear, None, "target (clear medium)")

    ref = fit_reference(data["reference_clear"].table, fixed=fixed.get("reference"),
                        max_nfev=max_nfev, progress=stage("step 0, reference"))
    med = fit_medium(data["reference_medium"].table, ref, fixed=fixed.get("medium"),
                     variant=variant, accuracy=accuracy, max_nfev=max_nfev,
                     progress=stage("step 1, medium"))
    tgt = fit_target(data["target_medium"].table, med, fixed=fixed.get("target"),
                     accuracy=accuracy, max_nfev=max_nfev, progress=stage("step 2, target"))
    direct = comparison = None
    if target_clear is not None:
        direct = fit_direct(data["target_clear"].table, fixed=fixed.get("target"),
                            max_nfev=max_nfev, progress=stage("target, clear medium"))
        comparison = compare(tgt, direct)

    names = {}
    with output_folder(outdir, owned=FILES.values()) as folder:
        for key, result in (("reference", ref), ("medium", med), ("target", tgt),
                            ("direct", direct)):
            if result is not None:
                result.to_json(folder / FILES[key])
                names[key] = FILES[key]
        if figures:
            if progress is not None:
                progress("figures", None, None)
            figs = {"reference_fig": (data["reference_clear"], ref, None, None),
                    "medium_fig": (data["reference_medium"], med, ref.as_model(), None),
                    "target_fig": (data["target_medium"], tgt, med.as_model(), None)}
            if direct is not None:
                figs["direct_fig"] = (data["target_clear"], direct, None, tgt)
            for key, (d, result, other, extra) in figs.items():
                write_bytes_atomic(folder / FILES[key], fit_figure(d, result, other, extra))
                names[key] = FILES[key]
        # inputs inside the output folder are named relative to it (links from report.md)
        shown = {k: (os.path.relpath(v, outdir) if isinstance(v, (str, os.PathLike))
                     and _inside(v, outdir) else v) for k, v in inputs.items()}
        report = report_markdown(ref, med, tgt, direct, comparison, truth, names, shown)
        write_text_atomic(folder / FILES["report"], report)
        names["report"] = FILES["report"]
    files = {key: os.path.join(outdir, name) for key, name in names.items()}
    return PipelineResult(ref, med, tgt, direct, comparison, files)


# --------------------------------------------------------------------------------------
# comparison with the directly measured target
# --------------------------------------------------------------------------------------
def compare(estimated: FitResult, direct: FitResult) -> dict:
    """Estimated (through the medium) against direct f_r of the same object.

    Per parameter: difference and difference / sqrt(se_est^2 + se_direct^2) (the estimate's
    total standard error when it has one); and the rms of f_r_est - f_r_direct over the
    configurations of the paper's protocol (absolute and relative to f_r_direct).
    """
    rows = {}
    se_est = estimated.stderr_total or estimated.stderr
    for name, value in estimated.params.items():
        ref = direct.params[name]
        a, b = se_est.get(name), direct.stderr.get(name)
        combined = math.hypot(a or 0.0, b or 0.0)
        rows[name] = {"estimated": value, "direct": ref, "difference": value - ref,
                      "stderr_combined": combined if combined > 0 else None,
                      "z": (value - ref) / combined if combined > 0 else None}
    configs = protocol()
    angles = tuple(configs[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    f_est = model_values(estimated, None, angles)
    f_dir = model_values(direct, None, angles)
    diff = f_est - f_dir
    return {"params": rows, "n_configurations": len(configs),
            "rms_fr_difference": float(np.sqrt(np.mean(diff ** 2))),
            "rms_fr_relative": float(np.sqrt(np.mean((diff / f_dir) ** 2))),
            "max_fr_relative": float(np.max(np.abs(diff / f_dir)))}


# --------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------
def _goniometer(data):
    """(psi, rho, signed theta_r) of in-plane data, or None if a row is out of the plane."""
    try:
        ti, tr = to_signed_inplane(*data.angles)
    except ValueError:
        return None
    psi, rho = to_goniometer(ti, tr)
    return np.round(psi, 6), rho, tr


def _curve_rho(rho_min, rho_max):
    fine = np.arange(-12.0, 12.0 + 1e-9, 0.5)
    coarse = np.arange(math.floor(rho_min), math.ceil(rho_max) + 1e-9, 2.0)
    rho = np.union1d(fine, coarse)
    return rho[(rho >= rho_min - 1e-9) & (rho <= rho_max + 1e-9)]


def fit_figure(data, result: FitResult, other: Model | None, extra: FitResult | None = None,
               dpi: int = 120) -> bytes:
    """PNG: data (markers, sigma bars) and fitted curves against theta_r, one colour per psi.

    ``other`` is the model held fixed (None for f_r alone); ``extra`` adds a dashed f_r curve
    (the through-medium estimate on the direct fit's figure). Out-of-plane data are drawn as
    model against data instead.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 4.6), dpi=dpi)
    ax = fig.add_subplot()
    titles = {"reference": "Step 0: reference object, clear medium (f_r)",
              "medium": "Step 1: reference object through the medium (f_t fitted)",
              "target": "Step 2: target object through the medium (f_r fitted)",
              "direct": "Target object, clear medium: direct fit and estimate"}
    gonio = _goniometer(data)
    y = data.y
    accuracy = result.accuracy or "default"
    if gonio is None:
        model = model_values(result, other, data.angles, accuracy)
        ax.plot(model, y, "o", ms=3, color=COLORS[0])
        lo, hi = min(np.min(y), np.min(model)), max(np.max(y), np.max(model))
        if lo > 0:
            ax.set_xscale("log")
            ax.set_yscale("log")
        ax.plot([lo, hi], [lo, hi], "-", color="0.5", lw=1)
        ax.set_xlabel("fitted model value [relative units, 1/sr]")
        ax.set_ylabel("measured value [relative units, 1/sr]")
    else:
        psi, rho, tr = gonio
        curves = []
        for k, p in enumerate(np.unique(psi)):
            sel = psi == p
            r = _curve_rho(rho[sel].min(), rho[sel].max())
            ti_c, tr_c = p / 2 + r, p / 2 - r
            curves.append((k, p, sel, tr_c, ti_c))
        all_ti = np.concatenate([c[4] for c in curves])
        all_tr = np.concatenate([c[3] for c in curves])
        from .engine.angles import from_signed_inplane
        angles_c = from_signed_inplane(all_ti, all_tr)
        angles_c = (angles_c[0], angles_c[1], angles_c[2], angles_c[3])
        fitted = model_values(result, other, angles_c, accuracy)
        dashed = model_values(extra, None, angles_c) if extra is not None else None
        from matplotlib.lines import Line2D

        start = 0
        handles = []
        for k, p, sel, tr_c, _ in curves:
            color = COLORS[k % len(COLORS)]
            n = len(tr_c)
            order = np.argsort(tr[sel])
            yerr = data.sigma[sel][order] if data.sigma is not None else None
            ax.errorbar(tr[sel][order], y[sel][order], yerr=yerr, fmt="o", ms=3, color=color,
                        elinewidth=0.8, capsize=0)
            ax.plot(tr_c, fitted[start:start + n], "-", color=color, lw=1.2)
            if dashed is not None:
                ax.plot(tr_c, dashed[start:start + n], "--", color=color, lw=1.0)
            handles.append(Line2D([], [], color=color, marker="o", ms=3, lw=1.2,
                                  label=f"psi = {p:g}°"))
            start += n
        positive = y[y > 0]
        if positive.size and np.max(positive) > LOG_RATIO * np.median(positive):
            ax.set_yscale("log")
            ax.set_ylim(bottom=max(np.min(positive) * 0.5, np.max(positive) * 1e-6))
        ax.set_xlabel("reflection angle theta_r [deg] (signed, in the plane of incidence)")
        ax.set_ylabel("observed value [relative units, 1/sr]")
        handles += [Line2D([], [], color="0.3", marker="o", ms=3, lw=0,
                           label="data" + (" (+- sigma)" if data.sigma is not None else "")),
                    Line2D([], [], color="0.3", lw=1.2, label="fitted model")]
        if dashed is not None:
            handles.append(Line2D([], [], color="0.3", lw=1.0, ls="--",
                                  label="f_r estimated through the medium (step 2)"))
        ax.legend(handles=handles, fontsize=7.5, loc="best", framealpha=0.8)
    ax.set_title(titles.get(result.step, result.model), fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


# --------------------------------------------------------------------------------------
# report.md
# --------------------------------------------------------------------------------------
def _fmt(x, digits=5) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.{digits}g}"


def _truth_model(truth, key):
    if not truth or truth.get(key) is None:
        return None
    model = truth[key]
    return PRESETS[model.upper()] if isinstance(model, str) else model


def _param_table(result: FitResult, truth_model) -> list[str]:
    head = "| parameter | value | stderr | stderr incl. given model |"
    rule = "|---|---:|---:|---:|"
    if truth_model is not None:
        head += " true | (value - true) / stderr |"
        rule += "---:|---:|"
    lines = [head, rule]
    for name, value in result.params.items():
        if name in result.fixed:
            se, tot = "fixed", "fixed"
        else:
            se = _fmt(result.stderr.get(name), 3)
            tot = _fmt((result.stderr_total or {}).get(name), 3) \
                if result.stderr_total is not None else "-"
        line = f"| {name} | {_fmt(value, 6)} | {se} | {tot} |"
        if truth_model is not None:
            true = getattr(truth_model, name)
            s = (result.stderr_total or result.stderr).get(name)
            z = (value - true) / s if s else None
            line += f" {_fmt(true, 6)} | {_fmt(z, 3)} |"
        lines.append(line)
    return lines


def _stats_lines(result: FitResult) -> list[str]:
    weight = "weighted by sigma" if result.weighted else \
        "unweighted (no sigma column): standard errors scaled by the reduced chi-square"
    lines = [f"- {result.n_points} points, {weight}; reduced chi-square "
             f"{_fmt(result.chi2_reduced, 4)}, rms relative residual "
             f"{_fmt(100 * result.rms_relative, 3)} %",
             f"- converged: {'yes' if result.converged else '**NO**'} ({result.message})"]
    if result.accuracy:
        lines.append(f"- quadrature accuracy of the result: {result.accuracy}")
    if result.variant:
        lines.append(f"- medium Fresnel variant: {result.variant} (MODEL.md sec. 3)")
    return lines


def report_markdown(ref, med, tgt, direct, comparison, truth, figures, inputs) -> str:
    """report.md: the parameter tables per step (value +- stderr), statistics, figures."""
    out = ["# veil fit: two-step estimation (MODEL.md sec. 7)", ""]
    listed = [f"- {k.replace('_', ' ')}: `{os.fspath(v)}`" for k, v in inputs.items()
              if isinstance(v, (str, os.PathLike))]
    if listed:
        out += ["Inputs:", ""] + listed + [""]
    if inputs.get("black") is not None:
        out += ["The black-cloth session was subtracted from both sessions in the medium.", ""]
    out += ["Uncertainties are one standard error from the Jacobian at the solution. "
            "\"stderr\" holds the model given to the step (the reference f_r in step 1, the "
            "medium in step 2) exact; \"stderr incl. given model\" adds that model's own "
            "uncertainty to first order (docs/fitting.md).", ""]
    sections = [("Step 0: reference object in a clear medium (f_r directly)", ref, "reference",
                 "reference_fig"),
                ("Step 1: the medium, through the reference object (f_r fixed)", med, "medium",
                 "medium_fig"),
                ("Step 2: the target object, through the medium (f_t fixed)", tgt, "target",
                 "target_fig")]
    for title, result, key, fig in sections:
        out += [f"## {title}", "", f"Model: {result.model}.", ""]
        out += _param_table(result, _truth_model(truth, key)) + [""]
        out += _stats_lines(result) + [""]
        if fig in figures:
            out += [f"![{title}]({figures[fig]})", ""]
    if direct is not None and comparison is not None:
        out += ["## The target measured directly, against the estimate", "",
                "The target's clear-medium data fitted directly (no medium); the estimate of "
                "step 2 against it. z = difference / sqrt(stderr_est^2 + stderr_direct^2), "
                "with the estimate's stderr including the given model's.", "",
                "| parameter | estimated (step 2) | direct | difference | z |",
                "|---|---:|---:|---:|---:|"]
        for name, row in comparison["params"].items():
            out.append(f"| {name} | {_fmt(row['estimated'], 6)} | {_fmt(row['direct'], 6)} | "
                       f"{_fmt(row['difference'], 3)} | {_fmt(row['z'], 3)} |")
        out += ["", f"Over the {comparison['n_configurations']} configurations of the paper's "
                    f"protocol (psi = 30, 60, 90 deg): rms of f_r(estimated) - f_r(direct) = "
                    f"{_fmt(comparison['rms_fr_difference'], 4)} (relative units), rms relative "
                    f"difference {_fmt(100 * comparison['rms_fr_relative'], 3)} %, largest "
                    f"{_fmt(100 * comparison['max_fr_relative'], 3)} %.", ""]
        out += _stats_lines(direct) + [""]
        if "direct_fig" in figures:
            out += [f"![direct fit]({figures['direct_fig']})", ""]
    return "\n".join(out)


__all__ = ["run_pipeline", "PipelineResult", "compare", "fit_figure", "report_markdown",
           "FILES"]
