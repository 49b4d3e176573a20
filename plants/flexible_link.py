"""The one-link flexible-joint manipulator of the paper, eqs. (34)-(38).

State ``x = (theta_m, omega_m, theta_l, omega_l / 10)``; A, B, C from (35)-(36). Table I of the
paper does not reproduce A (C_vf / I_m = 12.4, not 1.26, and the height h is missing), so A is
taken from (35) as printed. The nonlinearity is ``f4 = -c sin(x_i)`` with c = 0.333: the model
(34) and the classic sources (Raghavan & Hedrick 1994; Rajamani 1998) put gravity on the link
angle x3 (the default plant); the paper prints sin(x1) in (36) (the ``_printed`` variant).

Constants and channels of the sine term: :func:`plants._core.sine_terms` (alpha = c, rho = c / 2,
(beta, gamma) = (c^2, 0), global). The paper claims rho = beta = 0.1109, gamma = 0: its rho is c^2,
which is wrong (the pair dx = (0, 0, -d, d) gives a ratio -> c/2 = 0.1665); its beta is right.
"""

from __future__ import annotations

import numpy as np

from bench.registry import register_plant
from plants._core import Constants, Plant, check_real, sine_terms

SOURCE = (
    "Observer-based stabilization of one-sided Lipschitz systems with application to flexible "
    "link manipulator, eqs. (34)-(38)"
)

A = np.array(
    [[0.0, 1.0, 0.0, 0.0], [-48.6, -1.26, 48.6, 0.0], [0.0, 0.0, 0.0, 10.0], [1.95, 0.0, -1.95, 0.0]]
)
B = np.array([[0.0], [21.6], [0.0], [0.0]])
C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
X0 = np.array([-2.0, -2.0, -1.5, 2.0])
X_HAT0 = np.array([0.5, 1.0, 1.0, -1.0])

#: Gains printed in (37)-(38), in the paper's notation (u = F x_hat).
PAPER_K = np.array([[1.2907, -24.3525], [-23.0311, 2.6718], [1.3713, 53.2993], [5.8967, 6.7679]])
PAPER_F = np.array([[-11.7561, -1.8562, 6.4643, -14.2175]])

#: The states of (35): motor angle and speed, link angle, and link speed scaled by 1/10.
STATE_NAMES = ("theta_m [rad]", "omega_m [rad/s]", "theta_l [rad]", "omega_l / 10 [rad/s]")

#: The constants the paper claims below (36).
PAPER_CLAIMED = Constants(rho=0.1109, beta=0.1109, gamma=0.0, alpha=0.333)


#: Disturbance inputs of ``flexible_link_w_v1`` (the suite's choice; the paper has none): w1 enters the motor
#: angle's equation (as Nguyen, Pathirana & Trinh's W = e1 for the flexible-joint robot), w2 and w3 are sensor
#: noise of size 0.1 on the two outputs.
BW = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
DW = np.array([[0.0, 0.1, 0.0], [0.0, 0.0, 0.1]])


def _make(pid: str, c: float, index: int, t_final: float, notes: str, claimed: Constants = PAPER_CLAIMED,
          params: dict | None = None, **extra) -> Plant:
    c = check_real("c", c)
    gravity = sine_terms(4, acts=[3], reads=[index], coef=-c)
    return Plant(id=pid, A=A, B=B, C=C, x0=X0, x_hat0=X_HAT0, **gravity, claimed=claimed,
                 t_final=t_final, family="flexible_link", params={"c": c, **(params or {})}, source=SOURCE,
                 notes=notes, state_names=STATE_NAMES, **extra)


@register_plant("flexible_link", order=0)
def flexible_link(*, c: float = 0.333, t_final: float = 20.0) -> Plant:
    """Flexible link manipulator (35)-(36), gravity on the link angle: f4 = -c sin(x3)."""
    return _make("flexible_link", c, 2, t_final, "f4 = -c sin(x3), as in model (34)")


@register_plant("flexible_link_printed", order=1)
def flexible_link_printed(*, c: float = 0.333, t_final: float = 20.0) -> Plant:
    """Flexible link manipulator as printed in (36): f4 = -c sin(x1)."""
    return _make("flexible_link_printed", c, 0, t_final, "f4 = -c sin(x1), as printed in (36)")


@register_plant("flexible_link_w_v1", order=2, default=False)
def flexible_link_w(*, c: float = 0.333, t_final: float = 20.0) -> Plant:
    """Flexible link manipulator (35)-(36), gravity on the link angle, with disturbance inputs.

    The paper's plant (:func:`flexible_link`) with ``x' = ... + Bw w``, ``y = C x + Dw w`` (:data:`BW`,
    :data:`DW`: a disturbance on the motor angle's equation and sensor noise 0.1 on both outputs; the suite's
    choice, the paper has no disturbance), so that the L2 gains and the H-infinity designs have the paper's
    example to work on. On request only (``--plant flexible_link_w_v1``): its 18 pairs, each simulated a second
    time with the disturbance and with the L2 gains of every certified level, add about a third to the default
    run's wall time.

    Parameters
    ----------
    c : float
        Coefficient of the gravity term ``f4 = -c sin(x3)``.
    t_final : float
        Horizon in seconds.

    Returns
    -------
    Plant
        With ``Bw`` (4 x 3) and ``Dw`` (2 x 3); no claimed constants (the paper's claim is about its own
        plant, :func:`flexible_link`).
    """
    plant = _make("flexible_link_w_v1", c, 2, t_final,
                  "f4 = -c sin(x3); w: a disturbance on x1' and sensor noise 0.1 on both outputs (the suite's choice)",
                  claimed=Constants(), params={"version": 1}, Bw=BW, Dw=DW)
    return plant
