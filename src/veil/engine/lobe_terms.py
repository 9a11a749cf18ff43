"""The integrator's terms in which the BRDF's lobe meets the medium's phase lobe
(docs/model.md sec. 5): the 4D lobe-lobe term and the two one-sided terms.

Each term is written in two parts: its nodes, and a ``finish`` that sums the integrand
once the lobe and the phase function are known there. :mod:`veil.engine.integrator`
evaluates the lobe (:func:`veil.engine.nodes.lobe_at`) and the phase function at each
part's nodes. The 4D term's lobe is evaluated where it is summed: there are tens of thousands
of nodes per configuration, and XLA fuses the lobe into the sum instead of holding its
values.

A part returns ``(lobe_requests, phase_requests, finish)``: lists of node sets (for
``lobe_at``: (wi, wo, h, alpha); for the phase function: 1 - cos of the scattering angle) and
``finish(lobes, phases, densities)``, which takes the values in the same order: the phase
function there, and the density of the phase grids' sampling law there (the same values,
the same objects, unless the grids were drawn from another law: one shared by several
channels, or the medium's own held constant in a Jacobian, :func:`veil.engine.nodes.channel_grid`;
the balance weights take the law's density, the integrand the channel's phase).
"""

from __future__ import annotations

from .._jax import jax, jnp
from .nodes import dot3, half_distance, normalized, phase_ratio, polar, reflect


def apart(fn, vm, *args):
    """fn(*args) computed apart from the surrounding expression (not fused into it): a
    conditional on a value known only at run time keeps its branch a computation of its own
    (taken whenever the medium's parameters are finite; otherwise the result is NaN, as it
    would be anyway)."""
    return jax.lax.cond(
        jnp.all(jnp.isfinite(vm)),
        fn,
        lambda *a: jax.tree.map(lambda z: jnp.full_like(z, jnp.nan), fn(*a)),
        *args,
    )


def view_weight(medium, vm, r_prime, wr):
    """The medium's weight of its view-side lobe at R' (..., 3) for the camera at R, or 1."""
    if not medium.has_view_weight():
        return 1.0
    # apart: XLA would fuse it into the consumers of the grid's weights, the 4D products,
    # and evaluate it again at every node of them
    return apart(lambda a, b: medium.view_weight(vm, a, b), vm, r_prime, wr)


def _balanced(p_i, p_r, c, q_h, lobe):
    """lobe p_i p_r / (q_A + q_B + q_C) with the untruncated densities (balance rule)."""
    den = q_h * (p_i + p_r) / (4.0 * c) + p_i * p_r
    ok = (c > 0) & (den > 0)
    return jnp.where(ok, lobe * p_i * p_r / jnp.where(ok, den, 1.0), 0.0)


