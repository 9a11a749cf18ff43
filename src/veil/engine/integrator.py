"""The apparent reflectance of docs/model.md section 5 (paper eq. 1), by deterministic quadrature.

    f(I, R) = Int Int f_t(I, I') f_r(I', R') f_t(R', R) dI' dR'

With f_t = T_d + T_t a(.) b(.) p (:class:`veil.models.base.BTDF`) and
f_r = separable + lobe (:class:`veil.models.base.BRDF`) the product expands into terms of
very different difficulty, each integrated by the cheapest rule that is exact in the limit:

  T_d^2     C0 = Int Int f_r, a constant: albedo table over theta_I', once per call
  T_d T_t   a(I) Int b(I') p(I.I') A(I') dI'     2D phase grid about I, tabulated albedo A
  T_t T_d   b(R) Int a(R') p(R'.R) B(R') dR'     2D phase grid about R, tabulated albedo B
  T_t^2     separable part: products of two 2D phase-grid integrals
  T_t^2     lobe part: a 4D integral of three sharp factors, p(I.I'), the BRDF lobe and
            p(R'.R), by deterministic multiple-importance quadrature: three product grids
            (phase x half vector, half vector x phase, phase x phase), each evaluating the
            integrand times a balance weight, q_k / sum_j q_j, built from the untruncated
            densities of the three maps (any partition of unity is exact; this one makes the
            integrand smooth and bounded in every grid's coordinates).

Phase grids are truncated exactly at the horizon (per azimuth about I or R), and so are the
half-vector grids of the albedo tables (per azimuth, so that the reflected direction stays
above the horizon). The 4D term's half-vector grid is not truncated: where a reflected
direction falls below the horizon its integrand is set to zero, which is a discontinuity
only for an index-matched medium (eta_u = 1); otherwise the Fresnel transmittance and the
shadowing term already take the integrand to zero there. For configurations in the plane of
incidence the integrand is symmetric under y -> -y and only half of the azimuths are
evaluated. The models are evaluated at each term's nodes (:mod:`veil.engine.nodes`,
:mod:`veil.engine.lobe_terms`).
"""

from __future__ import annotations

import math

import numpy as np

from .._jax import jax, jnp
from . import lobe_terms
from .nodes import (
    HALF_PI,
    TWO_PI,
    channel_grid,
    facet_grids,
    half_grid,
    lobe_at,
    normalized,
    phase_grids,
    polar,
    reflect,
    separable_at,
)
from .quadrature import Rule, gauss_legendre_unit


# --------------------------------------------------------------------------------------
# albedo tables of the lobe (once per call)
# --------------------------------------------------------------------------------------
def _table_thetas(rule: Rule):
    """Table nodes theta = pi/2 (1 - (1 - v)^2), v uniform: twice as dense at the horizon,
    where the lobe's albedo rises steeply with the Fresnel factor."""
    v = np.linspace(0.0, 1.0, rule.table)
    return HALF_PI * (1.0 - (1.0 - v) ** 2)


def _table_coordinate(theta):
    return 1.0 - jnp.sqrt(jnp.maximum(1.0 - theta / HALF_PI, 0.0))


def _lobe_albedo_tables(brdf, vb, rule: Rule):
    """A(theta) = Int lobe(I', R') dR' and B(theta) = Int lobe(I', R') dI' on a theta grid."""
    th = np.minimum(_table_thetas(rule), HALF_PI - 1e-7)  # the limit at the horizon
    d = jnp.asarray(np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=-1))
    h, alpha, _, unit, y_max = half_grid(brdf, vb, d, rule.table_radial, rule.table_azimuth, True)
    other = reflect(d[:, None, :], h)
    din = jnp.broadcast_to(d[:, None, :], other.shape)
    c = jnp.sum(din * h, axis=-1)
    jac = unit[None, :] * 4.0 * c * y_max / brdf.facet_weight(vb, alpha)
    a_lobe, b_lobe = lobe_at(brdf, vb, [(din, other, h, alpha), (other, din, h, alpha)])
    return jnp.sum(jac * a_lobe, axis=-1), jnp.sum(jac * b_lobe, axis=-1)


