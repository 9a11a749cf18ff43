"""The function an engine Jacobian differentiates (docs/engine.md "Derivatives"): the apparent
reflectance by the quadrature whose phase grids are drawn at a fixed medium."""

from __future__ import annotations

import numpy as np

from veil._jax import jax
from veil.engine import integrator
from veil.engine.forward import Forward


def held_values(fwd: Forward, vm0):
    """f(vb, vm): ``fwd``'s apparent reflectance with the phase grids drawn at the medium
    ``vm0``, each node weighted by the phase at ``vm`` over the density it was drawn from;
    one compiled program for every (vb, vm)."""
    bt, mt = integrator.template_for(fwd._kb), integrator.template_for(fwd._km)
    wi, wr = np.asarray(fwd._wi)[: fwd.size], np.asarray(fwd._wr)[: fwd.size]
    at = np.asarray(vm0, dtype=float)
    run = jax.jit(
        lambda vb, vm: integrator.apparent_terms(
            bt, mt, fwd.rule, vb, vm, wi, wr, fwd.half, phase_grids_at=at
        )
    )

    def values(vb, vm):
        return fwd.combine(np.asarray(run(np.asarray(vb), np.asarray(vm))), vb, vm)

    return values
