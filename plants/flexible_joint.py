"""Single-link flexible-joint robot in unscaled coordinates (Zemouche & Boutayeb 2013).

State ``x = (theta_m, omega_m, theta_l, omega_l)`` (the paper's plant (35) scales x4 = omega_l / 10) ::

    A = [[0, 1, 0, 0], [-48.6, -1.25, 48.6, 0], [0, 0, 0, 1], [19.5, 0, -19.5, 0]]
    B = [0, 21.6, 0, 0]',  C = [I2 0],  f(x) = [0, 0, 0, -c sin(x3)]',  c = 3.33,

B and C those of :mod:`plants.flexible_link`. Unscaled, c is ten times the paper's 0.333. Initial
conditions of the sources: ``x(0) = (0.1, -0.1, 0.2, -0.2)``, ``x_hat(0) = (0.2, -0.2, 0.1, -0.1)``.
Disturbance inputs of [2], eq. (64): ``x' = ... + Wc w``, ``y = C x + Dc w``, ``Bw = Wc = [1, 0, 0, 0]'``,
``Dw = Dc = [1, 0]'`` ([2] then discretises by Euler at ts = 1 ms: ``flexible_joint(...).discretise(0.001,
"euler")`` is their discrete plant (1), W = ts Wc, D = Dc).
Constants and channels of the sine term: :func:`plants._core.sine_terms`, as :func:`flexible_joint` returns them.

References
----------
.. [1] A. Zemouche and M. Boutayeb, "On LMI conditions to design observers for Lipschitz
   nonlinear systems", Automatica 49(2), 2013 (flexible-joint robot example).
.. [2] M. C. Nguyen, P. N. Pathirana and H. Trinh, "Robust observer-based control designs for discrete
   nonlinear systems with disturbances", European Journal of Control, 2018, doi:10.1016/j.ejcon.2018.09.002,
   Example 1.
"""

from __future__ import annotations

import numpy as np

from bench.registry import register_plant
from plants._core import Constants, Plant, check_real, sine_terms
from plants.flexible_link import B, C

__all__ = ["flexible_joint"]

SOURCE = (
    "Zemouche & Boutayeb, Automatica 49(2), 2013 (flexible-joint robot example); also Nguyen, "
    "Pathirana & Trinh, Eur. J. Control 2018, Example 1, eq. (64) (with the disturbance inputs Wc, Dc)"
)

A = np.array(
    [[0.0, 1.0, 0.0, 0.0], [-48.6, -1.25, 48.6, 0.0], [0.0, 0.0, 0.0, 1.0], [19.5, 0.0, -19.5, 0.0]]
)
X0 = np.array([0.1, -0.1, 0.2, -0.2])
X_HAT0 = np.array([0.2, -0.2, 0.1, -0.1])

#: The coefficient of sin(x3) in the sources.
C_SOURCE = 3.33

#: Disturbance inputs of Nguyen et al. 2018, Example 1, eq. (64) (the continuous model before their Euler
#: step): ``x' = ... + Wc w``, ``y = C x + Dc w`` with ``Wc = [1, 0, 0, 0]'``, ``Dc = [1, 0]'``.
BW = np.array([[1.0], [0.0], [0.0], [0.0]])
DW = np.array([[1.0], [0.0]])


@register_plant("flexible_joint_v1")
def flexible_joint(*, c: float = C_SOURCE, t_final: float = 20.0) -> Plant:
    """Flexible-joint robot, unscaled (Zemouche & Boutayeb 2013): f4 = -c sin(x3).

    Parameters
    ----------
    c : float
        Coefficient of the gravity term (3.33 in the sources).
    t_final : float
        Simulation horizon in seconds.

    Returns
    -------
    Plant
        Claimed: the sources' alpha = 3.33 (for their c only); bounds: alpha = |c|, rho = |c|/2,
        (beta, gamma) = (c^2, 0), global.
    """
    c = check_real("c", c)
    gravity = sine_terms(4, acts=[3], reads=[2], coef=-c)
    claimed = Constants(alpha=C_SOURCE) if c == C_SOURCE else Constants()
    return Plant(id="flexible_joint_v1", A=A, B=B, C=C, x0=X0, x_hat0=X_HAT0, **gravity, claimed=claimed,
                 Bw=BW, Dw=DW, t_final=t_final, family="flexible_joint", params={"c": c, "version": 1}, source=SOURCE,
                 notes="unscaled coordinates (x4 = omega_l); f4 = -c sin(x3); claimed: Lipschitz alpha only",
                 state_names=("theta_m [rad]", "omega_m [rad/s]", "theta_l [rad]", "omega_l [rad/s]"))
