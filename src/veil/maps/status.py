"""The status of a pixel of a map (the ``status`` map; docs/maps.md)."""

from __future__ import annotations

#: Pixel status codes (the ``status`` map).
STATUS = {
    0: "converged",
    1: "masked (outside the mask, or no photo usable at this pixel)",
    2: "too few points (fewer usable photos than free parameters + 1: saturated, clipped or dark)",
    3: "not determined (a scale at zero, a rank-deficient Jacobian, or no positive value)",
    4: "at the edge of the table (a nonlinear parameter at the end of its tabulated range)",
    5: "did not converge (last Gauss-Newton step above the tolerance)",
}
CONVERGED, MASKED, FEW_POINTS, UNDETERMINED, EDGE, NOT_CONVERGED = range(6)


__all__ = ["STATUS", "CONVERGED", "MASKED", "FEW_POINTS", "UNDETERMINED", "EDGE", "NOT_CONVERGED"]
