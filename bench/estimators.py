"""Run-time estimators that are not a fixed gain: the continuous-discrete EKF (filterpy).

This is the harness side of :mod:`designs.ekf`: the design fixes the specification, the
harness runs the filter inside its sampled-time simulation.
"""

from __future__ import annotations

import numpy as np

from designs.ekf import EKFSpec
from plants._core import Plant

__all__ = ["ContinuousDiscreteEKF", "numeric_jacobian"]


def numeric_jacobian(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central finite-difference Jacobian of f at x (batch evaluation, one call)."""
    n = x.size
    E = np.eye(n) * h
    X = np.concatenate([x[:, None] + E, x[:, None] - E], axis=1)
    FX = np.asarray(f(X), dtype=float)
    return (FX[:, :n] - FX[:, n:]) / (2 * h)


class ContinuousDiscreteEKF:
    """A continuous-discrete EKF built on filterpy's ``ExtendedKalmanFilter``.

    filterpy's ``predict_x`` is linear (``F x + B u``) by default: it is overridden with the
    integration of the nonlinear model over one sample, and ``F`` is set to the discretised
    Jacobian before each ``predict``. ``update`` is called with the measurement of the current
    sample (``predict_update`` is not used: it evaluates H before predicting).

    Parameters
    ----------
    plant : Plant
    spec : EKFSpec
    x_hat0 : ndarray (n,)
    rtol, atol : float
        Tolerances of the prediction integral.
    """

    def __init__(self, plant: Plant, spec: EKFSpec, x_hat0: np.ndarray, *, rtol: float = 1e-8, atol: float = 1e-12):
        from filterpy.kalman import ExtendedKalmanFilter
        from scipy.integrate import solve_ivp
        from scipy.linalg import expm

        n, p = plant.n, plant.p
        A, B, C, f = plant.A, plant.B, plant.C, plant.f
        jac = plant.jacobian or (lambda x: numeric_jacobian(f, x))
        dt = spec.dt
        self.spec = spec

        class _EKF(ExtendedKalmanFilter):
            def predict_x(self, u=0):  # nonlinear prediction over one sample (u held)
                u = np.asarray(u, dtype=float).ravel()
                if not (np.all(np.isfinite(self.x)) and np.all(np.isfinite(u))):
                    raise FloatingPointError("EKF prediction from a non-finite estimate or input")
                sol = solve_ivp(lambda t, z: A @ z + B @ u + f(z), (0.0, dt), self.x[:, 0], method="DOP853",
                                rtol=rtol, atol=atol)
                self.x = sol.y[:, -1:].copy()

        self._ekf = _EKF(dim_x=n, dim_z=p, dim_u=plant.m)
        self._ekf.x = np.asarray(x_hat0, dtype=float).reshape(n, 1).copy()
        self._ekf.P = spec.p0 * np.eye(n)
        self._ekf.Q = spec.q * dt * np.eye(n)
        self._ekf.R = spec.r * np.eye(p)
        self._A, self._C, self._jac, self._dt, self._expm = A, C, jac, dt, expm

    @property
    def x(self) -> np.ndarray:
        """Current estimate, shape (n,)."""
        return self._ekf.x[:, 0].copy()

    @property
    def P(self) -> np.ndarray:
        """Current covariance."""
        return self._ekf.P.copy()

    def update(self, y: np.ndarray) -> None:
        """Measurement update with ``y = C x + v`` (linear measurement: H = C)."""
        C = self._C
        self._ekf.update(np.asarray(y, dtype=float).reshape(-1, 1), HJacobian=lambda x: C, Hx=lambda x: C @ x)

    def predict(self, u: np.ndarray) -> None:
        """Propagate the estimate (nonlinear) and covariance (Jacobian) over one sample."""
        J = self._A + np.asarray(self._jac(self.x), dtype=float)
        self._ekf.F = self._expm(J * self._dt)
        self._ekf.predict(u=np.asarray(u, dtype=float).reshape(-1, 1))
