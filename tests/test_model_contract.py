"""The contract every registered model family passes (docs/architecture.md, "Adding a model").

For each family: its parameter vector round-trips; its bounds reject what they must; its
sampling maps and their inverses agree and its weights are the derivatives of its
cumulatives; the parts the engine integrates sum to the model's value computed
independently (the formulas below, written from docs/model.md, not from veil); the engine's exact
Jacobian agrees with central differences; and the engine agrees with a brute-force
integral at a few configurations. Adding a family is its module, a registry line, and an
entry in INDEPENDENT (and BRUTE_FORCE) here.

The test-only families of tests/plugins/veil_test_models.py prove that the registry is
real: they run through every command without a line of veil changed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import veil_test_models  # noqa: F401  (registers the test-only families)

import reference as ref
import reference_physical as rphys
from support.held_nodes import held_values
from veil.engine.evaluator import CHUNK
from veil.engine.forward import Forward
from veil.engine.quadrature import RULES
from veil.models import REGISTRY, default_class

FAMILIES = sorted(REGISTRY)


# --------------------------------------------------------------------------------------
# independent values, from docs/model.md (and the test models' docstrings)
# --------------------------------------------------------------------------------------
def _angles(w):
    theta = np.degrees(np.arccos(np.clip(w[..., 2], -1, 1)))
    phi = np.degrees(np.arctan2(w[..., 1], w[..., 0]))
    return theta, phi


def _ts(model, wi, wo):
    ti, pi_ = _angles(wi)
    tr, pr = _angles(wo)
    return ref.reference_reflectance(tuple(model.to_vector()), ti, pi_, tr, pr)


def _hg(model, wa, wb):
    ta, pa = _angles(wa)
    tb, pb = _angles(wb)
    return ref.reference_btdf(tuple(model.to_vector()), ta, pa, tb, pb, model.variant)


def _lambert(model, wi, wo):
    ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return np.where(ok, model.rho * wi[..., 2] / math.pi, 0.0)


def _fisher_phase(kappa, one_minus_mu):
    return kappa * np.exp(-kappa * one_minus_mu) / (2 * math.pi * -np.expm1(-2 * kappa))


def _fisher(model, wa, wb):
    x = 1.0 - np.sum(wa * wb, axis=-1)
    return model.Td + model.Tt * _fisher_phase(model.kappa, x)


def _forward_series(model, wa, wb):
    """The scattered part of docs/model.md 8.1's f_t (the delta is a distribution): e^{-tau}
    sum_k w_k p(g^k) with the Fresnel factors of sec. 3 (reference_physical's pieces)."""
    x = 0.5 * np.sum((wa - wb) ** 2, axis=-1)
    lobe = rphys.scattered_lobe(model.tau, model.omega, model.g, x=x)
    ta = 1.0 - rphys.fresnel_dielectric(wa[..., 2], model.eta_u)
    tb = 1.0 - rphys.fresnel_dielectric(wb[..., 2], model.eta_u)
    a, b = (ta * ta, 1.0) if model.variant == "paper" else (ta, tb)
    return math.exp(-model.tau) * lobe * a * b


def _rough_plastic(model, wi, wo):
    """tests/reference_physical.py (docs/model.md sec. 8.2 in numpy, t and F_int as converged
    integrals, exact Smith G1)."""
    return rphys.rough_plastic_vec(wi, wo, model.rho, model.alpha, model.eta, model.ks,
                                  model.distribution, model.nonlinear, smith="exact",
                                  tables="exact")


def _rough_conductor(model, wi, wo):
    return rphys.rough_conductor_vec(wi, wo, model.alpha, model.ks, n=model.n, k=model.k,
                                    distribution=model.distribution, smith="exact")


def _nonparametric(model, wi, wo):
    """docs/model.md sec. 8.4 in numpy: the Bernstein diffuse basis in x = (1 - cos)^5 and a
    Beckmann lobe per width with a Fresnel curve linear in theta_d between its nodes
    (reference_physical's D and exact Smith G1)."""
    from veil.models.nonparametric import FRESNEL_DEGREES, WIDTHS

    ci, co = wi[..., 2], wo[..., 2]
    xi, xo = (1 - np.clip(ci, 0, 1)) ** 5, (1 - np.clip(co, 0, 1)) ** 5
    d0, d1, d2 = model.d0, model.d1, model.d2
    diffuse = ci / math.pi * (d0 * (1 - xi) * (1 - xo) + d1 * (xi * (1 - xo) + (1 - xi) * xo)
                              + d2 * xi * xo)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    theta_d = np.degrees(np.arccos(np.clip(np.sum(wo * h, axis=-1), -1, 1)))
    lobe = 0.0
    for k, alpha in enumerate(WIDTHS):
        curve = np.interp(theta_d, FRESNEL_DEGREES,
                          [getattr(model, f"w{k:02d}_{m}") for m in range(len(FRESNEL_DEGREES))])
        lobe = lobe + rphys._specular(wi, wo, alpha, "beckmann", "exact", lambda c: curve)
    return np.where((ci > 0) & (co > 0), diffuse + lobe, 0.0)


INDEPENDENT = {"torrance-sparrow": _ts, "henyey-greenstein": _hg,
               "lambertian-test": _lambert, "fisher-test": _fisher,
               "forward-series": _forward_series,
               "rough-plastic": _rough_plastic, "rough-conductor": _rough_conductor,
               "nonparametric": _nonparametric}


#: Instances of families without a preset, away from points where the model is not smooth
#: (the forward series at eta_u = 1, where total internal reflection starts on one side).
INSTANCES = {"forward-series": dict(tau=0.8, omega=0.95, g=0.9, eta_u=1.2, s=1.5),
             # a narrow lobe and a broad one with rising Fresnel curves, over a diffuse base
             "nonparametric": dict(d0=0.4, d1=0.2, d2=0.1, w02_0=0.3, w02_1=0.35, w02_3=1.0,
                                   w09_0=0.05, w09_2=0.2)}
#: Relative tolerance of the model against its independent value where the model itself
#: is a quadrature (default 1e-9; a medium's TABLE_ACCURACY if larger): rough-plastic
#: tabulates t(mu) and F_int (measured worst 6e-6 on these directions, docs/physics.md).
INDEPENDENT_RTOL = {"rough-plastic": 5e-5}


def _instance(name):
    """A non-trivial instance of the family: its preset if it has one, one of INSTANCES,
    else its template with the scales moved off 1."""
    cls = REGISTRY[name]
    if name in INSTANCES:
        return cls.template().replace(**INSTANCES[name])
    for model in veil_presets():
        if type(model) is cls:
            return model
    model = cls.template()
    return model.replace(**{n: getattr(model, n) * 3.0 for n in cls.scale_names()})


def veil_presets():
    from veil.models import PRESETS

    return list(PRESETS.values())


def _directions(n, seed, upper=True):
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if upper:
        v[:, 2] = np.abs(v[:, 2]) + 1e-3
        v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v


def test_every_family_has_an_independent_value():
    missing = [n for n in FAMILIES if n not in INDEPENDENT]
    assert not missing, f"add an independent formula for {missing} to INDEPENDENT"


# --------------------------------------------------------------------------------------
# declarations
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", FAMILIES)
def test_vector_and_dict_round_trip(name):
    model = _instance(name)
    cls = type(model)
    assert model.with_vector(model.to_vector()) == model
    assert cls.from_params(model.as_dict(), model.options()) == model
    assert list(model.as_dict()) == list(cls.param_names())
    assert model.to_vector().shape == (len(cls.PARAMS),)
    assert cls.template().structure() == cls.template().structure()
    for p in cls.PARAMS:
        assert cls.param(p.key) is p and cls.index(p.name) == cls.PARAMS.index(p)


@pytest.mark.parametrize("name", FAMILIES)
def test_bounds_reject_outside_values(name):
    from veil.errors import ParameterError

    cls = REGISTRY[name]
    model = cls.template()
    for p in cls.PARAMS:
        for bound, is_open, step in ((p.lower, p.lower_open, -1), (p.upper, p.upper_open, 1)):
            if not math.isfinite(bound):
                continue
            outside = bound + step * max(abs(bound), 1.0) * 1e-3
            with pytest.raises(ParameterError, match=p.name):
                model.replace(**{p.name: outside})
            if is_open:
                with pytest.raises(ParameterError):
                    model.replace(**{p.name: bound})
            else:
                model.replace(**{p.name: bound})  # a closed bound is allowed
        with pytest.raises(ParameterError):
            model.replace(**{p.name: math.nan})


@pytest.mark.parametrize("name", FAMILIES)
def test_starting_grids_lie_inside_the_bounds(name):
    cls = REGISTRY[name]
    for role, grid in cls.START.items():
        for pname, values in grid.items():
            p = cls.param(pname)
            inside = [v for v in values if p.contains(v)]
            assert inside, f"{name} START[{role}][{pname}] has no value inside {p.interval()}"


@pytest.mark.parametrize("name", FAMILIES)
def test_every_parameter_declares_whether_it_is_per_channel_or_shared(name):
    """Colour (docs/channels.md): a family says which of its parameters take one
    value per channel (albedos, scales, a medium's optical depth and albedo) and which one
    value tied across the channels (roughness, index, g) - ``Param(channels=...)``."""
    cls = REGISTRY[name]
    undeclared = [p.name for p in cls.PARAMS if p.channels is None]
    assert not undeclared, (f"{name}: declare channels='per-channel' or 'shared' for "
                            f"{', '.join(undeclared)}")
    sharing = cls.channel_sharing()
    for scale in cls.scale_names():  # a linear scale is an albedo: one per channel
        assert sharing[scale] == "per-channel", (name, scale)
    # a linear family's coefficients are all albedo-like (docs/nonparametric.md)
    assert "shared" in sharing.values() or len(cls.PARAMS) == 1 or cls.LINEAR, name


@pytest.mark.parametrize("name", FAMILIES)
def test_a_declared_model_error_is_a_relative_error_and_a_length(name):
    floor = REGISTRY[name].MODEL_ERROR_FLOOR
    if floor is not None:
        s, ell = floor
        assert 0.0 < s < 0.5 and math.isfinite(ell) and ell >= 0.0, (name, floor)


# --------------------------------------------------------------------------------------
# sampling maps and weights
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", [n for n in FAMILIES
                                  if REGISTRY[n].KIND == "brdf" and REGISTRY[n].HAS_LOBE])
