"""The apparent reflectance at a fixed set of configurations, as a function of parameters.

This is what fits and renderers hold on to: the directions are converted, padded and split
over the CPU devices once, and every evaluation (value, term matrices, Jacobians) reuses the
compiled engine. Padding to a few sizes keeps the number of compilations small: every call of
up to CHUNK configurations runs one program, a larger one the program of its multiple of
CHUNK (docs/engine.md).
"""

from __future__ import annotations

import functools
import hashlib
import math
import operator
import os
import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from functools import lru_cache

import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .._jax import jax, jnp
from ..errors import InputError, InputTypeError
from ..models.base import BRDF, BTDF
from . import integrator
from .angles import check_angles, direction
from .programs import JACOBIAN_OPTIONS, Program, structure_name
from .quadrature import FINER, RULES, Rule

_AXIS = "configurations"


#: The fewest configurations a program is compiled for: every smaller call runs the program
#: of CHUNK (the fits' chunk through a medium, veil.engine.evaluator), split over every
#: device. Programs for 8, 16 and 32 configurations, one device below 16, each cost a
#: compilation of seconds to make a call of a few configurations 1.5-5 ms faster at the fast
#: rule, 10-17 ms at the default and 0.3 s at "high" (benchmarks/bench_chunks.py).
CHUNK = 64


def _bucket(m: int, n_dev: int) -> int:
    """Padded size: CHUNK, or the multiple of CHUNK above ``m``; divisible by ``n_dev``. (A
    larger call in chunks of CHUNK ran 1.3 to 2.6 times slower: each call has a fixed cost
    of about 2.5 ms, the per-call tables on every device.)"""
    size = CHUNK * max(1, math.ceil(m / CHUNK))
    return n_dev * math.ceil(size / n_dev)


def _devices():
    devs = jax.devices()
    return devs if devs[0].platform == "cpu" else devs[:1]


@lru_cache(maxsize=16)
def _mesh(n_dev: int) -> Mesh:
    """A one-axis mesh over the first ``n_dev`` devices; configurations are split along it."""
    return Mesh(np.array(_devices()[:n_dev]), (_AXIS,))


def _sharded(fn, mesh: Mesh):
    """``fn(vb, vm, wi, wr)`` compiled once for every device of ``mesh``: the parameters are
    replicated, the configurations (leading axis of ``wi``, ``wr`` and of every output) are
    split. One SPMD program, so one compilation however many devices run it."""
    return jax.jit(
        jax.shard_map(fn, mesh=mesh, in_specs=(P(), P(), P(_AXIS), P(_AXIS)), out_specs=P(_AXIS))
    )


@lru_cache(maxsize=128)
def _terms_fn(kb, km, rule: Rule, half: bool, mesh: Mesh):
    bt, mt = integrator.template_for(kb), integrator.template_for(km)

    def fn(vb, vm, wi, wr):
        return integrator.apparent_terms(bt, mt, rule, vb, vm, wi, wr, half)

    return Program(
        _sharded(fn, mesh),
        _identity("terms", kb, km, rule, half, mesh),
        (kb[0], km[0]),
        _label("values", kb, km, rule, half),
    )


@lru_cache(maxsize=128)
def _terms_jac_fn(kb, km, rule: Rule, half: bool, nl_b: tuple, nl_m: tuple, mesh: Mesh):
    """Terms (M, 3, 2) and their derivatives (M, 3, 2, len(nl_b) + len(nl_m)) with respect
    to the listed parameters, the phase grids held (docs/engine.md "Derivatives"), by forward
    mode: the tangents of every basis vector carried through the quadrature together, beside
    one evaluation of the terms (jacfwd). Measured against one linearization with its tangent
    map applied to each basis vector (rough-plastic x forward-series, fast rule, in the
    medium's parameters): 26 % fewer lines of program, 20 % less compile time, the same run
    time (docs/performance.md "Compilation")."""
    bt, mt = integrator.template_for(kb), integrator.template_for(km)
    ib, im = np.asarray(nl_b, dtype=int), np.asarray(nl_m, dtype=int)
    nb = len(nl_b)

    def fn(vb, vm, wi, wr):
        def g(x):
            return integrator.apparent_terms(
                bt,
                mt,
                rule,
                vb.at[ib].set(x[:nb]),
                vm.at[im].set(x[nb:]),
                wi,
                wr,
                half,
                hold_phase_grids=bool(nl_m),  # the medium's parameters move them
            )

        x = jnp.concatenate([vb[ib], vm[im]])

        def along(direction):
            return jax.jvp(g, (x,), (direction,))

        # the terms do not depend on the direction: computed once, not per column
        return jax.vmap(along, out_axes=(None, -1))(jnp.eye(x.size, dtype=x.dtype))

    return jacobian_program(fn, kb, km, rule, half, nl_b, nl_m, mesh)