def lobe_lobe(brdf, medium, vb, vm, wi, wr, half: bool, grids, facets, y_full):
    """Int Int b(I') p(I.I') lobe(I', R') a(R') J(R') p(R'.R) dI' dR' (balanced MIS
    quadrature over three product grids), J the view-side weight of the medium (1 without
    one). ``grids`` are the phase grids (:func:`veil.engine.nodes.phase_grids`) about I
    (``half`` azimuths), about R, and about R with ``half`` azimuths (only when ``half``);
    ``facets`` the 4D term's facet grid (:func:`veil.engine.nodes.facet_grids`)."""
    (gi, ui, fi, pi_), (gr, ur, fr, pr) = grids[:2]
    bi = medium.factor_second(vm, gi[:, 2])
    ar = medium.factor_first(vm, gr[:, 2]) * view_weight(medium, vm, gr, wr)
    if half:  # component B needs only half of the R' azimuths (C pairs half I' with all R')
        grb, urb, frb, prb = grids[2]
        arb = medium.factor_first(vm, grb[:, 2]) * view_weight(medium, vm, grb, wr)
    else:
        grb, urb, frb, prb, arb = gr, ur, fr, pr, ar
    h, alpha, uh, qh = facets
    # A: I' on the phase grid about I, H on the facet grid, R' = refl(I') (zero below the
    # horizon, where the integrand already vanishes with a(R') and the shadowing term)
    i_a = gi[:, None, :]
    r_a = reflect(i_a, h)
    # B: R' on the phase grid about R, H on the facet grid, I' = refl(R')
    r_b = grb[:, None, :]
    i_b = reflect(r_b, h)
    # C: I' and R' on their phase grids, H their half vector
    i_c, r_c = gi[:, None, :], gr[None, :, :]
    h_c = normalized(i_c + r_c)
    alpha_c, sin_c = polar(h_c)
    phases = [half_distance(r_a, wr), half_distance(i_b, wi)]

    def finish(lobe, phase, density):
        if phase[0] is not density[0]:
            return finish_law(phase, density)
        # the lobe evaluated in place: fused into the sums, never held at the 4D nodes
        lobe_a = brdf.lobe(vb, i_a, r_a, h, alpha)
        lobe_b = brdf.lobe(vb, i_b, r_b, h, alpha)
        lobe_c = brdf.lobe(vb, i_c, r_c, h_c, alpha_c)
        p_r, p_i = phase
        val = _balanced(pi_[:, None], p_r, dot3(i_a, h), qh, lobe_a)
        val = val * medium.factor_first(vm, r_a[..., 2]) * bi[:, None]
        if medium.has_view_weight():
            val = val * medium.view_weight(vm, r_a, wr)
        total = jnp.sum(ui * fi * jnp.sum(uh * val, axis=-1))
        val = _balanced(p_i, prb[:, None], dot3(r_b, h), qh, lobe_b)
        val = val * arb[:, None] * medium.factor_second(vm, i_b[..., 2])
        total = total + jnp.sum(urb * frb * jnp.sum(uh * val, axis=-1))
        q_c = brdf.facet_weight(vb, alpha_c, sin_c) / y_full
        val = _balanced(pi_[:, None], pr[None, :], dot3(i_c, h_c), q_c, lobe_c)
        val = val * bi[:, None] * ar[None, :]
        return total + jnp.sum((ui * fi)[:, None] * (ur * fr)[None, :] * val)

    def finish_law(phase, density):
        # grids drawn from a law the channels share (the densities q, the channel's phase p):
        # what does not depend on the channel is computed once and held (the lobe and the
        # balance weights, divided by the density the channel's phase replaces), then
        # weighted by each channel's factors
        (p_r, p_i), (q_r, q_i) = phase, density
        q_c = brdf.facet_weight(vb, alpha_c, sin_c) / y_full
        lobe_a = brdf.lobe(vb, i_a, r_a, h, alpha)
        lobe_b = brdf.lobe(vb, i_b, r_b, h, alpha)
        lobe_c = brdf.lobe(vb, i_c, r_c, h_c, alpha_c)
        base_a, base_b, base_c = jax.lax.optimization_barrier(
            (
                _balanced(pi_[:, None], q_r, dot3(i_a, h), qh, lobe_a) * phase_ratio(uh, q_r),
                _balanced(q_i, prb[:, None], dot3(r_b, h), qh, lobe_b) * phase_ratio(uh, q_i),
                _balanced(pi_[:, None], pr[None, :], dot3(i_c, h_c), q_c, lobe_c),
            )
        )
        val = base_a * p_r * medium.factor_first(vm, r_a[..., 2])
        if medium.has_view_weight():
            val = val * medium.view_weight(vm, r_a, wr)
        total = jnp.sum(ui * fi * bi * jnp.sum(val, axis=-1))
        val = base_b * p_i * medium.factor_second(vm, i_b[..., 2])
        total = total + jnp.sum(urb * frb * arb * jnp.sum(val, axis=-1))
        return total + jnp.einsum("i,ij,j->", ui * fi * bi, base_c, ur * fr * ar)

    return [], phases, finish


