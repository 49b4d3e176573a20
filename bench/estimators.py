"""Run-time estimators that are not a fixed gain: the continuous-discrete EKF (filterpy), built from
a :class:`designs.ekf.EKFSpec` and run by :func:`bench.simulate.simulate_controller`."""

from __future__ import annotations

import numpy as np

from designs.ekf import EKFSpec
from plants import Plant

__all__ = ["ContinuousDiscreteEKF"]


def runtime_estimator(spec, plant: Plant, x_hat0: np.ndarray, *, t_final: float, options=None):
    """The run-time estimator (``dt``, ``x``, ``update(y)``, ``predict(u)``) a design specified (an
    :class:`designs.ekf.EKFSpec`), its prediction integrated with ``options``' tolerances."""
    if isinstance(spec, EKFSpec):
        spec.check_horizon(t_final)
        kw = {} if options is None else {"rtol": options.rtol, "atol": options.atol}
        return ContinuousDiscreteEKF(plant, spec, x_hat0, **kw)
    raise TypeError(f"estimator: no run-time estimator for a {type(spec).__name__}")


class ContinuousDiscreteEKF:
    """A continuous-discrete EKF on filterpy's ``ExtendedKalmanFilter``: the prediction integrates the
    nonlinear model over one sample, the covariance propagates with ``expm((A + Df) dt)``.

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
        dt = spec.dt
        self.spec = spec

        class _EKF(ExtendedKalmanFilter):
            x_next = None  # set by predict(u, x_next): the model's flow, integrated by the simulator

            def predict_x(self, u=0):  # nonlinear prediction over one sample (u held)
                if self.x_next is not None:
                    self.x = np.asarray(self.x_next, dtype=float).reshape(-1, 1).copy()
                    self.x_next = None
                    return
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
        self._A, self._C, self._jac, self._dt, self._expm = A, C, plant.jacobian_at, dt, expm
        self.dt = dt

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

    #: A simulator may integrate the prediction with the plant and pass it to :meth:`predict`.
    predicts_with_model = True

    def predict(self, u: np.ndarray, x_next: np.ndarray | None = None) -> None:
        """Propagate the estimate (nonlinear) and covariance (Jacobian) over one sample.

        Parameters
        ----------
        u : ndarray (m,)
            The input held over the sample.
        x_next : ndarray (n,), optional
            The estimate's model flow, integrated by the caller (None: here).
        """
        J = self._A + self._jac(self.x)
        self._ekf.F = self._expm(J * self._dt)
        self._ekf.x_next = x_next
        self._ekf.predict(u=np.asarray(u, dtype=float).reshape(-1, 1))