def jacobian_program(fn, kb, km, rule: Rule, half: bool, nl_b, nl_m, mesh, of: str = ""):
    """The :class:`Program` of a Jacobian function ``fn`` in the parameters ``nl_b`` and
    ``nl_m``, named for the store and the compile display (``of``: what else it computes,
    e.g. " of 3 channels")."""
    own = {p.name for p in kb[0].PARAMS}  # a medium's name the BRDF has too says whose it is
    names = [kb[0].PARAMS[i].name for i in nl_b] + [
        f"medium's {km[0].PARAMS[i].name}" if km[0].PARAMS[i].name in own else km[0].PARAMS[i].name
        for i in nl_m
    ]
    return Program(
        _sharded(fn, mesh),
        _identity(f"terms+jacobian {nl_b} {nl_m}{of}", kb, km, rule, half, mesh),
        (kb[0], km[0]),
        _label(f"values and d/d({', '.join(names)}){of}", kb, km, rule, half),
        JACOBIAN_OPTIONS,
    )


def non_default_options(classes, items) -> list[str]:
    """ "name=value" of each (name, value) of ``items`` that differs from its declared default
    in the models ``classes`` (for people: labels and the warmup's task names)."""
    defaults = {o.name: o.default for cls in classes for o in cls.OPTIONS}
    return [
        f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
        for k, v in items
        if defaults.get(k, object()) != v
    ]


def _label(what: str, kb, km, rule: Rule, half: bool = False) -> str:
    """What a compiled engine function is, for people (the compile display): ``half``, the
    program of configurations in the plane of incidence (its own, docs/engine.md), says so."""
    named = [f"{name}" for name, r in RULES.items() if r == rule] + [
        f"{name} error-estimate" for name, r in FINER.items() if r == rule
    ]
    options = non_default_options((kb[0], km[0]), kb[1:] + km[1:])
    models = f"{kb[0].NAME} x {km[0].NAME}" + (f" ({', '.join(options)})" if options else "")
    plane = ", in the plane of incidence" if half else ""
    return f"{models}: {what}, {named[0] if named else 'custom'} rule{plane}"


def _identity(what: str, kb, km, rule: Rule, half: bool, mesh: Mesh) -> str:
    """What a compiled engine function is, for the program store (veil.engine.programs)."""
    return (
        f"{what} | {structure_name(kb)} | {structure_name(km)} | {rule!r} | half={half} | "
        f"{mesh.devices.size} {_devices()[0].platform} devices"
    )


# Background compilation (Forward.prepare): the first call of each compiled function and
# input shape, run in a worker thread (JAX makes a concurrent call of the same function wait
# for that compilation rather than compile it twice). A running compilation cannot be
# interrupted: a process that exits meanwhile waits for it.
_PREPARED: dict = {}
_PREPARED_LOCK = threading.Lock()
_POOL: list = []


def _warm(fn, *args) -> None:
    jax.block_until_ready(fn(*args))


def _submit(fn, *args) -> Future:
    key = (fn, tuple(a.shape for a in args))
    with _PREPARED_LOCK:
        known = _PREPARED.get(key)
        if known is not None and not (known.done() and known.exception() is not None):
            return known
        if not _POOL:
            _POOL.append(
                ThreadPoolExecutor(
                    max_workers=max(2, os.cpu_count() or 1), thread_name_prefix="veil-compile"
                )
            )
        if len(_PREPARED) > 256:  # forget finished ones (the compiled code stays in JAX)
            for k in [k for k, f in _PREPARED.items() if f.done()]:
                del _PREPARED[k]
        _PREPARED[key] = _POOL[0].submit(_warm, fn, *args)
        return _PREPARED[key]