def _interp_table(table, theta, rule: Rule):
    """Cubic Hermite (Catmull-Rom) interpolation of a table uniform in v (_table_thetas)."""
    k = rule.table
    x = jnp.clip(_table_coordinate(theta) * (k - 1), 0.0, k - 1 - 1e-9)
    i = jnp.floor(x).astype(int)
    t = x - i
    ext = jnp.concatenate([2 * table[:1] - table[1:2], table, 2 * table[-1:] - table[-2:-1]])
    p0, p1, p2, p3 = ext[i], ext[i + 1], ext[i + 2], ext[i + 3]
    m1 = 0.5 * (p2 - p0)
    m2 = 0.5 * (p3 - p1)
    t2, t3 = t * t, t * t * t
    return (
        (2 * t3 - 3 * t2 + 1) * p1
        + (t3 - 2 * t2 + t) * m1
        + (-2 * t3 + 3 * t2) * p2
        + (t3 - t2) * m2
    )


def _simpson_weights(k: int, step: float) -> np.ndarray:
    w = np.ones(k)
    w[1:-1:2] = 4.0
    w[2:-1:2] = 2.0
    return w * step / 3.0


def _shared(brdf, rule, vb, half: bool):
    """Per-call quantities that do not depend on the configuration: the BRDF's own tables
    (``prepare``), the albedo tables of its lobe, the hemisphere integrals of its
    separable factors, and the facet grids of the lobe terms (4D and dense)."""
    aux = brdf.prepare(vb)
    x, w = gauss_legendre_unit(64)  # Int over the upper hemisphere of an isotropic factor
    c = jnp.asarray(x)
    weights = TWO_PI * jnp.asarray(w)
    s_at, t_at = separable_at(brdf, vb, aux, [c], [c])
    s_int = [jnp.sum(weights * s[0]) for s in s_at]
    t_int = [jnp.sum(weights * t[0]) for t in t_at]
    if brdf.HAS_LOBE:
        a_tab, b_tab = _lobe_albedo_tables(brdf, vb, rule)
        facets = (
            *facet_grids(
                brdf,
                vb,
                [
                    (rule.half_radial, rule.half_azimuth, False),
                    (rule.dense_radial, rule.dense_azimuth, half),
                ],
            ),
            brdf.facet_cdf(vb, HALF_PI),
        )
    else:
        a_tab = b_tab = jnp.zeros(rule.table)
        facets = None
    th = _table_thetas(rule)
    v = np.linspace(0.0, 1.0, rule.table)
    sw = jnp.asarray(_simpson_weights(rule.table, v[1]) * np.sin(th) * math.pi * (1.0 - v))
    c0_sep = sum(s * t for s, t in zip(s_int, t_int)) + 0.0 * jnp.sum(a_tab)
    c0_lobe = TWO_PI * jnp.sum(sw * a_tab)
    return c0_sep, c0_lobe, a_tab, b_tab, s_int, t_int, aux, facets


def pairs(medium_cls) -> list[tuple[str, str]]:
    """The medium's rows: unordered pairs of its components (light side, view side), in
    the order of ``COMPONENTS``; a row collects both orders of a mixed pair."""
    comps = medium_cls.COMPONENTS
    return [(a, b) for i, a in enumerate(comps) for b in comps[i:]]


