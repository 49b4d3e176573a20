"""The two discrete-time examples of Nguyen, Pathirana & Trinh (Eur. J. Control 2018), with their printed gains.

Both examples take a continuous model of the catalog, add the disturbance inputs of eq. (64) and discretise it
by Euler at ``ts = 1 ms``: ``A = I + ts Ac``, ``B = ts Bc``, ``f = ts fc``, ``W = ts Wc``, ``C = Cc``,
``D = Dc`` (the paper's words, Examples 1 and 2), which is :meth:`plants.Plant.discretise` with ``method =
"euler"`` (the constants of ``f`` follow exactly: Lipschitz ``ts alpha``, OSL ``ts rho``, QIB
``(ts^2 beta, ts gamma)``).

- ``nguyen2018_ex1_flexible_joint_v1``: Example 1, the single-link flexible-joint robot of eq. (64)
  (:func:`plants.flexible_joint.flexible_joint`, f4 = -3.33 sin(x3)), ``Wc = [1 0 0 0]'``, ``Dc = [1 0]'``,
  ``x(0) = [0.1 -0.1 0.2 -0.2]'``, ``x_hat(0) = [0.2 -0.2 0.1 -0.1]'``.
- ``nguyen2018_ex2_moving_object_v1``: Example 2, the "moving object" of Abbaszadeh & Marquez (ACC 2010)
  (:func:`plants.moving_object.moving_object`, f = -||x||^2 x on ``||x|| <= r``, r = 10), ``Wc = [2 1]'``,
  ``D = 1``, ``x(0) = [0.1 -0.1]'``, ``x_hat(0) = [-0.1 0.1]'``. The paper states (citing Abbaszadeh &
  Marquez) rho = 0, QIB ``beta = 0``, ``gamma = -4 r^2 ts`` and the local Lipschitz constant ``3 r^2 ts``:
  these are the plant's claimed constants after the Euler step (the trusted QIB pair is the tighter
  ``(0, -3 r^2 ts)``, :mod:`plants.moving_object`).

Horizon: 50 s (50,000 steps), the time axis of the paper's Figures 1-5. Both plants run on request only
(``--plant 'nguyen2018*'``; registered with ``default=False``): together they would add about 30 % to the CPU
time of the default run (docs/literature.md, "Cost").

The printed gains (:data:`EX1_K`, :data:`EX1_L`, :data:`EX2_K`, :data:`EX2_L`) are in the paper's notation,
``u = -K x_hat`` and observer gain ``L``: oslbench's ``F = -K`` and ``K = L`` (the design
:mod:`designs.nguyen2018_gains`). Example 1's L is printed as a 4 x 2 matrix whose eight entries the
text conversion gives as 0.0010, -0.0857, 0.0000, 0.6452, 0.0000, 0.3858, 0.0000, 0.2444; read row by row
(:data:`EX1_L`), ``A - L C`` has spectral radius 0.99905 < 1, read column by column 1.0008 > 1 (an unstable
observer), and the row reading makes L's first column equal to ``W`` (``W - L D = 0``: the disturbance does
not reach the error, as in Example 2, where ``W - L D = ts [2 1]' - [0.002 0.001]' = 0`` too). The same
conversion gives ``Cc`` and the LPV vertices row by row. Tests: ``tests/test_literature_examples.py``.

References
----------
.. [1] C. M. Nguyen, P. N. Pathirana and H. Trinh, "Robust observer-based control designs for discrete
   nonlinear systems with disturbances", European Journal of Control, 2018, doi:10.1016/j.ejcon.2018.09.002
   (accepted manuscript; Example 1 pp. 13-15, Example 2 pp. 15-16).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.registry import register_plant
from plants._core import Plant
from plants.flexible_joint import C_SOURCE, flexible_joint
from plants.moving_object import R_SOURCE, moving_object

__all__ = ["EX1_K", "EX1_L", "EX2_K", "EX2_L", "TS", "nguyen2018_ex1", "nguyen2018_ex2", "paper_disturbance"]

#: Sample time of both examples, seconds ("ts = 1ms = 0.001s").
TS = 0.001
#: Horizon of the paper's simulations, seconds (the time axis of Figures 1-5).
T_FINAL = 50.0

CITATION = ("Nguyen, Pathirana & Trinh, Eur. J. Control 2018, doi:10.1016/j.ejcon.2018.09.002")

#: Example 1, Theorem 3: controller gain (``u = -K x_hat``), 1 x 4, as printed.
EX1_K = np.array([[5705.0767, 33.3035, -3310.2808, 401.3578]])
#: Example 1, Theorem 3: observer gain L, 4 x 2, the printed entries read row by row (module docstring).
EX1_L = np.array([[0.0010, -0.0857], [0.0000, 0.6452], [0.0000, 0.3858], [0.0000, 0.2444]])
#: Example 2, Theorem 1 (eps0 = 0.0372): controller gain (``u = -K x_hat``), 1 x 2, as printed.
EX2_K = np.array([[-5.8992, -637.0308]])
#: Example 2, Theorem 1: observer gain L, 2 x 1, as printed.
EX2_L = np.array([[0.0020], [0.0010]])


def paper_disturbance(t) -> np.ndarray:
    """The disturbance of both examples' simulations (Example 1; "omega(k) as in Example 1" in Example 2).

    ``omega(k) = 0.1 cos(0.5 ts k)`` for ``k`` in ``((20 i - 3) / ts, 20 i / ts]``, ``i = 1, 2, ...``, and 0
    otherwise: bursts of ``0.1 cos(0.5 t)`` over the last 3 s of every 20 s (Figure 1 plots it over 0-50 s).
    The interval's brackets are lost in the text read (docs/literature.md); open on the left and closed on the
    right here, which moves one sample per burst.

    Parameters
    ----------
    t : float or array_like
        Times ``t = k ts`` in seconds.

    Returns
    -------
    ndarray
        Shape (1,) for a scalar t, (1, N) for N times (one disturbance input, as the plants' ``Bw``).
    """
    tt = np.asarray(t, dtype=float)
    phase = np.mod(tt, 20.0)
    on = ((phase > 17.0) | (phase == 0.0)) & (tt > 17.0)  # (20 i - 3, 20 i] for i >= 1
    w = np.where(on, 0.1 * np.cos(0.5 * tt), 0.0)
    return w.reshape(1) if tt.ndim == 0 else w.reshape(1, -1)


def _euler(plant: Plant, pid: str, source: str, notes: str) -> Plant:
    """``plant`` discretised by Euler at :data:`TS` under the id ``pid``, with the example's source and notes."""
    d = plant.discretise(TS, "euler", id=pid)
    return dataclasses.replace(d, source=source, notes=notes, params={**d.params, "version": 1})


@register_plant("nguyen2018_ex1_flexible_joint_v1", order=4, default=False)
def nguyen2018_ex1(*, c: float = C_SOURCE, t_final: float = T_FINAL) -> Plant:
    """Nguyen et al. 2018, Example 1: the flexible-joint robot (64), Euler at ts = 1 ms, with disturbance inputs.

    Parameters
    ----------
    c : float
        Coefficient of sin(x3) in the continuous model (3.33 in the paper; the knob of ``study admissible``).
    t_final : float
        Horizon in seconds (default 50 s, the paper's figures).

    Returns
    -------
    Plant
        ``dt = 0.001``; ``A = I + ts Ac``, ``B = ts Bc``, ``f = ts fc``, ``Bw = ts Wc``, ``Dw = Dc``; the
        paper's x(0), x_hat(0); constants of ``ts f`` (alpha = 3.33 ts, rho = 1.665 ts, (beta, gamma) =
        ((3.33 ts)^2, 0), global; claimed alpha = 3.33 ts, the LPV vertices' +-ts 3.33).
    """
    return _euler(flexible_joint(c=c, t_final=t_final), "nguyen2018_ex1_flexible_joint_v1",
                  f"{CITATION}, Example 1, eq. (64) (flexible-joint robot with disturbance inputs Wc, Dc), Euler at "
                  "ts = 1 ms (A = I + ts Ac, B = ts Bc, f = ts fc, W = ts Wc, C = Cc, D = Dc); x(0), x_hat(0) of "
                  "Example 1; printed gains K, L and mu = 1.0100 (Theorem 3), mu = 1.4392 (Theorem 4)",
                  "discrete time, dt = 1 ms, 50,000 steps over the paper's 50 s; f4 = -3.33 ts sin(x3)")


@register_plant("nguyen2018_ex2_moving_object_v1", order=4, default=False)
def nguyen2018_ex2(*, r: float = R_SOURCE, t_final: float = T_FINAL) -> Plant:
    """Nguyen et al. 2018, Example 2: the moving object, Euler at ts = 1 ms, with disturbance inputs, r = 10.

    Parameters
    ----------
    r : float
        Radius of the region ``||x|| <= r`` of the constants (10 in the paper; the knob of ``study admissible``).
    t_final : float
        Horizon in seconds (default 50 s, the paper's figures).

    Returns
    -------
    Plant
        ``dt = 0.001``; ``A = I + ts Ac``, ``B = ts Bc``, ``f = -ts ||x||^2 x``, ``Bw = ts Wc``, ``Dw = 1``;
        constants on ``||x|| <= 10``: claimed (the paper's) alpha = 3 r^2 ts = 0.3, rho = 0,
        (beta, gamma) = (0, -4 r^2 ts) = (0, -0.4); trusted (0, -3 r^2 ts).
    """
    return _euler(moving_object(r=r, t_final=t_final), "nguyen2018_ex2_moving_object_v1",
                  f"{CITATION}, Example 2 (moving object of Abbaszadeh & Marquez ACC 2010, disturbance inputs Wc, D, "
                  "r = 10), Euler at ts = 1 ms (A = I + ts Ac, B = ts Bc, f = ts fc, W = ts Wc, C = Cc, D = Dc); "
                  "x(0), x_hat(0) of Example 2; printed gains K, L (Theorem 1, eps0 = 0.0372) and mu = 1.9956 "
                  "(Theorem 1), mu = 2.0214 (Theorem 2)",
                  "discrete time, dt = 1 ms, 50,000 steps over the paper's 50 s; OSL rho = 0, local constants on "
                  "||x|| <= 10")