def wait_for_compilations() -> None:
    """Block until every compilation started by :meth:`Forward.prepare` has finished
    (errors are not raised here; the call that needs the program raises them)."""
    with _PREPARED_LOCK:
        pending = list(_PREPARED.values())
    for future in pending:
        future.exception()


def _unit_scale_vector(cls, v) -> np.ndarray:
    """``v`` with the model's scale parameters and gain at 1, on the host (as the programs
    see it: integrator.unit_scale_indices)."""
    out = np.array(v, dtype=float)
    out[list(integrator.unit_scale_indices(cls))] = 1.0
    return out


def _read_only(a) -> np.ndarray:
    """A host copy of a program's output that no caller can change (it is kept)."""
    out = np.asarray(a)
    out.flags.writeable = False
    return out


class Forward:
    """Apparent reflectance of ``brdf`` through ``medium`` at fixed configurations.

    Parameters are passed as vectors in the models' declaration order (``model.to_vector()``);
    the models given here fix only the code path (class and options such as the variant).
    """

    def __new__(cls, brdf, *args, **kwargs):
        # a linear family is the sum of its column model's programs (LinearForward)
        if cls is Forward and type(brdf).LINEAR:
            return super().__new__(LinearForward)
        return super().__new__(cls)

    def __init__(
        self,
        brdf: BRDF,
        medium: BTDF,
        theta_i,
        theta_r,
        phi_i=180.0,
        phi_r=0.0,
        rule: Rule | None = None,
    ):
        self.brdf, self.medium = brdf, medium
        self.rule = RULES["default"] if rule is None else rule
        if not isinstance(self.rule, Rule):
            raise InputTypeError(
                f"rule must be a veil.quadrature.Rule, got {rule!r} (for a named "
                "accuracy use veil.apparent.RULES[name])"
            )
        ti, tr, pi_, pr = (a.ravel() for a in check_angles(theta_i, theta_r, phi_i, phi_r))
        self.size = ti.size
        if self.size == 0:
            raise InputError("no configurations to evaluate")
        wi = np.asarray(direction(ti, pi_))
        wr = np.asarray(direction(tr, pr))
        # in the plane of incidence the integrand is symmetric under y -> -y
        self.half = bool(np.all(np.abs(wi[:, 1]) < 1e-12) and np.all(np.abs(wr[:, 1]) < 1e-12))
        self._mesh = _mesh(len(_devices()))
        self.devices = list(self._mesh.devices.flat)
        padded = _bucket(self.size, len(self.devices))
        idx = np.minimum(np.arange(padded), self.size - 1)
        split = NamedSharding(self._mesh, P(_AXIS))
        self._wi, self._wr = jax.device_put(wi[idx], split), jax.device_put(wr[idx], split)
        self._kb = integrator.template(brdf).structure()
        self._km = integrator.template(medium).structure()
        # the last output of each program, by its non-scale parameters (see _memo_run)
        self._last: dict = {}
        # outputs of the channels' program, by (program, non-scale parameters): its last run
        # (veil.engine.channel_programs.anticipate)
        self._anticipated: dict = {}

    # ----------------------------------------------------------------------------------
    def _run(self, fn, vb, vm):
        return fn(vb, vm, self._wi, self._wr)

    def _key(self, vb, vm) -> bytes:
        """What a program's output depends on: the non-scale parameters."""
        return (
            _unit_scale_vector(type(self.brdf), vb).tobytes()
            + _unit_scale_vector(type(self.medium), vm).tobytes()
        )

    def _memo_run(self, fn, vb, vm):
        """``fn``'s output at ``vb``, ``vm``, or its last output when only scale parameters
        changed since: the term matrices and their derivatives do not depend on them (the
        program sets them to 1, integrator._unit_scales). Channels whose own parameters are
        all scales (a BRDF's albedos, the paper medium's T_d and T_t) share their shared
        parameters' programs run once per iteration (docs/channels.md, "Cost")."""
        key = self._key(vb, vm)
        known = self._anticipated.get((fn, key))  # first: the announced channels' program
        if known is not None:
            return known
        last = self._last.get(fn)
        if last is not None and last[0] == key:
            return last[1]
        out = jax.tree_util.tree_map(_read_only, self._run(fn, vb, vm))
        self._last[fn] = (key, out)
        return out

    def prepare(self, values: bool = True, jacobians=()) -> list[Future]:
        """Start compiling (or loading) in the background what later calls will need: the
        term matrices (``values``, for ``terms`` and ``__call__``) and, for each
        ``(free_brdf, free_medium)`` of ``jacobians``, ``value_and_jacobian`` for those
        indices. Compilations run in parallel on worker threads; a call that needs one still
        being compiled waits for it. Returns the futures (None when done; an exception if
        the compilation failed)."""
        fns = []
        if values:
            fns.append(_terms_fn(self._kb, self._km, self.rule, self.half, self._mesh))
        for free in jacobians:
            fn = self._jacobian_fn(*free)[0]
            if fn is not None and fn not in fns:
                fns.append(fn)
        vb, vm = self._vectors(self.brdf.to_vector(), self.medium.to_vector())
        return [_submit(fn, vb, vm, self._wi, self._wr) for fn in fns]

    def _jacobian_fn(self, free_brdf, free_medium):
        bcls, mcls = type(self.brdf), type(self.medium)
        free_brdf = self._indices(free_brdf, bcls)
        free_medium = self._indices(free_medium, mcls)
        scale_b = {bcls.scale_index(p): p for p in bcls.SCALES}
        scale_m = {mcls.scale_index(p): p for p in mcls.SCALES}
        if mcls.GAIN is not None:
            scale_m[mcls.param_names().index(mcls.GAIN)] = "gain"
        # each once, in the declaration's order, whatever the caller's: one program per set
        # of free parameters (the columns are found by index below)
        nl_b = tuple(sorted({i for i in free_brdf if i not in scale_b}))
        nl_m = tuple(sorted({i for i in free_medium if i not in scale_m}))
        fn = (
            _terms_jac_fn(self._kb, self._km, self.rule, self.half, nl_b, nl_m, self._mesh)
            if nl_b or nl_m
            else None
        )
        return fn, free_brdf, free_medium, scale_b, scale_m, nl_b, nl_m

    def _vectors(self, vb, vm):
        out = []
        for name, v, cls in (("brdf", vb, type(self.brdf)), ("medium", vm, type(self.medium))):
            v = np.asarray(v, dtype=float)
            if v.shape != (len(cls.PARAMS),):
                raise InputError(
                    f"{name} parameter vector has shape {v.shape}; expected "
                    f"({len(cls.PARAMS)},) for {', '.join(cls.param_names())}"
                )
            if not np.all(np.isfinite(v)):
                raise InputError(f"{name} parameter vector {v.tolist()} has a non-finite value")
            out.append(v)  # numpy: jnp.asarray would compile a program in a new process
        return out

    def _indices(self, indices, cls):
        n = len(cls.PARAMS)
        try:
            return tuple(range(n)[operator.index(i)] for i in indices)
        except (IndexError, TypeError):
            raise IndexError(
                f"parameter indices {tuple(indices)!r} are not all integers in "
                f"[-{n}, {n}) for {', '.join(cls.param_names())}"
            ) from None

    def terms(self, vb, vm) -> np.ndarray:
        """Term matrices (M, rows, 2) with scale parameters set to 1 (see integrator)."""
        fn = _terms_fn(self._kb, self._km, self.rule, self.half, self._mesh)
        vb, vm = self._vectors(vb, vm)
        return self._memo_run(fn, vb, vm)[: self.size]

    def combine(self, terms, vb, vm) -> np.ndarray:
        """The apparent reflectance from the term matrices and the scale parameters, on the
        host (as :func:`veil.engine.integrator.combine_terms`; no eager JAX operation, each
        of which costs a compilation or a cache lookup in a fresh process)."""
        rows = integrator.row_scales(type(self.medium), vm)
        cols = integrator.column_scales(type(self.brdf), vb)
        return np.einsum("...mb,m,b->...", np.asarray(terms), rows, cols)

    def __call__(self, vb, vm) -> np.ndarray:
        return self.combine(self.terms(vb, vm), vb, vm)

    def value_and_jacobian(self, vb, vm, free_brdf=(), free_medium=()):
        """Values (M,) and the Jacobian (M, len(free_brdf) + len(free_medium)).

        ``free_*`` are parameter indices. Scale parameters (``Model.SCALES``) are
        differentiated analytically from the term matrices; the others by forward-mode
        automatic differentiation through the quadrature, its phase grids held where this
        point draws them (docs/engine.md "Derivatives"; for channels announced together,
        veil.engine.channel_programs, on their law's nodes).
        """
        fn, free_brdf, free_medium, scale_b, scale_m, nl_b, nl_m = self._jacobian_fn(
            free_brdf, free_medium
        )
        vb, vm = self._vectors(vb, vm)
        if fn is not None:
            terms, jac_nl = self._memo_run(fn, vb, vm)
            terms = terms[: self.size]
            jac_nl = jac_nl[: self.size]  # (M, rows, 2, len(nl_b) + len(nl_m))
        else:  # only scale parameters free: the term matrices are all it takes
            terms = self.terms(vb, vm)
            jac_nl = np.zeros(terms.shape + (0,))
        jb, jm = jac_nl[..., : len(nl_b)], jac_nl[..., len(nl_b) :]
        value = self.combine(terms, vb, vm)
        bcls, mcls = type(self.brdf), type(self.medium)
        rows = integrator.row_scales(mcls, vm)
        cols = integrator.column_scales(bcls, vb)
        columns = []
        for i in free_brdf:
            if i in scale_b:
                part = integrator.BRDF_PARTS.index(scale_b[i])
                columns.append(np.einsum("mk,m->k", terms[:, :, part].T, rows))
            else:
                k = nl_b.index(i)
                columns.append(np.einsum("kmb,m,b->k", jb[..., k], rows, cols))
        for i in free_medium:
            if i in scale_m:
                drows = integrator.row_scale_derivative(mcls, vm, i)
                columns.append(np.einsum("kmb,m,b->k", terms, drows, cols))
            else:
                k = nl_m.index(i)
                columns.append(np.einsum("kmb,m,b->k", jm[..., k], rows, cols))
        jac = np.stack(columns, axis=1) if columns else np.zeros((self.size, 0))
        return value, jac


