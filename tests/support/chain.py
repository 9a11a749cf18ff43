"""The paper's two-step chain on small sessions (55 configurations, one engine chunk) at 0.3 %
noise and the "fast" quadrature, where the medium is well determined and a first-order
propagation holds: shared by the uncertainty tests (tests/test_uncertainty.py,
tests/test_propagation.py)."""

import veil
from veil.fitting import fit_medium, fit_reference

SMALL = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")


def small_chain() -> dict:
    """Steps 0 and 1 (BRDF2 as reference in BTDF3) and the target's session (BRDF1):
    {"r0", "r1", "ref_medium", "target"}."""
    ref_clear = veil.simulate(veil.BRDF2, None, noise=0.003, seed=11, **SMALL)
    ref_medium = veil.simulate(veil.BRDF2, veil.BTDF3, noise=0.003, seed=12, **SMALL)
    target = veil.simulate(veil.BRDF1, veil.BTDF3, noise=0.003, seed=13, **SMALL)
    r0 = fit_reference(ref_clear)
    r1 = fit_medium(ref_medium, r0, accuracy="fast")
    return {"r0": r0, "r1": r1, "ref_medium": ref_medium, "target": target}