def _lobe_parts(brdf, medium, rule, half, vb, vm, maux, facets, wi, wr, grids, law=None):
    """The lobe's values of every lobe term of one configuration: the lobe and the phase
    function evaluated at each term's nodes (:mod:`.lobe_terms`), and the density of the
    grids' sampling ``law`` there when it is not the phase's own (channels sharing a law,
    :func:`apparent_terms_channels`; the phase held in a Jacobian, :func:`apparent_terms`).
    Returns {"lobe": 4D term, "sides": (view side, light side), "delta": lobe(I, R)}."""
    comps = medium.COMPONENTS
    parts = {}
    if "lobe" in comps:
        parts["lobe"] = lobe_terms.lobe_lobe(
            brdf, medium, vb, vm, wi, wr, half, grids[2:], facets[0], facets[2]
        )
    if "delta" in comps:
        h = normalized(wi + wr)
        parts["delta"] = ([(wi, wr, h, polar(h)[0])], [], lambda lobe, phase, law: lobe[0])
        if "lobe" in comps:
            parts["sides"] = lobe_terms.lobe_sides(
                brdf, medium, vb, vm, wi, wr, half, grids[0], grids[1], facets[1], facets[2]
            )
    if not parts:
        return {}
    lobes = lobe_at(brdf, vb, [r for req, _, _ in parts.values() for r in req])
    omm = [r for _, req, _ in parts.values() for r in req]
    phases = [medium.phase(vm, o, maux) for o in omm]
    densities = phases if law is None else [medium.phase(law[0], o, law[1]) for o in omm]
    out = {}
    for name, (req_l, req_p, finish) in parts.items():
        k = len(req_p)
        out[name] = finish(lobes[: len(req_l)], phases[:k], densities[:k])
        lobes, phases, densities = lobes[len(req_l) :], phases[k:], densities[k:]
    return out


def _one_config(brdf, medium, rule, half, vb, vm, shared, maux, wi, wr, law=None):
    """Term matrix E (rows, 2) of one configuration with the scale parameters set to 1.

    Rows: the medium's component pairs (:func:`pairs`: for the paper's medium T_d^2,
    T_d T_t, T_t^2), each with its components' weights; columns: the separable and lobe
    parts of f_r. ``law`` (vm, aux): the phase grids are drawn from it rather than from the
    medium's own phase (:func:`apparent_terms_channels`); (vm, aux, True): from the
    medium's own phase held constant (:func:`apparent_terms`).
    """
    c0_sep, c0_lobe, a_tab, b_tab, s_int, t_int, aux, facets = shared
    zero = 0.0 * c0_sep
    comps = medium.COMPONENTS
    a_i = medium.factor_first(vm, wi[2])  # a(I): the light's way into the medium
    b_i = medium.factor_second(vm, wi[2])  # b(I): the unscattered beam leaving it
    a_r = medium.factor_first(vm, wr[2])  # a(R): the unscattered view ray entering
    b_r = medium.factor_second(vm, wr[2])  # b(R): leaving towards the camera
    rows = {}

    def albedo(theta, table):
        return _interp_table(table, theta, rule) if brdf.HAS_LOBE else zero

    grids, cos_i, cos_r = _lobe_grids(brdf, medium, rule, half, vm, maux, wi, wr, law)
    # s_k at I and the I' nodes, t_k at R and the R' nodes
    s_at, t_at = separable_at(brdf, vb, aux, cos_i, cos_r)
    s_wi, t_wr = [s[0] for s in s_at], [t[0] for t in t_at]
    lobes = (
        _lobe_parts(brdf, medium, rule, half, vb, vm, maux, facets, wi, wr, grids, law)
        if brdf.HAS_LOBE
        else {}
    )
    if "iso" in comps:
        rows[("iso", "iso")] = (c0_sep, c0_lobe)
    if "lobe" in comps:
        (gi, ui, fi, _), (gr, ur, fr, _) = grids[:2]
        s_gi, t_gr = [s[1] for s in s_at], [t[1] for t in t_at]
        wgi = ui * fi * medium.factor_second(vm, gi[:, 2])
        wgr = (
            ur * fr * medium.factor_first(vm, gr[:, 2]) * lobe_terms.view_weight(medium, vm, gr, wr)
        )
        if "iso" in comps:
            # light lobe x view iso: a(I) Int b(I') p A(I'); light iso x view lobe: b(R) Int a J p B
            ti = jnp.arccos(jnp.clip(gi[:, 2], -1.0, 1.0))
            tr = jnp.arccos(jnp.clip(gr[:, 2], -1.0, 1.0))
            mixed_sep = a_i * jnp.sum(
                wgi * sum(s * tk for s, tk in zip(s_gi, t_int))
            ) + b_r * jnp.sum(wgr * sum(t * sk for t, sk in zip(t_gr, s_int)))
            mixed_lobe = a_i * jnp.sum(wgi * albedo(ti, a_tab)) + b_r * jnp.sum(
                wgr * albedo(tr, b_tab)
            )
            rows[("iso", "lobe")] = (mixed_sep, mixed_lobe)
        sep = sum(jnp.sum(wgi * s) * jnp.sum(wgr * t) for s, t in zip(s_gi, t_gr))
        rows[("lobe", "lobe")] = (a_i * b_r * sep, a_i * b_r * lobes.get("lobe", zero))
    if "delta" in comps:
        dl, dv = a_i * b_i, a_r * b_r
        f_sep = sum(s * t for s, t in zip(s_wi, t_wr)) + zero
        rows[("delta", "delta")] = (dl * dv * f_sep, dl * dv * lobes.get("delta", zero))
        if "iso" in comps:  # the unscattered beam on one side, the iso part on the other
            iso_sep = dl * sum(s * tk for s, tk in zip(s_wi, t_int)) + dv * sum(
                t * sk for t, sk in zip(t_wr, s_int)
            )
            iso_lobe = dl * albedo(jnp.arccos(jnp.clip(wi[2], -1.0, 1.0)), a_tab) + dv * albedo(
                jnp.arccos(jnp.clip(wr[2], -1.0, 1.0)), b_tab
            )
            rows[("delta", "iso")] = (iso_sep + zero, iso_lobe + zero)
        if "lobe" in comps:  # the unscattered beam on one side, the lobe on the other
            d_sep = dl * b_r * sum(
                s * jnp.sum(wgr * t) for s, t in zip(s_wi, t_gr)
            ) + dv * a_i * sum(t * jnp.sum(wgi * s) for t, s in zip(t_wr, s_gi))
            view_side, light_side = lobes.get("sides", (zero, zero))
            rows[("delta", "lobe")] = (
                d_sep + zero,
                dl * b_r * view_side + dv * a_i * light_side + zero,
            )
    return _weighted_rows(medium, vm, rows)