# --------------------------------------------------------------------------------------
# a linear family (``LINEAR``, docs/nonparametric.md): the sum of its column model's programs
# --------------------------------------------------------------------------------------
# A family such as veil.models.nonparametric sums lobes of very different widths. One
# quadrature of the sum samples its half vectors from one law, which resolves no lobe well
# (6 % off at the default rule for a narrow and a broad lobe together). Its column_groups()
# split the coefficients into groups that share one sampling law (one lobe width each, the
# diffuse basis with the first); each group is evaluated by the family's column model
# (columns()) with that group's coefficients, and the results add up: the apparent
# reflectance is linear in the coefficients for a fixed law, so the sum is the family's
# eq. (1), each lobe sampled as it needs, and the step fit's columns are its parts.


#: Term matrices of a linear family's lobe-width groups already evaluated, by (the
#: configurations, rule and models, the group's vector, the medium's vector), least recently
#: used first out beyond GROUP_TERMS_BYTES: a group whose coefficients did not change since
#: (a slider on one coefficient, the explorer's static states) is not evaluated again.
_GROUP_TERMS: OrderedDict = OrderedDict()
GROUP_TERMS_BYTES = 64 << 20
_GROUP_HELD = [0]  # bytes in _GROUP_TERMS
_GROUP_LOCK = threading.Lock()


