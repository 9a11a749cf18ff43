"""The whole estimation of docs/model.md sec. 7 in one call: steps 0-2, result files,
figures, report.

:func:`run_pipeline` fits the reference's f_r in a clear medium (step 0), the medium through
the reference (step 1) and the target through the medium (step 2), and writes into ``outdir``
(as one transaction, :func:`veil.io.output_folder`: a rerun replaces these files together,
an interrupted or failed run leaves the folder as it was):

- ``reference.json``, ``medium.json``, ``target.json``: :class:`veil.fitting.FitResult` files;
- ``reference.png``, ``medium.png``, ``target.png``: data against the fitted curves, value
  against the signed reflection angle theta_r, one curve per psi (like the paper's figs.
  15-17), over a panel of the relative residuals with the fit's model-error band, where a
  trend in the angles that the model cannot follow shows;
- with ``target_clear``: ``target_direct.json`` (the target fitted directly, no medium),
  ``target_direct.png`` and a comparison of the estimated f_r with it;
- ``report.md``: the parameter tables and the comparison.

Formats and the meaning of the uncertainties: docs/fitting.md.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .analysis.uncertainty import curve_stderr
from .data.measurements import CANONICAL
from .data.protocol import protocol
from .errors import FitError
from .fitting import (
    FitResult,
    fit_direct,
    fit_medium,
    fit_reference,
    fit_target,
    model_values,
    prepare,
)
from .fitting.model_error import check_kind
from .fitting.propagation import check_method
from .io import check_output_folder, output_folder, write_bytes_atomic, write_text_atomic
from .viz.documents import comparison_report, pipeline_report
from .viz.fit_figures import fit_figure

#: Output files, by role.
FILES = {"reference": "reference.json", "medium": "medium.json", "target": "target.json",
         "direct": "target_direct.json", "report": "report.md",
         "reference_fig": "reference.png", "medium_fig": "medium.png",
         "target_fig": "target.png", "direct_fig": "target_direct.png"}
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


def _check_fixed(fixed, what: str = "fixed") -> dict:
    if fixed is None:
        return {}
    if not isinstance(fixed, dict) or set(fixed) - set(STEP_KEYS):
        raise FitError(f"{what} = {fixed!r}; expected a dict by step, e.g. "
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
    for name in FILES.values():
        out = os.path.join(outdir, name)
        for what, inp in inputs.items():
            if isinstance(inp, (str, os.PathLike)) and _same(out, inp):
                raise FitError(f"input {what} ({os.fspath(inp)}) would be overwritten by the "
                               f"output {out}; veil never overwrites an input: choose another "
                               f"output directory")


def _prepare_sessions(inputs: dict) -> dict:
    """Every session read and checked before the first (long) fit (black cloth subtracted
    from the sessions in the medium)."""
    black = inputs["black"]
    data = {"reference_clear": prepare(inputs["reference_clear"], None,
                                       "reference (clear medium)"),
            "reference_medium": prepare(inputs["reference_medium"], black,
                                        "reference (in the medium)"),
            "target_medium": prepare(inputs["target_medium"], black, "target (in the medium)")}
    if inputs["target_clear"] is not None:
        data["target_clear"] = prepare(inputs["target_clear"], None, "target (clear medium)")
    return data


def _relative_to(inputs: dict, outdir: str) -> dict:
    """The inputs, those inside ``outdir`` named relative to it."""
    return {k: (os.path.relpath(v, outdir) if isinstance(v, (str, os.PathLike))
                and _inside(v, outdir) else v) for k, v in inputs.items()}


def _stage(progress, name: str):
    """The progress callback of one step (None without ``progress``); announces the step at
    once."""
    if progress is None:
        return None
    progress(f"{name}: starting", None, None)
    return lambda what, done, total: progress(f"{name}: {what}", done, total)


def _write_figures(folder, data: dict, ref, med, tgt, direct) -> dict:
    """The figure of each fit in ``folder``: {figure key: file name}."""
    figs = {"reference_fig": (data["reference_clear"], ref, None, None),
            "medium_fig": (data["reference_medium"], med, ref.as_model(), None),
            "target_fig": (data["target_medium"], tgt, med.as_model(), None)}
    if direct is not None:
        figs["direct_fig"] = (data["target_clear"], direct, None, tgt)
    for key, (d, result, other, extra) in figs.items():
        write_bytes_atomic(folder / FILES[key], fit_figure(d, result, other, extra))
    return {key: FILES[key] for key in figs}


def run_pipeline(reference_clear, reference_medium, target_medium, black=None, target_clear=None,
                 outdir="veil-fit", *, variant: str | None = None, accuracy: str = "default",
                 fixed=None, max_nfev=None, progress=None, truth=None,
                 figures: bool = True, brdf_model=None, medium_model=None, brdf_options=None,
                 medium_options=None, free=None, model_error=None,
                 propagation=None) -> PipelineResult:
    """Steps 0-2 of docs/model.md sec. 7 with files, figures and report.md in ``outdir``.

    reference_clear, reference_medium, target_medium : sessions (DataFrames or CSV paths):
        the reference in a clear medium, the reference in the medium, the target in the medium.
    black : black-cloth session in the medium, subtracted from both medium sessions.
    target_clear : optional target in a clear medium: fitted directly and compared with the
        estimate (parameter differences in units of their combined standard error, rms of
        the f_r difference over the protocol's configurations).
    fixed : parameters held per step, e.g. ``{"medium": {"eta": 1.33}}``; the target's also
        apply to the direct fit.
    free : parameters the families hold by default (``Param.held``) to fit too, per step,
        e.g. ``{"medium": ["s"]}``; the target's also apply to the direct fit.
    truth : optional true models {"reference": ..., "medium": ..., "target": ...} (simulated
        data) listed beside the estimates in report.md.
    brdf_model, medium_model, brdf_options, medium_options : the families of the objects and
        of the medium (registered names; default the paper's) and their options.
    model_error : the model-discrepancy term of every weighted step ("off", "independent"
        or "correlated", the default; :mod:`veil.fitting.model_error`): step 2 uses step 1's
        when larger than its own and counts the error the two share.
    propagation : how each step's given covariance enters its ``stderr_total`` ("auto", the
        default, "linear" or "sigma-points"; :mod:`veil.fitting.propagation`).
    Other arguments as :func:`veil.fit_medium`. Returns a :class:`PipelineResult`.
    """
    model_error = check_kind(model_error)
    propagation = check_method(propagation)
    fixed = _check_fixed(fixed)
    free = _check_fixed(free, "free")
    outdir = os.fspath(outdir)
    inputs = {"reference_clear": reference_clear, "reference_medium": reference_medium,
              "target_medium": target_medium, "black": black, "target_clear": target_clear}
    _check_outputs(outdir, inputs)

    # read and check every input before the first (long) fit
    data = _prepare_sessions(inputs)

    brdf = {"brdf_model": brdf_model, "options": brdf_options, "model_error": model_error}
    chained = {"model_error": model_error, "propagation": propagation}
    ref = fit_reference(data["reference_clear"].table, fixed=fixed.get("reference"),
                        max_nfev=max_nfev, progress=_stage(progress, "step 0, reference"),
                        free=free.get("reference"), **brdf)
    med = fit_medium(data["reference_medium"].table, ref, fixed=fixed.get("medium"),
                     variant=variant, accuracy=accuracy, max_nfev=max_nfev,
                     progress=_stage(progress, "step 1, medium"), medium_model=medium_model,
                     options=medium_options, free=free.get("medium"), **chained)
    tgt = fit_target(data["target_medium"].table, med, fixed=fixed.get("target"),
                     accuracy=accuracy, max_nfev=max_nfev,
                     progress=_stage(progress, "step 2, target"), free=free.get("target"),
                     brdf_model=brdf_model, options=brdf_options,
                     **chained)
    direct = comparison = None
    if target_clear is not None:
        direct = fit_direct(data["target_clear"].table, fixed=fixed.get("target"),
                            max_nfev=max_nfev, free=free.get("target"),
                            progress=_stage(progress, "target, clear medium"), **brdf)
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
            names.update(_write_figures(folder, data, ref, med, tgt, direct))
        # inputs inside the output folder are named relative to it (links from report.md)
        shown = _relative_to(inputs, outdir)
        report = pipeline_report(ref, med, tgt, direct, comparison, truth, names, shown)
        write_text_atomic(folder / FILES["report"], report)
        names["report"] = FILES["report"]
    files = {key: os.path.join(outdir, name) for key, name in names.items()}
    return PipelineResult(ref, med, tgt, direct, comparison, files)


# --------------------------------------------------------------------------------------
# comparison with the directly measured target
# --------------------------------------------------------------------------------------
def compare(estimated: FitResult, direct: FitResult) -> dict:
    """Estimated (through the medium; a step-2 or a joint fit) against direct f_r of the same
    object.

    Per parameter: difference and difference / sqrt(se_est^2 + se_direct^2) (the estimate's
    total standard error when it has one); and the rms of f_r_est - f_r_direct over the
    configurations of the paper's protocol (absolute and relative to f_r_direct). The curves
    are compared in units of their own standard error too (the covariances propagated
    through f_r's Jacobian at each configuration): ``fr_max_z`` the largest |difference| /
    se, ``fr_within_2se`` the share of configurations within two standard errors (None
    when an uncertainty is undetermined). Correlated parameters can differ by many of their
    own standard errors while the curves agree: the curves are what the estimate is for.
    """
    rows = {}
    se_est = estimated.stderr_total or estimated.stderr
    named = estimated.target_names()        # a joint fit's by their result names
    for name, ref in direct.params.items():
        key = named[name]
        value = estimated.params[key]
        a, b = se_est.get(key), direct.stderr.get(name)
        combined = math.hypot(a or 0.0, b or 0.0)
        rows[name] = {"estimated": value, "direct": ref, "difference": value - ref,
                      "stderr_combined": combined if combined > 0 else None,
                      "z": (value - ref) / combined if combined > 0 else None}
    configs = protocol()
    angles = tuple(configs[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    f_est, se_f_est = curve_stderr(estimated, angles)
    f_dir, se_f_dir = curve_stderr(direct, angles)
    diff = f_est - f_dir
    out = {"params": rows, "n_configurations": len(configs),
           "rms_fr_difference": float(np.sqrt(np.mean(diff ** 2))),
           "rms_fr_relative": float(np.sqrt(np.mean((diff / f_dir) ** 2))),
           "max_fr_relative": float(np.max(np.abs(diff / f_dir))),
           "fr_max_z": None, "fr_within_2se": None}
    if se_f_est is not None:
        se = np.hypot(se_f_est, 0.0 if se_f_dir is None else se_f_dir)
        if np.all(se > 0):
            z = np.abs(diff) / se
            out["fr_max_z"] = float(np.max(z))
            out["fr_within_2se"] = float(np.mean(z <= 2.0))
    return out



# --------------------------------------------------------------------------------------
# model sets side by side
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ComparisonResult:
    """``run_pipeline`` once per model set on the same data (``veil fit pipeline --compare``)."""

    results: dict
    seconds: dict
    difference: dict
    files: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        return all(r.converged for r in self.results.values())


def _for_family(cls, per_step: dict, step: str, what: str, used: set) -> dict | list | None:
    """The entries of ``per_step[step]`` that name parameters of ``cls`` (a fixed dict or a
    free list); records which were used."""
    entries = per_step.get(step)
    if not entries:
        return None
    names = cls.param_names()
    kept: dict | list
    if isinstance(entries, dict):
        kept = {k: v for k, v in entries.items() if k in names}
    else:
        kept = [k for k in entries if k in names]
    used.update((step, k) for k in kept)
    return kept


def _target_difference(results: dict) -> dict:
    """How far the other sets' target f_r is from the first's over the protocol's
    configurations: relative rms and largest difference."""
    names = list(results)
    first = names[0]
    configs = protocol()
    angles = tuple(configs[c].to_numpy() for c in CANONICAL)
    base = model_values(results[first].target, None, angles)
    rel = np.concatenate([(model_values(results[n].target, None, angles) - base) / base
                          for n in names[1:]])
    return {"against": first, "n": len(configs), "rms": float(np.sqrt(np.mean(rel ** 2))),
            "max": float(np.max(np.abs(rel)))}


def compare_models(reference_clear, reference_medium, target_medium, black=None,
                   target_clear=None, outdir="veil-compare", *, sets=None,
                   accuracy: str = "default", fixed=None, free=None, max_nfev=None,
                   progress=None, brdf_options=None, medium_options=None,
                   figures: bool = True, model_error=None,
                   propagation=None) -> ComparisonResult:
    """:func:`run_pipeline` with each named model set (default the paper's and the physical
    ones, :data:`veil.models.MODEL_SETS`) on the same sessions, each into ``outdir/<set>/``,
    and ``outdir/comparison.md``: goodness of fit (chi-square, AIC, BIC) step by step side by
    side, each estimate against the direct fit, and the sets' estimates against each other.

    Options, ``fixed`` and ``free`` entries apply to the sets whose families declare them;
    one that no set's family declares is an error. The folder is written as one transaction.
    """
    from .models import MODEL_SETS, model_class

    sets = dict(MODEL_SETS) if sets is None else dict(sets)
    if len(sets) < 2:
        raise FitError(f"sets = {list(sets)}: a comparison needs at least two model sets")
    fixed, free = _check_fixed(fixed), _check_fixed(free, "free")
    used_fix: set[tuple] = set()
    used_free: set[tuple] = set()
    used_opts: set[str] = set()
    plans: dict[str, dict[str, Any]] = {}
    for name, chosen in sets.items():
        brdf, medium = model_class(chosen["brdf"], "brdf"), model_class(chosen["medium"], "medium")
        b_opts = {k: v for k, v in (brdf_options or {}).items() if k in brdf.option_names()}
        m_opts = {k: v for k, v in (medium_options or {}).items() if k in medium.option_names()}
        used_opts.update(b_opts, m_opts)
        plans[name] = dict(
            brdf_model=brdf.NAME, medium_model=medium.NAME, brdf_options=b_opts,
            medium_options=m_opts,
            fixed={step: f for step in STEP_KEYS if (f := _for_family(
                medium if step == "medium" else brdf, fixed, step, "fixed", used_fix))},
            free={step: f for step in STEP_KEYS if (f := _for_family(
                medium if step == "medium" else brdf, free, step, "free", used_free))})
    for what, per_step, used in (("fixed", fixed, used_fix), ("free", free, used_free)):
        unused = [f"{step}.{k}" for step, entries in per_step.items() for k in entries
                  if (step, k) not in used]
        if unused:
            raise FitError(f"{what} {', '.join(unused)}: no compared model has such a "
                           f"parameter ({', '.join(sets)})")
    unused = sorted(set(brdf_options or {}) | set(medium_options or {}) - used_opts)
    if unused:
        raise FitError(f"option(s) {', '.join(unused)}: no compared model declares them")
    outdir = os.fspath(outdir)
    inputs = [reference_clear, reference_medium, target_medium, black, target_clear]
    for inp in inputs:
        if isinstance(inp, (str, os.PathLike)) and _inside(inp, outdir):
            raise FitError(f"input {os.fspath(inp)} lies inside the output folder {outdir}; "
                           f"veil never overwrites an input: choose another output directory")
    results, seconds = {}, {}
    with output_folder(outdir, owned=list(sets) + ["comparison.md"]) as folder:
        for name, plan in plans.items():
            if progress is not None:
                progress(f"model set '{name}'", None, None)
            inner = None if progress is None else (
                lambda what, done, total, name=name: progress(f"{name}: {what}", done, total))
            t0 = time.perf_counter()
            results[name] = run_pipeline(reference_clear, reference_medium, target_medium,
                                         black=black, target_clear=target_clear,
                                         outdir=folder / name, accuracy=accuracy,
                                         max_nfev=max_nfev, progress=inner, figures=figures,
                                         model_error=model_error,
                                         propagation=propagation, **plan)
            seconds[name] = time.perf_counter() - t0
        difference = _target_difference(results)
        write_text_atomic(folder / "comparison.md",
                          comparison_report(results, seconds, difference))
    # the sets' files were written in the staging folder, now moved to outdir
    files = {"comparison": os.path.join(outdir, "comparison.md")}
    for name, r in results.items():
        files.update({f"{name}/{key}": os.path.join(outdir, name, os.path.basename(path))
                      for key, path in r.files.items()})
    return ComparisonResult(results, seconds, difference, files)


__all__ = ["run_pipeline", "PipelineResult", "compare", "compare_models", "ComparisonResult",
           "fit_figure", "FILES"]