def test_facet_maps_invert_and_weights_are_densities(name):
    model = _instance(name)
    v = np.asarray(model.to_vector())
    cls = model  # the instance: its functions may read its options
    top = float(cls.facet_cdf(v, math.pi / 2))
    y = np.linspace(0.01, 0.99, 41) * top
    alpha = np.asarray(cls.facet_inverse_cdf(v, y))
    assert np.allclose(np.asarray(cls.facet_cdf(v, alpha)), y, rtol=1e-9, atol=1e-12 * top)
    a = np.linspace(0.02, 1.4, 30)
    h = 1e-6
    numeric = (np.asarray(cls.facet_cdf(v, a + h)) - np.asarray(cls.facet_cdf(v, a - h))) / (2 * h)
    weight = np.asarray(cls.facet_weight(v, a)) * 2 * math.pi * np.sin(a)
    assert np.allclose(weight, numeric, rtol=1e-5, atol=1e-9 * np.max(np.abs(numeric)))


@pytest.mark.parametrize("name", [n for n in FAMILIES
                                  if REGISTRY[n].KIND == "medium" and REGISTRY[n].has("lobe")])
def test_phase_maps_invert_and_integrate_to_one(name):
    model = _instance(name)
    v = np.asarray(model.to_vector())
    tol = max(model.TABLE_ACCURACY, 1e-9)  # tabulated phase functions declare their accuracy
    frac = np.linspace(0.01, 0.99, 41)
    omm = np.asarray(model.phase_inverse_cone_fraction(v, frac))
    assert np.allclose(np.asarray(model.phase_cone_fraction(v, omm)), frac, rtol=tol, atol=1e-12)
    assert float(model.phase_cone_fraction(v, 2.0)) == pytest.approx(1.0, rel=max(tol, 1e-12))
    assert float(model.phase_cone_fraction(v, 0.0)) == pytest.approx(0.0, abs=1e-15)
    # d (cone fraction) / d (1 - cos gamma) = 2 pi p: the solid angle of a cone is 2 pi (1 - cos)
    x = np.concatenate([np.geomspace(1e-6, 1e-2, 20), np.linspace(0.02, 1.9, 20)])
    h = 1e-7 * np.maximum(x, 1e-4)
    numeric = (np.asarray(model.phase_cone_fraction(v, x + h))
               - np.asarray(model.phase_cone_fraction(v, x - h))) / (2 * h)
    assert np.allclose(2 * math.pi * np.asarray(model.phase(v, x)), numeric, rtol=max(1e-5, tol))


