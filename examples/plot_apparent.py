"""
The paper's object through its three media
===========================================

The apparent reflectance f(I, R) of docs/model.md eq. (1): the paper's object BRDF1 seen
through its three simulated media BTDF1-3 (docs/model.md sec. 6), in the plane of incidence
with the light at 30 deg, beside the object's own f_r (eq. 2a). From BTDF1 to BTDF3 the
medium scatters more and more broadly (g from 0.98 to 0.88): the specular peak at
theta_r = 30 deg spreads, and the off-specular floor rises towards the peak. The levels are
relative: the media's coefficients T_d and T_t scale the curves (docs/model.md sec. 3).
"""

import matplotlib.pyplot as plt
import numpy as np

import veil

theta_i = 30.0
theta_r = np.linspace(-80.0, 80.0, 161)      # signed in-plane: < 0 is the light's side
ti = np.full_like(theta_r, theta_i)
phi_r = np.where(theta_r >= 0, 0.0, 180.0)  # the camera's azimuth (light at 180 deg)
tr = np.abs(theta_r)

fig, ax = plt.subplots(figsize=(6.4, 4.0))
ax.semilogy(theta_r, veil.reflectance(veil.BRDF1, ti, tr, 180.0, phi_r), "k--",
            label="BRDF1 in clear water")
for name in ("BTDF1", "BTDF2", "BTDF3"):
    value = veil.apparent(veil.BRDF1, veil.PRESETS[name], ti, tr, 180.0, phi_r,
                          accuracy="fast")
    ax.semilogy(theta_r, value, label=f"through {name}")
ax.set_xlabel("theta_r (deg), light at theta_i = 30 deg")
ax.set_ylabel("apparent reflectance (relative)")
ax.legend()
fig.tight_layout()
plt.show()