def _lobe_grids(brdf, medium, rule, half, vm, maux, wi, wr, law=None):
    """(grids, cosines at I and its nodes, at R and its nodes) of :func:`_one_config`:
    without the medium's lobe no grids; with it the 2D terms' dense grids about I (I') and
    about R (R'), and the 4D term's grids; drawn from ``law`` when given
    (:func:`veil.engine.nodes.channel_grid`)."""
    if "lobe" not in medium.COMPONENTS:
        return None, [wi[2]], [wr[2]]
    specs = [
        (wi, rule.dense_radial, rule.dense_azimuth, half),
        (wr, rule.dense_radial, rule.dense_azimuth, half),
    ]
    if brdf.HAS_LOBE:
        specs += [
            (wi, rule.phase_radial, rule.phase_azimuth, half),
            (wr, rule.phase_radial, rule.phase_azimuth, False),
        ]
        specs += [(wr, rule.phase_radial, rule.phase_azimuth, True)] if half else []
    if law is None:
        grids = phase_grids(medium, vm, maux, specs)
    else:
        grids = [
            channel_grid(medium, vm, maux, spec[0], grid, own=len(law) > 2)
            for spec, grid in zip(specs, phase_grids(medium, law[0], law[1], specs))
        ]
    return grids, [wi[2], grids[0][0][:, 2]], [wr[2], grids[1][0][:, 2]]


def _weighted_rows(medium, vm, rows: dict):
    """The term matrix (rows, 2): each component pair's row times its weights."""
    out = []
    for a, b in pairs(medium):
        sep_v, lobe_v = rows[(a, b)] if (a, b) in rows else rows[(b, a)]
        w = medium.weight(vm, a) * medium.weight(vm, b)
        out.append(jnp.stack([w * sep_v, w * lobe_v]))
    return jnp.stack(out)


#: The parts of a BRDF (columns of a term matrix), as models name them in ``SCALES``.
BRDF_PARTS = ("separable", "lobe")


