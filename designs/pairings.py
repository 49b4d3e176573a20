"""The registered observer-based pairings ``feedback+estimator``: adding one is one line.

Feedback parts: ``lqr`` (python-control). Estimator parts: ``rh_riccati`` (Raghavan-Hedrick
Riccati), ``rajamani`` (Lipschitz LMI), ``zhang_osl`` (OSL/QIB LMI), ``lqe`` (Kalman gain),
``ekf`` (filterpy EKF, sampled time), ``hinf_lipschitz`` (H-infinity observer for Lipschitz systems).
"""

from designs import ekf, hinf_lipschitz, lmi_observers, lqr, riccati  # noqa: F401  (parts register on import)
from designs._parts import register_pairing

PAIRINGS = [
    register_pairing("lqr", "rh_riccati"),
    register_pairing("lqr", "rajamani"),
    register_pairing("lqr", "zhang_osl"),
    register_pairing("lqr", "lqe"),
    register_pairing("lqr", "ekf"),
    register_pairing("lqr", "hinf_lipschitz"),
]
