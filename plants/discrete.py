"""Discrete-time plants of the catalog: continuous plants of the catalog sampled at a stated time.

``flexible_link_d10ms_v1`` is :func:`plants.flexible_link.flexible_link` (the seed paper's eqs.
(34)-(38), gravity on the link angle, c = 0.333) discretised by :meth:`plants.Plant.discretise` with a
zero-order hold at h = 0.01 s: ``A_d = expm(h A)``, ``B_d = Gamma B``, ``f_d = Gamma f`` with ``Gamma =
int_0^h expm(A s) ds``; C, x0, x_hat0 and the 20 s horizon (2000 steps) kept. The fastest mode of A is
about 7 rad/s, so ``h |lambda| ~ 0.07``. The constants of ``f_d`` are derived by the rules stated in
:meth:`plants.Plant.discretise` and checked by the sampler as every plant's.
"""

from __future__ import annotations

import dataclasses

from bench.registry import register_plant
from plants._core import Plant
from plants.flexible_link import flexible_link

__all__ = ["flexible_link_d10ms"]

#: Sample time of ``flexible_link_d10ms_v1`` in seconds.
H_FLEXIBLE_LINK = 0.01


@register_plant("flexible_link_d10ms_v1", order=3)
def flexible_link_d10ms(*, c: float = 0.333, t_final: float = 20.0) -> Plant:
    """Flexible link manipulator (35)-(36) with a zero-order hold at h = 10 ms (discrete time).

    Parameters
    ----------
    c : float
        Coefficient of the gravity term ``f4 = -c sin(x3)`` of the continuous plant.
    t_final : float
        Horizon in seconds (rounded up to a multiple of h).

    Returns
    -------
    Plant
        ``dt = 0.01``; params ``c``, ``h``, ``zoh = 1``, ``version = 1``.
    """
    plant = flexible_link(c=c, t_final=t_final).discretise(H_FLEXIBLE_LINK, "zoh", id="flexible_link_d10ms_v1")
    return dataclasses.replace(plant, params={**plant.params, "version": 1})
