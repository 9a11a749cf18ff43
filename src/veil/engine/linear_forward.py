"""A linear family through a medium (``LINEAR``, docs/nonparametric.md): the sum of its
column model's programs, one group of basis functions at a time.

A family such as :class:`veil.models.nonparametric.NonParametric` sums lobes of very
different widths. One quadrature of the sum samples its half vectors from one law, which
resolves no lobe well (6 % off at the default rule for a narrow and a broad lobe together).
Its ``column_groups()`` split the coefficients into groups that share one sampling law (one
lobe width each, the diffuse basis with the first); each group is evaluated by the family's
column model (``columns()``) with that group's coefficients, and the results add up: the
apparent reflectance is linear in the coefficients for a fixed law, so the sum is the
family's eq. (1), each lobe sampled as it needs, and the step fit's columns are its parts.
"""

from __future__ import annotations

import numpy as np

from .forward import Forward


class LinearForward(Forward):
    """:class:`Forward` of a linear family (module docstring): ``terms``, ``__call__``,
    ``value_and_jacobian`` and ``prepare`` as Forward's, from the column model's Forward."""

    def __init__(self, brdf, medium, theta_i, theta_r, phi_i=180.0, phi_r=0.0, rule=None):
        column_cls, _ = type(brdf).columns()
        self.brdf, self.medium = brdf, medium
        self._inner = Forward(column_cls.template(), medium, theta_i, theta_r, phi_i, phi_r, rule)
        self.rule, self.size, self.half = self._inner.rule, self._inner.size, self._inner.half
        self.devices = self._inner.devices
        #: [(the column model's base vector, {family index: column model index})]
        self._groups = type(brdf).column_groups()
        #: the column model's linear coefficients: every group's Jacobian takes all of them
        self._linear = tuple(sorted({c for _, where in self._groups for c in where.values()}))

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
        wanted = [(self._linear if fb else (), fm) for fb, fm in jacobians]
        return self._inner.prepare(values, wanted)

    def terms(self, vb, vm) -> np.ndarray:
        vb, vm = self._vectors(vb, vm)
        return sum(self._inner.terms(self._vector(g, vb), vm) for g in self._active(vb))

    def value_and_jacobian(self, vb, vm, free_brdf=(), free_medium=()):
        """Values and d/d(``free_brdf`` coefficients, ``free_medium``): each coefficient's
        column from its group's Jacobian in the column model's coefficients, the medium's
        summed over the groups."""
        vb, vm = self._vectors(vb, vm)
        free_brdf = self._indices(free_brdf, type(self.brdf))
        free_medium = self._indices(free_medium, type(self.medium))
        wrt_b = self._linear if free_brdf else ()
        value = np.zeros(self.size)
        jac_b = np.zeros((self.size, len(free_brdf)))
        jac_m = np.zeros((self.size, len(free_medium)))
        for g in self._active(vb, every=bool(free_brdf)):
            val, jac = self._inner.value_and_jacobian(self._vector(g, vb), vm, wrt_b, free_medium)
            value += val
            jac_m += jac[:, len(wrt_b) :]
            where = self._groups[g][1]
            for k, i in enumerate(free_brdf):
                if i in where:
                    jac_b[:, k] = jac[:, wrt_b.index(where[i])]
        return value, np.concatenate([jac_b, jac_m], axis=1)


__all__ = ["LinearForward"]