def unit_scale_indices(model) -> tuple[int, ...]:
    """The indices of a model's scale parameters and its gain: the term matrices are computed
    with these at 1 (:func:`_unit_scales`), so they do not depend on them."""
    out = [model.scale_index(part) for part in model.SCALES]
    gain = getattr(model, "GAIN", None)
    if gain is not None:
        out.append(model.param_names().index(gain))
    return tuple(out)


def _unit_scales(model, v):
    for i in unit_scale_indices(model):
        v = v.at[i].set(1.0)
    return v


def _scale(model, v, part):
    i = model.scale_index(part)
    return 1.0 if i is None else v[i]


def _gain(medium_cls, vm):
    return 1.0 if medium_cls.GAIN is None else vm[medium_cls.param_names().index(medium_cls.GAIN)]


def row_scales(medium_cls, vm):
    """The rows' weights from the medium's scale parameters: s_a s_b for each component pair
    (:func:`pairs`; a component without a scale counts 1), times the gain; numpy."""
    vm = np.asarray(vm, dtype=float)
    s = {c: float(_scale(medium_cls, vm, c)) for c in medium_cls.COMPONENTS}
    gain = float(_gain(medium_cls, vm))
    return np.array([s[a] * s[b] * gain for a, b in pairs(medium_cls)])


def row_scale_derivative(medium_cls, vm, index: int) -> np.ndarray:
    """d row_scales / d parameter ``index`` of the medium (a scale or the gain)."""
    vm = np.asarray(vm, dtype=float)
    s = {c: float(_scale(medium_cls, vm, c)) for c in medium_cls.COMPONENTS}
    gain = float(_gain(medium_cls, vm))
    names = medium_cls.param_names()
    if medium_cls.GAIN is not None and names[index] == medium_cls.GAIN:
        return np.array([s[a] * s[b] for a, b in pairs(medium_cls)])
    comp = [c for c, n in medium_cls.SCALES.items() if n == names[index]]
    if not comp:
        raise ValueError(f"{names[index]} is not a scale of {medium_cls.NAME}")
    c = comp[0]
    return np.array(
        [
            gain * ((s[b] if a == c else 0.0) + (s[a] if b == c else 0.0))
            for a, b in pairs(medium_cls)
        ]
    )


def column_scales(brdf_cls, vb):
    """The BRDF's column weights (separable, lobe) from its scale parameters."""
    return np.array([float(_scale(brdf_cls, vb, part)) for part in BRDF_PARTS])


def combine_terms(brdf_cls, medium_cls, terms, vb, vm):
    """Apparent reflectance from the term matrices (..., rows, 2) and the scale parameters."""
    s = {c: _scale(medium_cls, vm, c) for c in medium_cls.COMPONENTS}
    rows = jnp.stack([s[a] * s[b] * jnp.ones(()) for a, b in pairs(medium_cls)])
    rows = rows * _gain(medium_cls, vm)
    cols = jnp.stack([_scale(brdf_cls, vb, part) * jnp.ones(()) for part in BRDF_PARTS])
    return jnp.einsum("...mb,m,b->...", terms, rows, cols)


