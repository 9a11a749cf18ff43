"""Programs of several colour channels at once (docs/channels.md, "Cost").

Channels whose media differ only in scale parameters share one run of a one-channel
program (:meth:`veil.engine.forward.Forward._memo_run`). Channels whose media differ in
non-scale parameters (forward-series' tau and omega) would each run it: their phase lobes
differ, and so the nodes where the BRDF is evaluated. Here their phase grids are drawn from
one sampling law of all the channels (``Medium.sampling_law``;
:func:`veil.engine.integrator.apparent_terms_channels`), so one program evaluates the BRDF
once for every channel and each channel's medium at the shared nodes.

:func:`anticipate` runs that program for the channels of one iteration and keeps each
channel's output where the one-channel calls of the same iteration find it, so a fit of
several channels (one :class:`~veil.fitting.problem.Block` per channel, one engine) needs
no change beyond announcing the iteration's parameter vectors.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from .._jax import jax, jnp
from ..models.base import Medium
from . import integrator
from .forward import (
    Forward,
    LinearForward,
    Program,
    _identity,
    _label,
    _read_only,
    _sharded,
    _submit,
    _terms_fn,
    jacobian_program,
)
from .quadrature import Rule


def shares_nodes(medium) -> bool:
    """Whether ``medium``'s family declares a sampling law for channels (its channels that
    differ in non-scale parameters then run one program together)."""
    return type(medium).sampling_law is not Medium.sampling_law


@lru_cache(maxsize=64)
def _channel_terms_fn(kb, km, rule: Rule, half: bool, channels: int, mesh):
    """Term matrices (M, C, rows, 2) of ``channels`` media (rows of ``vms``) and one BRDF."""
    bt, mt = integrator.template_for(kb), integrator.template_for(km)

    def fn(vb, vms, wi, wr):
        return integrator.apparent_terms_channels(bt, mt, rule, vb, vms, wi, wr, half)

    return Program(
        _sharded(fn, mesh),
        _identity(f"terms of {channels} channels", kb, km, rule, half, mesh),
        (kb[0], km[0]),
        _label(f"values of {channels} channels", kb, km, rule, half),
    )


@lru_cache(maxsize=64)
def _channel_jacobian_fn(kb, km, rule: Rule, half: bool, nl_b, nl_m, channels: int, mesh):
    """Terms (M, C, rows, 2) and their derivatives (..., len(nl_b) + len(nl_m)): each
    channel's in the shared BRDF parameters and in its own medium's (one tangent per
    parameter for every channel at once: a channel's terms depend on no other channel's
    medium, the sampling law held where it is)."""
    bt, mt = integrator.template_for(kb), integrator.template_for(km)
    ib, im = np.asarray(nl_b, dtype=int), np.asarray(nl_m, dtype=int)
    nb = len(nl_b)

    def fn(vb, vms, wi, wr):
        law = jax.lax.stop_gradient(integrator.channel_law(mt, vms))

        def g(xb, xm):
            return integrator.apparent_terms_channels(
                bt, mt, rule, vb.at[ib].set(xb), vms.at[:, im].set(xm), wi, wr, half, law
            )

        xb, xm = vb[ib], vms[:, im]

        def along(direction):
            dm = jnp.broadcast_to(direction[nb:], xm.shape)
            return jax.jvp(g, (xb, xm), (direction[:nb], dm))

        eye = jnp.eye(nb + len(nl_m), dtype=vb.dtype)
        return jax.vmap(along, out_axes=(None, -1))(eye)

    return jacobian_program(fn, kb, km, rule, half, nl_b, nl_m, mesh, f" of {channels} channels")


def is_channel_program(fn) -> bool:
    """Whether ``fn`` is one of the channels' programs (for tests and the compile display)."""
    return " channels" in getattr(fn, "identity", "")


def _programs(forward: Forward, channels: int, free):
    """(the one-channel program whose calls the channels' output answers, the channels'
    program) for values (``free`` None) or the Jacobian in ``free`` (free_brdf,
    free_medium), or None when only scale parameters are free."""
    f = forward
    if free is None:
        one = _terms_fn(f._kb, f._km, f.rule, f.half, f._mesh)
        return one, _channel_terms_fn(f._kb, f._km, f.rule, f.half, channels, f._mesh)
    one, _, _, _, _, nl_b, nl_m = f._jacobian_fn(*free)
    if one is None:
        return None
    many = _channel_jacobian_fn(f._kb, f._km, f.rule, f.half, nl_b, nl_m, channels, f._mesh)
    return one, many


def _applies(forward: Forward) -> bool:
    return not isinstance(forward, LinearForward) and shares_nodes(forward.medium)


def anticipate(forward: Forward, vbs: Sequence, vms: Sequence, free=None) -> bool:
    """Run the channels' program for the channels' parameter vectors (``vbs``, ``vms``, one
    per channel) and keep each channel's output for the one-channel calls that follow
    (values, or the Jacobian in ``free`` as :meth:`Forward.value_and_jacobian` takes it).
    Only where it pays: the medium declares a sampling law, the channels share the BRDF's
    non-scale parameters and differ in the medium's. Returns whether it ran."""
    if not _applies(forward) or len(vms) < 2:
        return False
    pairs = [forward._vectors(vb, vm) for vb, vm in zip(vbs, vms)]
    keys = [forward._key(vb, vm) for vb, vm in pairs]
    nb = len(type(forward.brdf).PARAMS) * 8
    if len({k[:nb] for k in keys}) != 1 or len(set(keys)) < 2:
        return False
    # every channel, a repeated medium too: one program per number of channels, not one per
    # number of distinct media (a fit's channels may start from the same grid point)
    programs = _programs(forward, len(pairs), free)
    if programs is None:
        return False
    one, many = programs
    out = forward._run(many, pairs[0][0], np.stack([vm for _, vm in pairs]))
    first = {key: c for c, key in reversed(list(enumerate(keys)))}
    forward._anticipated = {
        **{k: v for k, v in forward._anticipated.items() if k[0] is not one},
        **{
            (one, key): jax.tree_util.tree_map(lambda a, c=c: _read_only(np.asarray(a)[:, c]), out)
            for key, c in first.items()
        },
    }
    return True


def prepare(forward: Forward, channels: int, values: bool = True, jacobians=()) -> list:
    """Compile (or load) in the background the channels' programs that :func:`anticipate`
    will run for ``channels`` channels (as :meth:`Forward.prepare`)."""
    if not _applies(forward) or channels < 2:
        return []
    wanted = ([None] if values else []) + [tuple(free) for free in jacobians]
    vb, vm = forward._vectors(forward.brdf.to_vector(), forward.medium.to_vector())
    vms = np.tile(vm, (channels, 1))
    futures = []
    for free in wanted:
        programs = _programs(forward, channels, free)
        if programs is not None:
            futures.append(_submit(programs[1], vb, vms, forward._wi, forward._wr))
    return futures


__all__ = ["anticipate", "is_channel_program", "prepare", "shares_nodes"]
