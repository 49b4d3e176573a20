"""The "moving object" one-sided Lipschitz plant (Abbaszadeh & Marquez 2010; Nguyen et al. 2018).

::

    A = [[-1, 1], [1.5, -0.5]],  B = [0, -1]',  C = [0, 1],
    f(x) = -x (x1^2 + x2^2) = -||x||^2 x.

A has eigenvalues 0.5 and -2. Sources: ``x(0) = (0.1, -0.1)``, ``x_hat(0) = (-0.1, 0.1)``, the
region r = 10; the disturbance inputs ``Bw = Wc = [2, 1]'``, ``Dw = D = 1`` of Nguyen et al. (2018),
Example 2 (``x' = A x + B u + f(x) + Wc w``, ``y = C x + D w``; they then discretise by Euler with
ts = 1 ms). ``f = -grad(||x||^4 / 4)`` is monotone, so rho = 0 globally, while f is Lipschitz
only locally.

Constants on the (convex) ball ``||x|| <= r``: along a segment ``df = -H dx`` with ``H`` the average
of ``-J(x) = ||x||^2 I + 2 x x'``, symmetric, ``0 <= H <= 3 r^2 I``. So alpha = 3 r^2 (tight at
``||x|| = r``, dx along x); ``<df, dx> = -dx' H dx <= 0``, rho = 0; and ``||df||^2 = dx' H^2 dx
<= 3 r^2 dx' H dx = -3 r^2 <dx, df>``, so (beta, gamma) = (0, -3 r^2), tight. The sources claim
rho = 0, alpha = 3 r^2 and the looser (0, -4 r^2).

References
----------
.. [1] M. Abbaszadeh and H. J. Marquez, "Nonlinear observer design for one-sided Lipschitz
   systems", Proc. American Control Conference, 2010 (the nonlinearity).
.. [2] M. C. Nguyen, P. N. Pathirana and H. Trinh, European Journal of Control, 2018,
   Example 2 (the plant, initial conditions and r = 10).
"""

from __future__ import annotations

import numpy as np

from bench.registry import register_plant
from plants._core import Constants, Plant, PlantError, check_real

__all__ = ["moving_object"]

SOURCE = (
    "Abbaszadeh & Marquez, ACC 2010 (nonlinearity); Nguyen, Pathirana & Trinh, Eur. J. Control 2018, "
    "Example 2 (plant, initial conditions, r = 10, disturbance inputs Wc, D)"
)

A = np.array([[-1.0, 1.0], [1.5, -0.5]])
B = np.array([[0.0], [-1.0]])
C = np.array([[0.0, 1.0]])
X0 = np.array([0.1, -0.1])
X_HAT0 = np.array([-0.1, 0.1])

#: Disturbance inputs of Nguyen et al. 2018, Example 2 (the continuous model before their Euler step):
#: ``x' = ... + Wc w``, ``y = C x + D w`` with ``Wc = [2, 1]'``, ``D = 1``.
BW = np.array([[2.0], [1.0]])
DW = np.array([[1.0]])

#: Region radius used by Nguyen et al.
R_SOURCE = 10.0


def _f(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return -np.sum(x * x, axis=0) * x


def _jacobian(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float).reshape(-1)
    return -(float(x @ x) * np.eye(x.size) + 2.0 * np.outer(x, x))


@register_plant("moving_object_v1")
def moving_object(*, r: float = R_SOURCE, t_final: float = 20.0) -> Plant:
    """Moving object OSL plant (Abbaszadeh & Marquez 2010; Nguyen et al. 2018): f = -||x||^2 x.

    Parameters
    ----------
    r : float
        Radius of the region ``||x|| <= r`` where the local constants hold (10 in the source).
    t_final : float
        Simulation horizon in seconds.

    Returns
    -------
    Plant
        PlantError when the region ``||x|| <= r`` does not contain the initial conditions.
    """
    r = check_real("r", r, lo=0.0, strict=True)
    for name, v in (("x0", X0), ("x_hat0", X_HAT0)):
        if np.linalg.norm(v) > r:
            raise PlantError(f"r: the region ||x|| <= {r:g} must contain {name} = {v.tolist()}")
    return Plant(id="moving_object_v1", A=A, B=B, C=C, f=_f, jacobian=_jacobian, x0=X0, x_hat0=X_HAT0,
                 claimed=Constants(alpha=3 * r**2, rho=0.0, beta=0.0, gamma=-4 * r**2, radius=r),
                 bounds=Constants(alpha=3 * r**2, rho=0.0, beta=0.0, gamma=-3 * r**2, radius=r),
                 Bw=BW, Dw=DW, t_final=t_final, family="moving_object", params={"r": r, "version": 1}, source=SOURCE,
                 notes="OSL with rho = 0 globally; Lipschitz only locally (3 r^2 on ||x|| <= r)",
                 state_names=("x1 [-]", "x2 [-]"))