# --------------------------------------------------------------------------------------
# the engine's decomposition sums to the model's value
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", FAMILIES)
def test_parts_sum_to_the_independent_value(name):
    model = _instance(name)
    v = np.asarray(model.to_vector())
    wa, wb = _directions(400, 1), _directions(400, 2)
    if model.KIND == "medium":  # f_t also between nearby directions, where the lobe lives
        near = wa + 0.05 * _directions(400, 3, upper=False)
        near /= np.linalg.norm(near, axis=1, keepdims=True)
        wa, wb = np.concatenate([wa, wa]), np.concatenate([wb, near])
        wb[:, 2] = np.abs(wb[:, 2])
    got = np.asarray(model.evaluate(v, wa, wb))
    want = INDEPENDENT[name](model, wa, wb)
    tol = max(getattr(model, "TABLE_ACCURACY", 0.0), INDEPENDENT_RTOL.get(name, 1e-9))
    assert np.allclose(got, want, rtol=tol, atol=1e-12 * np.max(np.abs(want)))


# --------------------------------------------------------------------------------------
# the engine: Jacobians and a brute-force integral
# --------------------------------------------------------------------------------------
#: The physical families are paired with each other, in the validation data's set-up (one
#: pass 15, plate 5 wide: validation/README.md), as the physical pipeline fits them: their
#: engine programs are then the ones test_compare's pipeline compiles (the program store
#: builds each once for the suite) and the finite-plate weighting is in the checked Jacobian.
PHYSICAL_PARTNERS = {"forward-series": "rough-plastic", "rough-plastic": "forward-series"}
SET_UP = {"path_length": 15.0, "plate_width": 5.0}