def apparent_terms(
    brdf_template,
    medium_template,
    rule,
    vb,
    vm,
    wi,
    wr,
    half=False,
    batch_size=None,
    hold_phase_grids=False,
    phase_grids_at=None,
):
    """Term matrices (M, rows, 2) for unit direction arrays (M, 3); see :func:`_one_config`.

    Pure JAX and differentiable in the non-scale parameters of ``vb`` and ``vm``.
    ``half=True`` is valid only when every configuration lies in the xz plane.

    The phase grids (docs/engine.md "Derivatives") are drawn from the medium's phase at
    ``vm``, or at the medium vector ``phase_grids_at``, each node then weighted by the phase
    at ``vm`` over the density it was drawn from. ``hold_phase_grids`` draws them at ``vm``
    held constant (``stop_gradient``): the values are the default's (within rounding), and
    derivatives in the medium's parameters are those of the quadrature whose nodes stay
    where they are (the Jacobian programs).
    """
    if hold_phase_grids and phase_grids_at is not None:
        raise ValueError("hold_phase_grids and phase_grids_at exclude each other")
    brdf, mcls = brdf_template, type(medium_template)  # options select the code paths
    vb1 = _unit_scales(type(brdf), jnp.asarray(vb))
    vm1 = _unit_scales(mcls, jnp.asarray(vm))
    shared = _shared(brdf, rule, vb1, half)
    maux = medium_template.prepare(vm1)
    law = None
    if hold_phase_grids:  # the medium's own law: p / q taken as exactly 1
        held = jax.tree.map(lambda a: jax.lax.stop_gradient(a) if _is_array(a) else a, maux)
        law = (jax.lax.stop_gradient(vm1), held, True)
    elif phase_grids_at is not None:
        at = _unit_scales(mcls, jnp.asarray(phase_grids_at))
        law = (at, medium_template.prepare(at))

    def f(x):
        return _one_config(
            brdf, medium_template, rule, half, vb1, vm1, shared, maux, x[0], x[1], law
        )

    if batch_size is None:  # keep the live intermediate arrays to a few hundred MB
        batch_size = _batch(wi.shape[0], 1_500_000 // rule.points_per_config)
    return jax.lax.map(f, (wi, wr), batch_size=batch_size)


def _is_array(a) -> bool:
    return isinstance(a, (jax.Array, np.ndarray, float, int))


def channel_law(medium_template, vms):
    """The medium's sampling law (vm, aux) of the channels ``vms`` (C, n), their scale
    parameters at 1 (``Medium.sampling_law``)."""
    mcls = type(medium_template)
    unit = jax.vmap(lambda v: _unit_scales(mcls, v))(jnp.asarray(vms))
    return medium_template.sampling_law(unit)


def apparent_terms_channels(
    brdf_template, medium_template, rule, vb, vms, wi, wr, half=False, law=None
):
    """Term matrices (M, C, rows, 2) of C channels that share the BRDF's non-scale
    parameters ``vb`` and differ in the medium's (rows of ``vms``), the scale parameters set
    to 1 (docs/channels.md, "Cost").

    The phase grids of every channel are drawn from one sampling law (``law``, (vm, aux);
    by default the medium's ``sampling_law`` of the channels), each channel's phase
    weighting its nodes (:func:`veil.engine.nodes.channel_grid`), so that the BRDF, the
    expensive factor, is evaluated once at nodes every channel shares; only the medium's
    factors are per channel. Each channel's terms are the quadrature of eq. (1) with that
    law in place of its own phase: equal to :func:`apparent_terms` within the rule's error.
    """
    brdf, mcls = brdf_template, type(medium_template)
    vb1 = _unit_scales(type(brdf), jnp.asarray(vb))
    vms1 = jax.vmap(lambda v: _unit_scales(mcls, v))(jnp.asarray(vms))
    shared = _shared(brdf, rule, vb1, half)
    if law is None:
        law = channel_law(medium_template, vms)
    mauxs = jax.vmap(medium_template.prepare)(vms1)

    def f(x):
        def channel(vm1, maux):
            return _one_config(
                brdf, medium_template, rule, half, vb1, vm1, shared, maux, x[0], x[1], law
            )

        return jax.vmap(channel)(vms1, mauxs)

    # the live arrays of C channels per configuration: C times fewer configurations at once
    limit = 1_500_000 // (rule.points_per_config * vms1.shape[0])
    return jax.lax.map(f, (wi, wr), batch_size=_batch(wi.shape[0], limit))


def _batch(n: int, limit: int) -> int:
    """The largest divisor of ``n`` up to ``limit`` (at least 1): a batch that leaves no
    remainder, which lax.map would compile as a second copy of the body."""
    return max(b for b in range(1, max(1, min(n, limit)) + 1) if n % b == 0)


_TEMPLATES: dict = {}


def template(model):
    """The cached template instance for a model's structure (static options only)."""
    return _TEMPLATES.setdefault(model.structure(), model)


def template_for(structure):
    """The template instance registered for a model structure (see :func:`template`)."""
    return _TEMPLATES[structure]
