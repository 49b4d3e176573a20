"""Single-link flexible-joint robot in unscaled coordinates (Zemouche & Boutayeb 2013).

State ``x = (theta_m, omega_m, theta_l, omega_l)``: motor angle and velocity, link angle and
velocity (no scaling of omega_l, unlike the paper's plant (35) whose x4 is omega_l / 10). ::

    A = [[0, 1, 0, 0], [-48.6, -1.25, 48.6, 0], [0, 0, 0, 1], [19.5, 0, -19.5, 0]]
    B = [0, 21.6, 0, 0]',  C = [I2 0],  f(x) = [0, 0, 0, -c sin(x3)]',  c = 3.33.

The gravity term acts on the link angle x3 with c = 3.33, ten times the paper's 0.333 because
the fourth state is not divided by 10: a harder case for every design (Lipschitz constant
3.33 instead of 0.333). Initial conditions of the sources' simulation:
``x(0) = (0.1, -0.1, 0.2, -0.2)``, ``x_hat(0) = (0.2, -0.2, 0.1, -0.1)``.

Constants of ``f = (0, 0, 0, -c sin(x3))`` (analytic, global; same argument as the flexible
link): alpha = c; rho = c / 2, since ``<df, dx> = -c (sin a - sin b) d4 <= c |d3| |d4| <=
(c/2)(d3^2 + d4^2)``, tight for ``dx = (0, 0, -d, d)`` as d -> 0 near x3 = 0; and
``(beta, gamma) = (c^2, 0)`` since ``||df||^2 = c^2 (sin a - sin b)^2 <= c^2 d3^2``. The
sources claim the Lipschitz constant alpha = 3.33 only (they design Lipschitz observers).
Channel structure (global): ``G = e4``, ``H = e3'``, ``phi(z) = -c sin(z)``, slopes in ``[-|c|, |c|]``.

References
----------
.. [1] A. Zemouche and M. Boutayeb, "On LMI conditions to design observers for Lipschitz
   nonlinear systems", Automatica 49(2), 2013 (flexible-joint robot example).
.. [2] M. C. Nguyen, P. N. Pathirana and H. Trinh, European Journal of Control, 2018 (the same
   robot as an example).
"""

from __future__ import annotations

import numpy as np

from bench.registry import register_plant
from plants._core import Constants, Plant, check_real, sine_terms

__all__ = ["flexible_joint"]

SOURCE = (
    "Zemouche & Boutayeb, Automatica 49(2), 2013 (flexible-joint robot example); also Nguyen, "
    "Pathirana & Trinh, Eur. J. Control 2018"
)

A = np.array(
    [[0.0, 1.0, 0.0, 0.0], [-48.6, -1.25, 48.6, 0.0], [0.0, 0.0, 0.0, 1.0], [19.5, 0.0, -19.5, 0.0]]
)
B = np.array([[0.0], [21.6], [0.0], [0.0]])
C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
X0 = np.array([0.1, -0.1, 0.2, -0.2])
X_HAT0 = np.array([0.2, -0.2, 0.1, -0.1])

#: The coefficient of sin(x3) in the sources.
C_SOURCE = 3.33


@register_plant("flexible_joint_v1")
def flexible_joint(*, c: float = C_SOURCE, t_final: float = 20.0) -> Plant:
    """Flexible-joint robot, unscaled (Zemouche & Boutayeb 2013): f4 = -3.33 sin(x3).

    Parameters
    ----------
    c : float
        Coefficient of the gravity term, ``f4 = -c sin(x3)`` (3.33 in the sources).
    t_final : float
        Simulation horizon in seconds.

    Returns
    -------
    Plant
        Version 1 of the plant; claimed constants are the sources' (alpha = 3.33), the analytic
        bounds are global: alpha = |c|, rho = |c|/2, (beta, gamma) = (c^2, 0).
    """
    c = check_real("c", c)
    gravity = sine_terms(4, acts=[3], reads=[2], coef=-c)
    # the sources' claim is about their c; for another c there is no claim to check
    claimed = Constants(alpha=C_SOURCE) if c == C_SOURCE else Constants()
    return Plant(id="flexible_joint_v1", A=A, B=B, C=C, x0=X0, x_hat0=X_HAT0, **gravity.fields(), claimed=claimed,
                 t_final=t_final, family="flexible_joint", params={"c": c, "version": 1}, source=SOURCE,
                 notes="unscaled coordinates (x4 = omega_l); f4 = -c sin(x3); claimed: Lipschitz alpha only")