def _pair(name):
    """The family paired with the paper's model of the other kind (a physical family with
    the other physical family, PHYSICAL_PARTNERS)."""
    model = _instance(name)
    if name in PHYSICAL_PARTNERS:
        partner = _instance(PHYSICAL_PARTNERS[name])
    else:
        partner = _instance(default_class("medium" if model.KIND == "brdf" else "brdf").NAME)
    brdf, medium = (model, partner) if model.KIND == "brdf" else (partner, model)
    if name in PHYSICAL_PARTNERS:
        medium = medium.replace(**SET_UP)
    return brdf, medium


#: The coefficients of the linear family whose Jacobian column is checked (a diffuse one, a
#: narrow and a broad width at three Fresnel nodes, zero and non-zero ones): its 55 columns
#: run one function per width and node, and all of them took 240 s of the suite.
LINEAR_CHECKED = ("d1", "w02_0", "w02_3", "w09_1", "w09_2")


@pytest.mark.parametrize("name", FAMILIES)
def test_engine_jacobian_matches_central_differences(name):
    """In every parameter of the family (its partner has its own case: the Jacobian in the
    partner's parameters too would double the compilation): the central differences of the
    quadrature whose phase grids stay where the Jacobian's point put them (docs/engine.md
    "Derivatives"), and within the rule's error of those of the engine's values, whose grids move."""
    brdf, medium = _pair(name)
    # the fits' chunk (64 configurations in the plane of incidence, "fast"): the program is
    # the one step 1 (a medium family) or step 2 (a BRDF family) iterates with, compiled
    # once for the suite whichever test comes first
    ti, tr = np.linspace(5.0, 75.0, CHUNK), np.linspace(70.0, 10.0, CHUNK)
    fwd = Forward(brdf, medium, ti, tr, rule=RULES["fast"])
    vb, vm = brdf.to_vector(), medium.to_vector()
    nb, nm = len(vb), len(vm)
    own_b = _instance(name).KIND == "brdf"
    free_b, free_m = (tuple(range(nb)), ()) if own_b else ((), tuple(range(nm)))
    if brdf.LINEAR:  # every coefficient enters by the same code: two widths, three nodes
        free_b = tuple(brdf.index(n) for n in LINEAR_CHECKED)
    value, jac = fwd.value_and_jacobian(vb, vm, free_b, free_m)
    assert np.allclose(value, fwd(vb, vm), rtol=1e-12)
    assert jac.shape == (len(ti), len(free_b) + len(free_m))
    held = fwd if brdf.LINEAR else held_values(fwd, vm)
    # the same quadrature at the point its grids were drawn at (p / q = 1 within the phase
    # table's interpolation, 3e-7 for forward-series)
    assert np.allclose(held(vb, vm), value, rtol=1e-6)
    for col, k in enumerate(list(free_b) + [nb + i for i in free_m]):
        x = np.concatenate([vb, vm])
        h = 1e-5 * max(abs(x[k]), 1e-3)
        up, down = x.copy(), x.copy()
        up[k] += h
        down[k] -= h
        numeric = (held(up[:nb], up[nb:]) - held(down[:nb], down[nb:])) / (2 * h)
        scale = np.max(np.abs(numeric)) + 1e-300
        close = np.isclose(jac[:, col], numeric, rtol=1e-4, atol=1e-6 * scale)
        assert np.all(close), (name, k, np.flatnonzero(~close))
        # the engine's values, grids moving with the parameter: a derivative of the same
        # integral, different by the quadrature's error of the derivative (the fast rule's
        # Jacobian differs from the default rule's by up to 3.5 % of a column's scale)
        moving = (fwd(up[:nb], up[nb:]) - fwd(down[:nb], down[nb:])) / (2 * h)
        off = np.abs(jac[:, col] - moving) / (np.max(np.abs(moving)) + 1e-300)
        assert off.max() <= 0.05 and np.median(off) <= 0.02, (name, k, off.max())