def _side_nodes(brdf, vb, fixed, center, view, grid, facets, y_full):
    """One side's nodes (vmapped over the two sides by :func:`lobe_sides`)."""
    g, _, _, p = grid
    # the phase grid: density of the free direction p, of the facet strategy q_h / (4 c)
    hg = normalized(g + fixed)
    c = dot3(g, hg)
    alpha_h, sin_h = polar(hg)
    q = jnp.where(hg[..., 2] > 0, brdf.facet_weight(vb, alpha_h, sin_h) / y_full, 0.0)
    q_free = q / (4.0 * jnp.maximum(c, 1e-300))
    ok = (c > 0) & (p + q_free > 0)
    w_phase = jnp.where(ok, p / jnp.where(ok, p + q_free, 1.0), 0.0)
    # the facet grid: H by the facet law, free = mirror of the fixed direction
    h = facets[0][0]
    free = reflect(fixed, h)
    fixed_g, fixed_f = jnp.broadcast_to(fixed, g.shape), jnp.broadcast_to(fixed, free.shape)
    return dict(
        w_phase=w_phase,
        hg=hg,
        alpha_h=alpha_h,
        free=free,
        c_free=dot3(fixed, h),
        omm=half_distance(free, center),
        i_p=jnp.where(view, fixed_g, g),
        o_p=jnp.where(view, g, fixed_g),
        i_f=jnp.where(view, fixed_f, free),
        o_f=jnp.where(view, free, fixed_f),
    )


def lobe_sides(brdf, medium, vb, vm, wi, wr, half: bool, grid_i, grid_r, facets, y_full):
    """The BRDF's lobe against the phase lobe on one side, the other direction fixed, for
    both sides (view, light):

        view:     Int lobe(F, R') a(R') J(R') p(R'.C) dR'    (F = I, C = R)
        light:    Int p(C.I') b(I') lobe(I', F) dI'          (F = R, C = I)

    by balanced MIS over two grids: the dense phase grid about C (``grid_r``, ``grid_i``,
    shared with the other 2D terms), and half vectors from the facet law (``facets``, the
    dense facet grid) with the free direction the mirror of F. The sides are one vmapped
    computation (the program holds the medium's factors once); ``finish`` returns
    (view side, light side)."""
    del half  # the facet grid was made with it
    fixed, center = jnp.stack([wi, wr]), jnp.stack([wr, wi])
    view = jnp.array([True, False])
    grids = jax.tree.map(lambda a, b: jnp.stack([a, b]), tuple(grid_r), tuple(grid_i))
    nodes = jax.vmap(lambda f, c, v, g: _side_nodes(brdf, vb, f, c, v, g, facets, y_full))(
        fixed, center, view, grids
    )
    lobes = [
        (nodes["i_p"], nodes["o_p"], nodes["hg"], nodes["alpha_h"]),
        (
            nodes["i_f"],
            nodes["o_f"],
            jnp.broadcast_to(facets[0], nodes["free"].shape),
            jnp.broadcast_to(facets[1], nodes["free"].shape[:-1]),
        ),
    ]
    phases = [nodes["omm"]]

    def weight(free, center, view):
        z = free[..., 2]
        w = jnp.where(view, medium.factor_first(vm, z), medium.factor_second(vm, z))
        if medium.has_view_weight():
            w = w * jnp.where(view, medium.view_weight(vm, free, center), 1.0)
        return w

    def side(center, view, grid, node, lobe_p, lobe_f, p_free, q_free, own_law):
        g, u, f, _ = grid
        total = jnp.sum(u * f * node["w_phase"] * lobe_p * weight(g, center, view))
        qh, uh = facets[3][0], facets[2][0]
        q_free = p_free if own_law else q_free  # the density of the phase grid's law
        den = q_free + qh / (4.0 * jnp.maximum(node["c_free"], 1e-300))
        ok = (node["c_free"] > 0) & (node["free"][..., 2] > 0) & (den > 0)
        val = jnp.where(
            ok, lobe_f * weight(node["free"], center, view) * p_free / jnp.where(ok, den, 1.0), 0.0
        )
        return total + jnp.sum(uh * val)

    def finish(lobe, phase, density):
        own_law = phase[0] is density[0]

        def one(*args):
            return side(*args, own_law)

        both = jax.vmap(one)(center, view, grids, nodes, lobe[0], lobe[1], phase[0], density[0])
        return both[0], both[1]

    return lobes, phases, finish
