"""Chua's circuit, double-scroll parameters (Chua, Komuro & Matsumoto 1986).

Dimensionless Chua circuit with a control input on the first state ::

    x1' = a (x2 - x1 - h(x1)) + u,   x2' = x1 - x2 + x3,   x3' = -b x2,
    h(x1) = m1 x1 + (m0 - m1) (|x1 + 1| - |x1 - 1|) / 2,

with the double-scroll values a = 9, b = 14.28, m0 = -1/7, m1 = 2/7. The linear part of h
(``m1 x1``) goes into A and the saturation into f::

    A = [[-a (1 + m1), a, 0], [1, -1, 1], [0, -b, 0]],
    f(x) = [k sat(x1), 0, 0]',  k = -a (m0 - m1) = 27/7,  sat(s) = (|s + 1| - |s - 1|) / 2.

Chosen here: ``B = C' = e1``, ``x(0) = (0.7, 0, 0)``, ``x_hat(0) = 0``.

Constants (analytic, global): sat is monotone with slopes in [0, 1], so ``df = k s dx1 e1`` with
``s in [0, 1]``: alpha = |k|; ``<df, dx> = k s dx1^2`` gives rho = max(k, 0) (tight inside
|x1| < 1); (beta, gamma) = (k^2, 0). Claimed by the source: alpha = a |m0 - m1|. Channel (global):
``G = H' = e1``, ``phi(z) = k sat(z)``, slopes in ``[min(k, 0), max(k, 0)]``.

References
----------
.. [1] L. O. Chua, M. Komuro and T. Matsumoto, "The double scroll family", IEEE Trans.
   Circuits and Systems 33(11), 1986.
"""

from __future__ import annotations

import numpy as np

from bench.registry import register_plant
from plants._core import Channels, Constants, Plant, check_real, saturation_slopes

__all__ = ["chua"]

SOURCE = "Chua, Komuro & Matsumoto, IEEE TCAS 33(11), 1986 (double scroll); B = C' = e1 chosen here"

X0 = np.array([0.7, 0.0, 0.0])
X_HAT0 = np.array([0.0, 0.0, 0.0])


@register_plant("chua_v1")
def chua(
    *, a: float = 9.0, b: float = 14.28, m0: float = -1.0 / 7.0, m1: float = 2.0 / 7.0, t_final: float = 20.0
) -> Plant:
    """Chua's circuit, double scroll (a = 9, b = 14.28, m0 = -1/7, m1 = 2/7), B = C' = e1.

    Parameters
    ----------
    a, b : float
        Circuit parameters (alpha and beta of the dimensionless Chua equations).
    m0, m1 : float
        Inner and outer slopes of Chua's diode ``h``.
    t_final : float
        Simulation horizon in seconds.

    Returns
    -------
    Plant
    """
    a, b, m0, m1 = (check_real(name, v) for name, v in (("a", a), ("b", b), ("m0", m0), ("m1", m1)))
    k = -a * (m0 - m1)

    def f(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        out = np.zeros_like(x)
        out[0] = k * 0.5 * (np.abs(x[0] + 1.0) - np.abs(x[0] - 1.0))
        return out

    def jacobian(x: np.ndarray) -> np.ndarray:
        J = np.zeros((3, 3))
        J[0, 0] = k if abs(float(np.asarray(x, dtype=float)[0])) < 1.0 else 0.0
        return J

    A = np.array([[-a * (1.0 + m1), a, 0.0], [1.0, -1.0, 1.0], [0.0, -b, 0.0]])
    channels = Channels(G=np.array([[1.0], [0.0], [0.0]]), H=np.array([[1.0, 0.0, 0.0]]),
                        phi=lambda z: k * 0.5 * (np.abs(z + 1.0) - np.abs(z - 1.0)), lo=min(k, 0.0), hi=max(k, 0.0),
                        narrow=saturation_slopes(k))
    return Plant(id="chua_v1", A=A, B=np.array([[1.0], [0.0], [0.0]]), C=np.array([[1.0, 0.0, 0.0]]), f=f,
                 jacobian=jacobian, x0=X0, x_hat0=X_HAT0, claimed=Constants(alpha=abs(a * (m0 - m1))),
                 bounds=Constants(alpha=abs(k), rho=max(k, 0.0), beta=k**2, gamma=0.0), channels=channels,
                 t_final=t_final, family="chua", params={"a": a, "b": b, "m0": m0, "m1": m1, "version": 1},
                 source=SOURCE, notes="m1 x1 in A, the saturation in f; B = [1,0,0]', C = [1,0,0]",
                 state_names=("x1 = v_C1 [-]", "x2 = v_C2 [-]", "x3 = i_L [-]"))
