"""The least-squares problem every fit solves (docs/model.md sec. 7; docs/fitting.md).

A :class:`Problem` stacks sessions: each :class:`Block` is one measured session (its data,
the BRDF of its object and, unless it is clear water, its medium) and maps its models'
parameter vectors into one global vector of :class:`Slot` s. A step fit of the two-step
method is a problem of one session with one model free; a joint fit shares the object's
BRDF between its sessions and the media's parameters as declared. Residuals are
(model - value) * w session after session (w = 1/sigma, or 1 without sigma columns), plus
optional prior rows (:meth:`Problem.set_prior`).

Parameter names: those of the models' declarations, a medium's aliased where declared
(the paper medium's ``eta`` is ``eta_u`` beside the BRDF's ``eta``); a joint fit prefixes the
reference object's with ``ref.`` and suffixes a medium's own with ``[label]``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..engine import quadrature
from ..engine.evaluator import WRT, ApparentModel, DirectModel
from ..engine.integrator import BRDF_PARTS, row_scales
from ..engine.quadrature import RULES
from ..errors import FitError
from ..models import BRDF, Medium, Model, Param
from . import coordinates
from .session_data import FitData, prepare

#: Quadrature of the iterations through a medium; the polish uses the requested accuracy.
ITERATION_ACCURACY = "fast"
#: Labels meaning clear water (no medium: the session measures f_r directly).
CLEAR = ("none", "clear")
OBJECTS = ("target", "reference")


def check_accuracy(accuracy) -> None:
    """A FitError unless ``accuracy`` names a quadrature rule ("fast", "default", "high")."""
    quadrature.check_accuracy(accuracy, error=FitError)


class SessionModel:
    """Model values of one session at fixed configurations (docs/model.md sec. 2, 5), with the
    Jacobian w.r.t. every parameter of either model or both; ``medium=None`` is clear water (f_r
    directly). Built on :mod:`veil.engine.evaluator` (one compilation per accuracy)."""

    def __init__(self, brdf: BRDF, medium: Medium | None, angles, rule=ITERATION_ACCURACY):
        if isinstance(rule, str):
            check_accuracy(rule)
            rule = RULES[rule]
        angles = tuple(np.asarray(a, dtype=float).ravel() for a in angles)
        self.size = angles[0].size
        if self.size == 0:
            raise FitError("a session has no configurations")
        self.brdf, self.medium = brdf, medium
        self.nb = len(type(brdf).PARAMS)
        self.nm = 0 if medium is None else len(type(medium).PARAMS)
        if medium is None:
            self._direct = DirectModel(brdf, angles)
        else:
            self._engine = ApparentModel(brdf, medium, angles, rule)

    @property
    def calls(self) -> tuple[int, int]:
        """(value evaluations, Jacobian evaluations) so far."""
        e = self._direct if self.medium is None else self._engine
        return e.values_calls, e.jacobian_calls

    def prepare(self, values: bool = True, jacobians=(), channels: int = 1) -> None:
        """Compile (or load) in the background what later calls will need: values, and
        Jacobians with respect to each ``wrt`` of ``jacobians`` (see Forward.prepare), for
        ``channels`` channels sharing this model (:meth:`anticipate`)."""
        if self.medium is not None:
            self._engine.prepare(values, jacobians, channels)

    def anticipate(self, pairs, wrt=None) -> None:
        """The (vb, vm) of every channel sharing this model at one iteration: their values
        (or Jacobians in ``wrt``) computed together where the medium lets them
        (veil.engine.channel_programs), kept for each channel's call."""
        if self.medium is not None and len(pairs) > 1:
            vbs = [np.asarray(vb, dtype=float) for vb, _ in pairs]
            vms = [np.asarray(vm, dtype=float) for _, vm in pairs]
            self._engine.anticipate(vbs, vms, wrt)

    def values(self, vb, vm=None) -> np.ndarray:
        if self.medium is None:
            return self._direct.values(np.asarray(vb, dtype=float))
        return self._engine.values(np.asarray(vb, dtype=float), np.asarray(vm, dtype=float))

    def terms(self, vb, vm=None) -> np.ndarray:
        """Term matrices (M, R, B) with every scale parameter set to 1: rows the medium's
        scale products (veil.engine.integrator.row_scales; one row of 1 in clear water),
        columns the BRDF's parts (column_scales). values = rows . terms . columns."""
        vb = np.asarray(vb, dtype=float)
        if self.medium is None:
            return self._direct_terms(vb)
        return self._engine.terms(vb, np.asarray(vm, dtype=float))

    def _direct_terms(self, vb) -> np.ndarray:
        """Clear water: column k is f_r with part k's scale at 1 and the other scales at 0;
        a part without a scale parameter is the remainder with every scale at 0 (once)."""
        cls = type(self.brdf)
        scaled = {part: cls.scale_index(part) for part in BRDF_PARTS}
        cols, remainder_done = [], False
        for part in BRDF_PARTS:
            v = vb.copy()
            for i in scaled.values():
                if i is not None:
                    v[i] = 0.0
            if scaled[part] is not None:
                v[scaled[part]] = 1.0
            elif remainder_done or not cls.HAS_LOBE and part == "lobe":
                cols.append(np.zeros(self.size))
                continue
            else:
                remainder_done = True
            cols.append(self._direct.values(v))
        return np.stack(cols, axis=1)[:, None, :]

    def jacobian(self, vb, vm=None, wrt=WRT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Values (M,), d/d vb (M, nb) and d/d vm (M, nm); through a medium, the derivatives
        of a model not in ``wrt`` are NaN (not computed)."""
        vb = np.asarray(vb, dtype=float)
        if self.medium is None:
            val, jac = self._direct.value_and_jacobian(vb)
            return val, jac, np.zeros((self.size, 0))
        val, jac = self._engine.value_and_jacobian(vb, np.asarray(vm, dtype=float), wrt)
        return val, jac[:, : self.nb], jac[:, self.nb :]

    def row_weights(self, vm) -> np.ndarray:
        """The medium's row scales at ``vm`` ([1] in clear water)."""
        return np.ones(1) if self.medium is None else row_scales(type(self.medium), vm)


@dataclass
class Session:
    """One measured session (docs/model.md sec. 7): a measurement ``table`` (DataFrame or CSV
    path), the ``medium`` label it was measured in ("none" for clear water) and the
    ``object`` measured ("target" or "reference"); ``black`` the black-cloth table
    subtracted from it channel by channel (None: already subtracted, or none)."""

    table: object
    medium: str = "none"
    object: str = "target"
    name: str | None = None
    black: Any = None

    def __post_init__(self):
        if not isinstance(self.medium, str) or not self.medium.strip():
            raise FitError(
                f"session medium = {self.medium!r}: expected a non-empty label "
                f"(e.g. 'low', 'x2') or 'none' for clear water"
            )
        self.medium = self.medium.strip()
        if self.medium.lower() in CLEAR:
            self.medium = "none"
        bad = [c for c in "[]=,:@ " if c in self.medium]
        if bad:
            raise FitError(
                f"session medium label {self.medium!r} contains {bad[0]!r}; labels "
                f"may not contain spaces or any of [ ] = , : @"
            )
        if self.object not in OBJECTS:
            raise FitError(f"session object = {self.object!r}: expected 'target' or 'reference'")
        if self.name is None:
            src = self.table if isinstance(self.table, (str, os.PathLike)) else None
            self.name = f"{self.object} in {self.medium if self.medium != 'none' else 'water'}" + (
                f" ({os.fspath(src)})" if src is not None else ""
            )

    @property
    def clear(self) -> bool:
        return self.medium == "none"


@dataclass(frozen=True)
class Slot:
    """One parameter of a problem: its result ``name``, the model parameter it is (``spec``,
    at ``index`` in the model's vector), the kind of model (``kind`` brdf/medium) and its
    owner (an object name or medium label, "*" when shared by the media); ``scale`` when it
    only scales a part of its model, or all of it (a gain), linearly."""

    name: str
    kind: str
    owner: str
    index: int
    spec: Param
    scale: bool = False

    @property
    def coordinate(self) -> str:
        """Fit coordinate (:mod:`veil.fitting.coordinates`): log, atanh or plain."""
        return coordinates.coordinate(self.spec)

    def to_u(self, x: float) -> float:
        return coordinates.to_u(self.spec, x, self.coordinate)

    def to_x(self, u: float) -> tuple[float, float]:
        return coordinates.to_x(self.spec, u, self.coordinate)

    def bounds(self, u0: float) -> tuple[float, float]:
        return coordinates.bounds(self.spec, u0, self.coordinate)


def model_slots(model, kind: str, owner: str, name=lambda p: p.key) -> list[Slot]:
    """Slots of every parameter of ``model`` (class or instance), named by ``name(param)``."""
    cls: type[Model] = model if isinstance(model, type) else type(model)
    scales = set(cls.scale_names()) | {getattr(cls, "GAIN", None)} - {None}
    return [Slot(name(p), kind, owner, i, p, p.name in scales) for i, p in enumerate(cls.PARAMS)]


@dataclass
class Block:
    """One session inside a :class:`Problem`: data, global indices of its BRDF vector ``ib``
    and medium vector ``im`` (None in clear water), its models (fixing the code path), and
    its engines by accuracy."""

    session: Session
    data: FitData
    ib: np.ndarray
    im: np.ndarray | None
    brdf: BRDF
    medium: Medium | None
    models: dict = field(default_factory=dict)

    def model(self, accuracy: str) -> SessionModel:
        if accuracy not in self.models:
            self.models[accuracy] = SessionModel(self.brdf, self.medium, self.data.angles, accuracy)
        return self.models[accuracy]

    @property
    def size(self) -> int:
        return self.data.size


class Problem:
    """Stacked weighted least squares over sessions (module docstring).

    ``params`` lists every :class:`Slot`, ``values`` their natural values (fixed ones
    included), ``free`` which are estimated.
    """

    def __init__(self, blocks, params, values, free, weighted: bool):
        self.blocks = list(blocks)
        self.params = list(params)
        self.values = np.asarray(values, dtype=float).copy()
        self.free = np.asarray(free, dtype=bool).copy()
        self.weighted = weighted
        self.names = [p.name for p in self.params]
        self.n_points = int(sum(b.size for b in self.blocks))
        self.y = np.concatenate([b.data.y for b in self.blocks])
        self.w = np.concatenate([b.data.w for b in self.blocks])
        #: canonical angles (theta_i, phi_i, theta_r, phi_r) of all points, in row order
        self.angles = tuple(
            np.concatenate(parts) for parts in zip(*(b.data.angles for b in self.blocks))
        )
        self._cache: dict = {}
        self._last: tuple[tuple[bytes, Any], Any] | None = None
        self.prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def set_prior(self, names, mean, cov) -> None:
        """A Gaussian prior N(mean, cov) (natural units) on parameters ``names``: extra
        residuals L^-1 (x - mean), L L^T = cov. It carries a previous step's result into a
        refit (veil.analysis.diagnostics: a step-2 fit with the medium of step 1 free but
        held to its uncertainty)."""
        cov = np.asarray(cov, dtype=float)
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise FitError("the prior covariance is not positive definite") from None
        idx = np.array([self.index(n) for n in names])
        self.prior = (idx, np.asarray(mean, dtype=float), np.linalg.inv(chol))

    def prior_rows(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Prior residuals (k,) and their Jacobian (k, P) w.r.t. all natural parameters."""
        if self.prior is None:
            return np.zeros(0), np.zeros((0, len(self.params)))
        idx, mean, inv = self.prior
        jac = np.zeros((len(idx), len(self.params)))
        jac[:, idx] = inv
        return inv @ (np.asarray(x)[idx] - mean), jac

    @property
    def free_index(self) -> np.ndarray:
        return np.flatnonzero(self.free)

    @property
    def free_names(self) -> list[str]:
        return [self.names[k] for k in self.free_index]

    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise FitError(
                f"{name!r} is not a parameter of this fit; its parameters are "
                f"{', '.join(self.names)}"
            ) from None

    # -- coordinates ---------------------------------------------------------------------
    def to_u(self, x) -> np.ndarray:
        return np.array([self.params[k].to_u(x[k]) for k in self.free_index])

    def to_x(self, u, base=None) -> tuple[np.ndarray, np.ndarray]:
        x = (self.values if base is None else np.asarray(base, dtype=float)).copy()
        d = np.empty(len(u))
        for j, k in enumerate(self.free_index):
            x[k], d[j] = self.params[k].to_x(u[j])
        return x, d

    def bounds(self, u0) -> tuple[np.ndarray, np.ndarray]:
        pairs = [self.params[k].bounds(u0[j]) for j, k in enumerate(self.free_index)]
        return np.array([a for a, _ in pairs]), np.array([b for _, b in pairs])

    # -- evaluation ----------------------------------------------------------------------
    def split(self, block: Block, x) -> tuple[np.ndarray, np.ndarray | None]:
        return x[block.ib], (None if block.im is None else x[block.im])

    def model_values(self, x, accuracy=ITERATION_ACCURACY) -> np.ndarray:
        """Model values of all sessions, concatenated, at natural parameters ``x``."""
        x = np.asarray(x, dtype=float)
        key = (x.tobytes(), accuracy)
        cached = self._cache.get(key)
        if cached is not None:
            return cached[0]
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        self.anticipate(x, accuracy)
        return np.concatenate([b.model(accuracy).values(*self.split(b, x)) for b in self.blocks])

    def anticipate(self, x, accuracy, wrt=None, values: bool = True) -> None:
        """Announce ``x`` to every engine that several blocks (channels) share, so that it
        evaluates them together (:meth:`SessionModel.anticipate`); ``wrt`` the models each
        block differentiates (as :meth:`wrt`; None: values; blocks that differentiate
        nothing are evaluated only if ``values``). A group whose blocks differentiate
        different models is not announced."""
        groups: dict = {}
        for k, b in enumerate(self.blocks):
            if b.medium is not None:
                groups.setdefault(id(b.models), []).append(k)
        for members in groups.values():
            kinds = {() if wrt is None else tuple(wrt[k]) for k in members}
            if len(members) < 2 or len(kinds) > 1 or kinds == {()} and not values:
                continue
            pairs = [self.split(self.blocks[k], x) for k in members]
            self.blocks[members[0]].model(accuracy).anticipate(pairs, kinds.pop() or None)

    def remember(self, x, accuracy, values) -> None:
        """Keep ``values`` (the model at natural ``x``, ``accuracy``) for the next call of
        :meth:`model_values` there (a solver's last evaluation is its solution's)."""
        if values is not None:
            self._last = ((np.asarray(x, dtype=float).tobytes(), accuracy), values)

    def wrt(self, columns) -> tuple:
        """Per block, the models (WRT) whose derivatives the global ``columns`` need (None:
        every parameter)."""
        wanted = None if columns is None else {int(c) for c in np.ravel(columns)}
        out = []
        for b in self.blocks:
            kinds = [
                kind
                for kind, idx in (("brdf", b.ib), ("medium", b.im))
                if idx is not None and (wanted is None or wanted & {int(i) for i in idx})
            ]
            out.append(tuple(kinds))
        return tuple(out)

    def value_and_jacobian(
        self, x, accuracy=ITERATION_ACCURACY, columns=None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Model values (N,) and d values / d (global parameters) (N, P), unweighted.

        ``columns``: the global parameter indices (or a boolean mask) the caller reads; the
        engine then differentiates only the models they belong to (a step-2 fit needs no
        derivative in the medium's parameters). Columns of a session's model that was not
        differentiated are NaN in its rows (another session's parameters are 0 there);
        columns computed at the same point by an earlier call are kept. None: all."""
        x = np.asarray(x, dtype=float)
        if columns is not None and np.asarray(columns).dtype == bool:
            columns = np.flatnonzero(columns)
        key = (x.tobytes(), accuracy)
        wrt = self.wrt(columns)
        cached = self._cache.get(key)
        if cached is not None and all(set(w) <= set(h) for w, h in zip(wrt, cached[2])):
            return cached[0], cached[1]
        have = cached[2] if cached is not None else tuple(() for _ in self.blocks)
        missing_by_block = [
            tuple(k for k in WRT if k in w and k not in h) for w, h in zip(wrt, have)
        ]
        self.anticipate(x, accuracy, missing_by_block, values=cached is None)
        vals, rows, done = [], [], []
        start = 0
        for b, want, had in zip(self.blocks, wrt, have):
            rows_b = slice(start, start + b.size)
            missing = tuple(k for k in WRT if k in want and k not in had)
            if cached is not None:  # the first call's values are kept
                val, full = cached[0][rows_b], cached[1][rows_b].copy()
            else:  # another block's parameters: 0; this one's not differentiated: NaN
                val, full = None, np.zeros((b.size, len(self.params)))
                for kind, idx in (("brdf", b.ib), ("medium", b.im)):
                    if b.medium is not None and kind not in want:
                        full[:, idx] = np.nan
            if missing or val is None:
                new, jb, jm = b.model(accuracy).jacobian(*self.split(b, x), wrt=missing)
                val = new if val is None else val
                # a block's BRDF and medium slots are distinct: one kind at a time
                for kind, idx, jac in (("brdf", b.ib, jb), ("medium", b.im, jm)):
                    if kind in missing or (kind == "brdf" and b.medium is None):
                        full[:, idx] = 0.0
                        np.add.at(full.T, idx, jac.T)
            vals.append(val)
            rows.append(full)
            done.append(tuple(k for k in WRT if k in want or k in had))
            start += b.size
        out = (np.concatenate(vals), np.concatenate(rows), tuple(done))
        self._cache = {key: out}
        return out[0], out[1]

    def engine_calls(self) -> dict:
        """{accuracy: [value evaluations, Jacobian evaluations]} summed over the sessions."""
        out: dict = {}
        counted: set = set()
        for b in self.blocks:
            if id(b.models) in counted:  # engines shared by channels (channel_steps)
                continue
            counted.add(id(b.models))
            for acc, m in b.models.items():
                c = out.setdefault(acc, [0, 0])
                v, j = m.calls
                c[0] += v
                c[1] += j
        return out

    def slices(self) -> list[slice]:
        out, start = [], 0
        for b in self.blocks:
            out.append(slice(start, start + b.size))
            start += b.size
        return out

    def with_fixed(self, names_values: dict) -> Problem:
        """A copy of the problem with more parameters held fixed (profiles, refits)."""
        out = Problem.__new__(Problem)
        out.__dict__.update(self.__dict__)
        out.values = self.values.copy()
        out.free = self.free.copy()
        out._cache = {}
        out._last = None
        for n, v in names_values.items():
            k = self.index(n)
            out.values[k] = float(v)
            out.free[k] = False
        if not out.free.any():
            raise FitError("every parameter is fixed: nothing to fit")
        return out

    def with_freed(self, names) -> Problem:
        """A copy of the problem with the parameters ``names`` free, at their values (a
        linear family's coefficients its solve held at 0, in its profiles)."""
        out = self.with_fixed({})
        for n in names:
            out.free[self.index(n)] = True
        return out


def session_problem(
    table,
    brdf: BRDF,
    medium: Medium | None = None,
    *,
    free=(),
    black=None,
    what: str = "session",
    data: FitData | None = None,
) -> Problem:
    """One session as a :class:`Problem` over the BRDF's parameters and the medium's (names
    as declared, the medium's aliased where declared); ``free`` names the estimated ones,
    the others hold the given models' values. The problem of a step fit of docs/model.md sec. 7.
    ``data`` (already prepared) replaces ``table`` and ``black``."""
    data = prepare(table, black, what) if data is None else data
    session = Session(data.table, "none" if medium is None else "m", "target", name=what)
    params = model_slots(brdf, "brdf", "target")
    values = list(brdf.to_vector())
    im = None
    if medium is not None:
        params += model_slots(medium, "medium", "m")
        values += list(medium.to_vector())
        im = np.arange(len(type(brdf).PARAMS), len(params))
    names = [p.name for p in params]
    if len(set(names)) != len(names):
        assert medium is not None  # a model's own names differ
        raise FitError(
            f"the parameters of {brdf.NAME} and {medium.NAME} share a "
            f"name ({', '.join(names)}): one of them must declare an alias"
        )
    free = list(free)
    unknown = [n for n in free if n not in names]
    if unknown:
        raise FitError(
            f"{', '.join(map(repr, unknown))}: not a parameter of this session "
            f"(parameters: {', '.join(names)})"
        )
    mask = np.array([n in free for n in names])
    if not mask.any():
        raise FitError("no free parameter: nothing to fit")
    block = Block(session, data, np.arange(len(type(brdf).PARAMS)), im, brdf, medium)
    return Problem([block], params, values, mask, weighted=data.sigma is not None)


__all__ = [
    "ITERATION_ACCURACY",
    "CLEAR",
    "OBJECTS",
    "check_accuracy",
    "SessionModel",
    "Session",
    "Slot",
    "model_slots",
    "Block",
    "Problem",
    "session_problem",
]
