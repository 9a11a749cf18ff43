"""What a fit's silent sessions leave undetermined (docs/fitting.md, "Not determined").

A session (a block of a :class:`~veil.fitting.problem.Problem`: a channel of a fit over
colour channels, a session of a joint fit) without a single positive value carries no signal.
It cannot determine the parameters only it depends on (a channel's own albedo and scales);
the parameters it shares with sessions that have a signal (the tied roughness and index of a
fit over channels) are determined by those. Such a fit is "not determined", but the
parameters that are determined keep their uncertainties: the covariance with the
undetermined ones held, from the sessions that carry a signal (:func:`held_covariance`).
"""

from __future__ import annotations

import numpy as np

from . import least_squares as lsq
from .problem import Block, Problem


def silent_blocks(problem: Problem) -> list[bool]:
    """Per block of ``problem``: whether it has no positive value (no signal)."""
    return [not np.any(problem.y[sl] > 0) for sl in problem.slices()]


def _slots(block: Block) -> set[int]:
    """The global indices of a block's parameters (BRDF and medium)."""
    return {int(i) for i in block.ib} | (set() if block.im is None else {int(i) for i in block.im})


def block_only(problem: Problem, k: int, silent: list[bool]) -> list[str]:
    """The free parameters of block ``k`` that no block with a signal depends on, in the
    problem's order (every free parameter of a problem of one block)."""
    mine = _slots(problem.blocks[k])
    heard: set[int] = set().union(*(_slots(b) for b, s in zip(problem.blocks, silent) if not s))
    return [problem.names[i] for i in problem.free_index if i in mine and i not in heard]


def no_signal(problem: Problem) -> tuple[list[str], list[str]]:
    """(a reason per block without a positive value, the free parameters those blocks alone
    would determine); both empty when every block has a signal."""
    why: list[str] = []
    which: list[str] = []
    silent = silent_blocks(problem)
    for k, (b, sl) in enumerate(zip(problem.blocks, problem.slices())):
        if not silent[k]:
            continue
        y = problem.y[sl]
        own = block_only(problem, k, silent)
        why.append(
            f"session {b.session.name!r} has no positive value (all "
            f"{'zero' if np.all(y == 0) else 'zero or negative'}"
            f"{' after black-cloth subtraction' if b.medium is not None else ''}): "
            + (
                f"it carries no signal to fit {', '.join(own)}"
                if own
                else "it carries no signal (the other sessions determine all its parameters; "
                "its rows are left out of the uncertainties)"
            )
        )
        which += own
    return why, [n for n in problem.free_names if n in which]


def held_covariance(
    problem: Problem, jw: np.ndarray, held: list[str], residuals: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """(covariance of the free parameters not ``held``, their indices into the problem's
    names) from the weighted Jacobian ``jw`` of the free parameters (prior rows last) without
    the held ones' columns and the rows of blocks without a signal, as a fit with the held
    parameters fixed and those blocks left out would compute it; unweighted data scale it by
    the reduced chi-square of ``residuals`` over the rows kept. None when nothing is left
    free or the rest is singular too."""
    keep = np.array([n not in held for n in problem.free_names], dtype=bool)
    silent = silent_blocks(problem)
    rows = np.ones(jw.shape[0], dtype=bool)
    for s, sl in zip(silent, problem.slices()):
        rows[sl] = not s
    if not keep.any():
        return None
    cov, full = lsq.covariance(jw[np.ix_(rows, keep)])
    if not full:
        return None
    if not problem.weighted:
        data = rows[: problem.n_points]
        dof = int(data.sum()) - int(keep.sum())
        cov = cov * float(lsq.residual_variance(residuals[data], dof))
    return cov, problem.free_index[keep]


__all__ = ["silent_blocks", "block_only", "no_signal", "held_covariance"]
