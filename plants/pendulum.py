"""Damped pendulum with a torque input (textbook; Khalil, Nonlinear Systems, Sec. 1.2.1).

The pendulum equation ``m l theta'' = -m g sin(theta) - k l theta' + T / l`` with
``x = (theta, omega)``, the friction ratio ``b = k / m`` and the torque scaled so that
``u = T / (m l^2)`` gives ::

    A = [[0, 1], [0, -b]],  B = [0, 1]',  C = [1, 0],  f(x) = [0, -(g/l) sin(x1)]'.

Values picked here: ``g / l = 9.81``, ``b = 0.1``, the angle measured, ``x(0) = (1, 0)``,
``x_hat(0) = 0``; the whole sine is in f (A has eigenvalues 0 and -b). Constants and channels of
the sine term: :func:`plants._core.sine_terms` (alpha = g/l, rho = (g/l)/2, (beta, gamma) =
((g/l)^2, 0), global); claimed: alpha and rho.

References
----------
.. [1] H. K. Khalil, Nonlinear Systems, 3rd ed., Prentice Hall, 2002, Section 1.2.1
   (pendulum equation).
"""

from __future__ import annotations

import numpy as np

from bench.registry import register_plant
from plants._core import Constants, Plant, check_real, sine_terms

__all__ = ["pendulum"]

SOURCE = "Khalil, Nonlinear Systems, 3rd ed., 2002, Sec. 1.2.1 (pendulum equation); g/l = 9.81, b = 0.1 picked"

G_OVER_L = 9.81
DAMPING = 0.1
X0 = np.array([1.0, 0.0])
X_HAT0 = np.array([0.0, 0.0])


@register_plant("pendulum_v1")
def pendulum(*, g_over_l: float = G_OVER_L, b: float = DAMPING, t_final: float = 20.0) -> Plant:
    """Damped pendulum (Khalil, Sec. 1.2.1): f2 = -(g/l) sin(x1), g/l = 9.81, b = 0.1.

    Parameters
    ----------
    g_over_l : float
        Ratio g / l in 1/s^2, >= 0 (9.81 by default).
    b : float
        Viscous friction ratio k / m in 1/s, >= 0 (0.1 by default).
    t_final : float
        Simulation horizon in seconds.

    Returns
    -------
    Plant
    """
    k = check_real("g_over_l", g_over_l, lo=0.0)
    b = check_real("b", b, lo=0.0)
    gravity = sine_terms(2, acts=[1], reads=[0], coef=-k)
    return Plant(id="pendulum_v1", A=np.array([[0.0, 1.0], [0.0, -b]]), B=np.array([[0.0], [1.0]]),
                 C=np.array([[1.0, 0.0]]), x0=X0, x_hat0=X_HAT0, **gravity,
                 claimed=Constants(alpha=k, rho=k / 2), t_final=t_final, family="pendulum",
                 params={"g_over_l": k, "b": b, "version": 1}, source=SOURCE,
                 notes="theta measured; the whole sine is in f (A has eigenvalues 0 and -b)",
                 state_names=("theta [rad]", "omega [rad/s]"))