def _sphere_integral(fn, center, density_cone, n_r=1200, n_a=256):
    """Int over the upper hemisphere of fn(d) (d unit vectors), in coordinates about
    ``center``: u = the lobe's cone fraction (``density_cone`` maps u to 1 - cos), beta the
    azimuth; a plain midpoint rule (the check is slow and simple on purpose)."""
    u = (np.arange(n_r) + 0.5) / n_r
    beta = 2 * math.pi * (np.arange(n_a) + 0.5) / n_a
    omm, jac = density_cone(u)
    c = np.asarray(center, dtype=float)
    t1 = np.cross(c, [0.0, 1.0, 0.0] if abs(c[1]) < 0.9 else [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(c, t1)
    s = np.sqrt(np.maximum(omm * (2 - omm), 0))
    d = ((1 - omm)[:, None, None] * c + s[:, None, None]
         * (np.cos(beta)[None, :, None] * t1 + np.sin(beta)[None, :, None] * t2))
    val = np.where(d[..., 2] > 0, fn(d), 0.0)
    return float(np.sum(val * jac[:, None]) / (n_r * n_a) * 2 * math.pi)


def _lambertian_through(brdf, medium, wi, wr):
    """f = rho/pi [Int f_t(I, I') cos I' dI'] [Int f_t(R', R) dR'] for a Lambertian surface:
    the isotropic part of f_t in closed form (pi iso, 2 pi iso), the lobe's by a hemisphere
    integral about its axis."""
    iso = float(medium.iso(medium.to_vector()))
    medium = medium.replace(**{medium.SCALES["iso"]: 0.0})
    v = np.asarray(medium.to_vector())

    def cone(u):  # u -> 1 - cos, with d(1 - cos)/du; cone fraction of the lobe
        omm = np.asarray(medium.phase_inverse_cone_fraction(v, u))
        dens = 2 * math.pi * np.asarray(medium.phase(v, omm))
        return omm, 1.0 / dens

    def ft(a, b):
        return np.asarray(medium.evaluate(v, np.broadcast_to(a, b.shape), b))

    a = math.pi * iso + _sphere_integral(lambda d: ft(wi, d) * d[..., 2], wi, cone)
    b = 2 * math.pi * iso + _sphere_integral(lambda d: np.asarray(medium.evaluate(
        v, d, np.broadcast_to(wr, d.shape))), wr, cone)
    return brdf.rho / math.pi * a * b


def _ts_fn(brdf):
    """The paper's f_r from tests/reference.py as brdf_fn(wi, wo) of reference_physical."""
    def fn(wi, wo):
        return _ts(brdf, wi, wo)
    fn.sampling_alpha = math.radians(math.sqrt(math.log(2)) / brdf.n)
    return fn


@pytest.mark.parametrize("options", [{}, {"variant": "exit", "eta_u": 1.33},
                                     {"path_length": 15.0, "plate_width": 5.0}])
def test_forward_series_engine_matches_the_independent_reference(options):
    """docs/model.md 8.1 through eq. (1): the delta, 2-D and 4-D terms, the Fresnel variants and
    the finite plate's view weighting, against tests/reference_physical.py (Gauss rules and
    QMC with MIS, written from docs/model.md alone)."""
    brdf = ref_preset("BRDF2")
    values = dict(tau=1.0, omega=0.99, g=0.88, eta_u=1.0)
    values.update({k: v for k, v in options.items() if k in ("eta_u",)})
    opts = {k: v for k, v in options.items() if k != "eta_u"}
    medium = REGISTRY["forward-series"].from_params({**values, "s": 1.0}, opts)
    ti, tr = np.array([20.0, 60.0]), np.array([25.0, 10.0])
    got = Forward(brdf, medium, ti, tr, rule=RULES["default"])(brdf.to_vector(),
                                                                 medium.to_vector())
    for k in range(ti.size):
        want, se = rphys.forward_series_apparent(
            _ts_fn(brdf), values["tau"], values["omega"], values["g"], values["eta_u"], ti[k],
            tr[k], variant=opts.get("variant", "paper"), path_length=opts.get("path_length"),
            plate_half_width=opts.get("plate_width", 0) / 2 or None, n_qmc=2 ** 12, n_rep=6)
        assert abs(got[k] - want) <= 4 * se + 1e-3 * want, (k, got[k], want, se)


@pytest.mark.parametrize("g", [0.0, 0.3, 0.88, 0.95, 0.99, 0.995])
def test_forward_series_phase_tables_hold_their_accuracy_over_the_parameter_range(g):
    """The tabulated scattered lobe (density, cone fraction, sampling map and the density it
    returns with it) against the closed-form series of docs/model.md 8.1, within TABLE_ACCURACY,
    from a single order's narrow peak to the broad tail of many orders."""
    cls = REGISTRY["forward-series"]
    tol = cls.TABLE_ACCURACY
    omm = np.concatenate([np.geomspace(1e-10, 1e-2, 300), np.linspace(0.01, 2.0, 300)])
    frac = np.concatenate([np.geomspace(1e-4, 1e-2, 30), np.linspace(0.01, 0.999, 300)])
    for tau in (0.02, 1.0, 3.0):
        model = cls(tau=tau, omega=0.99, g=g)
        v = np.asarray(model.to_vector())
        x = tau * 0.99
        norm = math.expm1(x)
        pdf = rphys.scattered_lobe(tau, 0.99, g, x=omm) / norm
        w = rphys.series_weights(tau, 0.99) / norm

        def cone(o):  # sum_k w_k F_HG(g^k; o), F_HG = (1 + g) o / (s (s + 1 - g))
            total = 0.0
            for k, wk in enumerate(w, start=1):
                gk = g ** k
                sk = np.sqrt((1 - gk) ** 2 + 2 * gk * o)
                total = total + wk * (1 + gk) * o / (sk * (sk + 1 - gk))
            return total
        assert np.allclose(np.asarray(model.phase(v, omm)), pdf, rtol=tol, atol=0), tau
        assert np.allclose(np.asarray(model.phase_cone_fraction(v, omm)), cone(omm),
                           rtol=tol, atol=1e-12), tau
        o, p = (np.asarray(a) for a in model.phase_sample(v, frac * cone(2.0)))
        assert np.allclose(cone(o), frac * cone(2.0), rtol=tol, atol=1e-12), tau
        assert np.allclose(p, rphys.scattered_lobe(tau, 0.99, g, x=o) / norm, rtol=tol), tau


def ref_preset(name):
    from veil.models import PRESETS

    return PRESETS[name]


@pytest.mark.parametrize("pair", ["lambertian-test:henyey-greenstein",
                                  "lambertian-test:fisher-test",
                                  "torrance-sparrow:fisher-test"])
def test_engine_matches_a_brute_force_integral(pair):
    bname, mname = pair.split(":")
    brdf, medium = _instance(bname), _instance(mname)
    ti, tr = np.array([20.0, 50.0]), np.array([35.0, 10.0])
    got = Forward(brdf, medium, ti, tr, rule=RULES["default"])(brdf.to_vector(),
                                                                 medium.to_vector())
    if bname == "lambertian-test":
        from veil.engine.angles import direction

        wi, wr = np.asarray(direction(ti, 180.0)), np.asarray(direction(tr, 0.0))
        want = np.array([_lambertian_through(brdf, medium, a, b) for a, b in zip(wi, wr)])
        assert np.allclose(got, want, rtol=2e-3)
    else:
        # the paper's BRDF through the test medium: Monte Carlo with importance sampling of
        # both lobes and of the facet law, balance heuristic (tests/reference.py's method)
        want, se = _mc_apparent(brdf, medium, ti, tr)
        assert np.all(np.abs(got - want) <= 4 * se + 2e-3 * want), (got, want, se)


#: The microfacet families through the paper's medium BTDF2 (g = 0.93): rough plastic in
#: water (alpha 0.1, eta 1.12; the separable part is a quadrature table, F_int included) and
#: a rough conductor (no separable part at all).
MICROFACET_BRUTE_FORCE = {
    "rough-plastic": (dict(rho=0.5, alpha=0.1, eta=1.12, ks=1.0), 1 << 19),
    "rough-conductor": (dict(alpha=0.05, n=1.0, k=3.0, ks=1.0), 1 << 18),
    # the distribution option reaches the engine's facet sampling and lobe (GGX's long tail)
    "rough-plastic:ggx": (dict(rho=0.5, alpha=0.1, eta=1.12, ks=1.0, distribution="ggx"),
                          1 << 19),
    # the engine evaluates the family one lobe width at a time by its column model (a
    # Beckmann lobe with a Fresnel curve linear in theta_d, and the diffuse basis;
    # engine/forward.py LinearForward, whose sum tests/test_nonparametric.py checks)
    "nonparametric": (dict(d0=0.4, d1=0.1, d2=0.2, alpha=0.05, f0=0.3, f1=0.5, f2=0.0, f3=1.0),
                      1 << 19),
}


@pytest.mark.parametrize("name", sorted(MICROFACET_BRUTE_FORCE))
def test_microfacet_families_through_btdf2_match_monte_carlo(name):
    """The engine at the default rule against _mc_apparent (Monte Carlo with MIS over the
    phase lobes and the facet law; values from the models' evaluate only) at three
    configurations: within 4 standard errors plus the engine's 1e-3 (measured for
    rough-plastic: within 0.7 standard errors, relative standard error 1.2e-3 to 2.4e-3;
    the engine's own change at twice the nodes per dimension is below 7e-5)."""
    from veil.models import PRESETS

    params, n = MICROFACET_BRUTE_FORCE[name]
    from veil.models.nonparametric import NonParametricColumn

    family = name.split(":")[0]
    cls = NonParametricColumn if family == "nonparametric" else REGISTRY[family]
    brdf, medium = cls(**params), PRESETS["BTDF2"]
    ti, tr = np.array([20.0, 30.0, 0.0]), np.array([35.0, 30.0, 60.0])
    got = Forward(brdf, medium, ti, tr, rule=RULES["default"])(brdf.to_vector(),
                                                                 medium.to_vector())
    want, se = _mc_apparent(brdf, medium, ti, tr, n=n)
    assert np.all(se < 5e-3 * want)
    assert np.all(np.abs(got - want) <= 4 * se + 1e-3 * want), ((got - want) / se, got, want)


def _mc_apparent(brdf, medium, ti, tr, n=1 << 17, seed=7):
    """eq. (1) by Monte Carlo with three strategies combined by the balance heuristic: I' and
    R' from the medium's lobes (mixed with uniform directions for the isotropic part); I'
    from its lobe and R' its mirror about a half vector from the facet law; and the reverse.
    The value uses only the models' ``evaluate`` (checked above against docs/model.md); the
    sampling maps only move samples. Returns (values, standard errors)."""
    import jax

    from veil.engine.angles import direction

    rng = np.random.default_rng(seed)
    vm = np.asarray(medium.to_vector())
    vb = np.asarray(brdf.to_vector())
    top = float(brdf.facet_cdf(vb, math.pi / 2))
    # the models' own functions, each compiled once for the samples' shape (evaluated op by
    # op they compile every primitive for every shape: most of the test's time)
    phase = jax.jit(lambda omm: medium.phase(vm, omm))
    phase_inverse = jax.jit(lambda u: medium.phase_inverse_cone_fraction(vm, u))
    facet_inverse = jax.jit(lambda y: brdf.facet_inverse_cdf(vb, y))
    facet_weight = jax.jit(lambda alpha: brdf.facet_weight(vb, alpha))
    f_t = jax.jit(lambda w_in, w_out: medium.evaluate(vm, w_in, w_out))
    f_r = jax.jit(lambda w_in, w_out: brdf.evaluate(vb, w_in, w_out))

    def frame(c):
        t1 = np.cross(c, [0.0, 1.0, 0.0])
        t1 /= np.linalg.norm(t1)
        return t1, np.cross(c, t1)

    def from_axis(c, omm, beta):
        t1, t2 = frame(c)
        s = np.sqrt(np.maximum(omm * (2 - omm), 0))
        return (1 - omm)[:, None] * c + s[:, None] * (np.cos(beta)[:, None] * t1
                                                      + np.sin(beta)[:, None] * t2)

    def q(c, d):  # mixture density: half lobe about c, half uniform on the sphere
        return 0.5 * np.asarray(phase(1.0 - d @ c)) + 0.5 / (4 * math.pi)

    def draw(c, k):
        lobe = rng.random(k) < 0.5
        omm = np.where(lobe, np.asarray(phase_inverse(rng.random(k))),
                       2.0 * rng.random(k))
        return from_axis(c, omm, 2 * math.pi * rng.random(k))

    def facet(k):
        alpha = np.asarray(facet_inverse(rng.random(k) * top))
        phi = 2 * math.pi * rng.random(k)
        h = np.stack([np.sin(alpha) * np.cos(phi), np.sin(alpha) * np.sin(phi),
                      np.cos(alpha)], axis=1)
        return h

    def f_h(h):
        alpha = np.arccos(np.clip(h[:, 2], -1, 1))
        return np.asarray(facet_weight(alpha)) / top

    def reflect(d, h):
        return 2 * np.sum(d * h, axis=1)[:, None] * h - d

    out, err = [], []
    for a, b in zip(np.asarray(direction(ti, 180.0)), np.asarray(direction(tr, 0.0))):
        samples = []
        i_a, r_a = draw(a, n), draw(b, n)
        i_b = draw(a, n)
        h_b = facet(n)
        r_b = reflect(i_b, h_b)
        r_c = draw(b, n)
        h_c = facet(n)
        i_c = reflect(r_c, h_c)
        for i2, r2 in ((i_a, r_a), (i_b, r_b), (i_c, r_c)):
            s = i2 + r2
            h = s / np.linalg.norm(s, axis=1, keepdims=True)
            c = np.abs(np.sum(i2 * h, axis=1))
            fh = np.where(h[:, 2] > 0, f_h(h), 0.0)
            pa = q(a, i2) * q(b, r2)
            pb = q(a, i2) * fh / (4 * c)
            pc = q(b, r2) * fh / (4 * c)
            ok = (i2[:, 2] > 0) & (r2[:, 2] > 0)
            fti = np.asarray(f_t(np.broadcast_to(a, i2.shape), i2))
            ftr = np.asarray(f_t(r2, np.broadcast_to(b, r2.shape)))
            fr = np.asarray(f_r(i2, r2))
            samples.append(np.where(ok, fti * fr * ftr / (pa + pb + pc), 0.0))
        x = np.concatenate(samples) * 3  # each strategy holds a third of the samples
        out.append(x.mean())
        err.append(x.std() / math.sqrt(x.size))
    return np.array(out), np.array(err)