class LinearForward(Forward):
    """:class:`Forward` of a linear family (module docstring): ``terms``, ``__call__``,
    ``value_and_jacobian`` and ``prepare`` as Forward's, from the column model's Forward."""

    def __init__(self, brdf, medium, theta_i, theta_r, phi_i=180.0, phi_r=0.0, rule=None):
        column_cls, _ = type(brdf).columns()
        self.brdf, self.medium = brdf, medium
        self._inner = Forward(column_cls.template(), medium, theta_i, theta_r, phi_i, phi_r, rule)
        self.rule, self.size, self.half = self._inner.rule, self._inner.size, self._inner.half
        digest = hashlib.sha256()
        for a in check_angles(theta_i, theta_r, phi_i, phi_r):
            digest.update(np.ascontiguousarray(a, dtype=float).ravel().tobytes())
        #: what a group's terms depend on besides its and the medium's vectors
        self._where = (digest.hexdigest(), self.rule, self._inner._kb, self._inner._km)
        self.devices = self._inner.devices
        #: [(the column model's base vector, {family index: column model index})]
        self._groups = type(brdf).column_groups()

    def _vector(self, group: int, vb) -> np.ndarray:
        base, where = self._groups[group]
        v = np.array(base, dtype=float)
        for i, c in where.items():
            v[c] = vb[i]
        return v

    def _active(self, vb, every: bool = False) -> list[int]:
        """The groups with a non-zero coefficient (the first always; all when ``every``)."""
        return [
            g
            for g, (_, where) in enumerate(self._groups)
            if every or g == 0 or any(vb[i] != 0.0 for i in where)
        ]

    def prepare(self, values: bool = True, jacobians=()) -> list:
        """As :meth:`Forward.prepare`; a derivative in the family's coefficients needs the
        values program only (:meth:`value_and_jacobian`)."""
        wanted = [((), fm) for _, fm in jacobians if fm]
        return self._inner.prepare(values or any(fb for fb, _ in jacobians), wanted)

    def terms(self, vb, vm) -> np.ndarray:
        vb, vm = self._vectors(vb, vm)
        groups = (self._group_terms(self._vector(g, vb), vm) for g in self._active(vb))
        return np.array(functools.reduce(operator.add, groups))  # in order, as sum() added

    def _group_terms(self, v: np.ndarray, vm: np.ndarray) -> np.ndarray:
        """One group's term matrices at its vector ``v``: remembered (:data:`_GROUP_TERMS`)."""
        key = (self._where, v.tobytes(), vm.tobytes())
        with _GROUP_LOCK:
            if key in _GROUP_TERMS:
                _GROUP_TERMS.move_to_end(key)
                return _GROUP_TERMS[key]
        out = np.array(self._inner.terms(v, vm), dtype=float)
        out.setflags(write=False)
        with _GROUP_LOCK:
            if key not in _GROUP_TERMS:  # (another thread may have put it meanwhile)
                _GROUP_TERMS[key] = out
                _GROUP_HELD[0] += out.nbytes
            while _GROUP_HELD[0] > GROUP_TERMS_BYTES and _GROUP_TERMS:
                _GROUP_HELD[0] -= _GROUP_TERMS.popitem(last=False)[1].nbytes
        return out

    def value_and_jacobian(
        self, vb, vm, free_brdf=(), free_medium=()
    ) -> tuple[np.ndarray, np.ndarray]:
        """Values and d/d(``free_brdf`` coefficients, ``free_medium``). The values are linear
        in the coefficients, so a coefficient's column is its group's values with that
        coefficient 1 and the others 0: the values program, no program of derivatives (the
        largest programs of all: 13k lines, 19 s to compile through forward-series). The
        medium's columns are summed over the groups' Jacobians."""
        vb, vm = self._vectors(vb, vm)
        free_brdf = self._indices(free_brdf, type(self.brdf))
        free_medium = self._indices(free_medium, type(self.medium))
        # the value: the groups' Jacobian programs' with the medium's columns, else the
        # values program's (the two agree to rounding)
        value = np.zeros(self.size) if free_medium else self(vb, vm)
        jac_m = np.zeros((self.size, len(free_medium)))
        for g in self._active(vb) if free_medium else ():
            val, jac = self._inner.value_and_jacobian(self._vector(g, vb), vm, (), free_medium)
            value += val
            jac_m += jac
        jac_b = np.zeros((self.size, len(free_brdf)))
        for k, i in enumerate(free_brdf):
            unit = np.zeros_like(vb)
            unit[i] = 1.0
            groups = [g for g, (_, where) in enumerate(self._groups) if i in where]
            if not groups:  # a family whose column_groups() miss a coefficient: a veil bug
                raise ValueError(f"{type(self.brdf).__name__}: coefficient {i} in no group")
            for g in groups:
                v = self._vector(g, unit)
                jac_b[:, k] += self._inner.combine(self._group_terms(v, vm), v, vm)
        return value, np.concatenate([jac_b, jac_m], axis=1)
