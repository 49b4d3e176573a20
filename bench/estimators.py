"""Run-time estimators that are not a fixed gain: the continuous-discrete EKF and the discrete EKF (filterpy),
built from a :class:`designs.ekf.EKFSpec` and run by the simulator (:func:`bench.simulate.simulate_controller`
for a continuous plant, the stepping simulator for a discrete one)."""

from __future__ import annotations

import numpy as np

from designs.ekf import EKFSpec
from plants import Plant

__all__ = ["ContinuousDiscreteEKF", "DiscreteEKF"]


def runtime_estimator(spec, plant: Plant, x_hat0: np.ndarray, *, t_final: float):
    """The run-time estimator (``dt``, ``x``, ``update(y)``, ``predict(u, x_next)``) a design specified (an
    :class:`designs.ekf.EKFSpec`)."""
    if isinstance(spec, EKFSpec):
        spec.check_horizon(t_final)
        if plant.discrete:
            return DiscreteEKF(plant, spec, x_hat0)
        return ContinuousDiscreteEKF(plant, spec, x_hat0)
    raise TypeError(f"estimator: no run-time estimator for a {type(spec).__name__}")


class ContinuousDiscreteEKF:
    """A continuous-discrete EKF on filterpy's ``ExtendedKalmanFilter``: the prediction is the nonlinear
    model's flow over one sample (integrated by the simulator), the covariance propagates with
    ``expm((A + Df) dt)``.

    Parameters
    ----------
    plant : Plant
    spec : EKFSpec
    x_hat0 : ndarray (n,)
    """

    def __init__(self, plant: Plant, spec: EKFSpec, x_hat0: np.ndarray):
        from filterpy.kalman import ExtendedKalmanFilter
        from scipy.linalg import expm

        n, p = plant.n, plant.p
        dt = spec.dt

        class _EKF(ExtendedKalmanFilter):
            def predict_x(self, u=0):  # the model's flow, set by predict(u, x_next)
                self.x = self.x_next

        self._ekf = _EKF(dim_x=n, dim_z=p, dim_u=plant.m)
        self._ekf.x = np.asarray(x_hat0, dtype=float).reshape(n, 1).copy()
        self._ekf.P = spec.p0 * np.eye(n)
        self._ekf.Q = spec.q * dt * np.eye(n)
        self._ekf.R = spec.r * np.eye(p)
        self._A, self._C, self._jac, self._expm = plant.A, plant.C, plant.jacobian_at, expm
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

    #: The simulator integrates the prediction with the plant and passes it to :meth:`predict`.
    predicts_with_model = True

    def predict(self, u: np.ndarray, x_next: np.ndarray) -> None:
        """Propagate the estimate (nonlinear) and covariance (Jacobian) over one sample.

        Parameters
        ----------
        u : ndarray (m,)
            The input held over the sample.
        x_next : ndarray (n,)
            The estimate's model flow over the sample with ``u`` held, integrated by the caller.
        """
        J = self._A + self._jac(self.x)
        self._ekf.F = self._expm(J * self.dt)
        self._ekf.x_next = np.asarray(x_next, dtype=float).reshape(-1, 1).copy()
        self._ekf.predict(u=np.asarray(u, dtype=float).reshape(-1, 1))


class DiscreteEKF:
    """The discrete EKF of ``x_{k+1} = A x_k + B u_k + f(x_k)``, ``y_k = C x_k + v_k`` on filterpy's
    ``ExtendedKalmanFilter``, with the interface of :class:`ContinuousDiscreteEKF` (``dt``, ``x``, ``P``,
    ``update(y)``, ``predict(u)``). It predicts with the model itself (:attr:`predicts_with_model` is False):
    ``x_hat <- A x_hat + B u + f(x_hat)``, ``P <- J P J' + Q`` with ``J = A + df/dx(x_hat)`` at the estimate
    before the step (Jazwinski 1970, ch. 8; Simon 2006, eqs. (13.47)-(13.48)).

    Parameters
    ----------
    plant : Plant
        A discrete plant; ``spec.dt`` must be its sample time.
    spec : EKFSpec
        ``Q = q dt I`` per step, ``R = r I``, ``P0 = p0 I``.
    x_hat0 : ndarray (n,)

    Raises
    ------
    ValueError
        If the plant is not discrete or ``spec.dt`` is not its sample time.
    """

    #: The filter predicts with its own model: the simulator calls ``predict(u)``.
    predicts_with_model = False

    def __init__(self, plant: Plant, spec: EKFSpec, x_hat0: np.ndarray):
        from filterpy.kalman import ExtendedKalmanFilter

        if not plant.discrete:
            raise ValueError(f"plant: the discrete EKF needs a discrete plant (dt > 0), got dt = {plant.dt:g}")
        if not np.isclose(spec.dt, plant.dt, rtol=1e-12, atol=0.0):
            raise ValueError(f"dt: the discrete EKF runs at the plant's sample time {plant.dt:g}, got {spec.dt:g}")
        n, p = plant.n, plant.p

        class _EKF(ExtendedKalmanFilter):
            def predict_x(self, u=0):  # the model step, set by predict(u)
                self.x = self.x_next

        self._ekf = _EKF(dim_x=n, dim_z=p, dim_u=plant.m)
        self._ekf.x = np.asarray(x_hat0, dtype=float).reshape(n, 1).copy()
        self._ekf.P = spec.p0 * np.eye(n)
        self._ekf.Q = spec.q * plant.dt * np.eye(n)
        self._ekf.R = spec.r * np.eye(p)
        self._plant = plant
        self.dt = plant.dt

    @property
    def x(self) -> np.ndarray:
        """Current estimate, shape (n,)."""
        return self._ekf.x[:, 0].copy()

    @property
    def P(self) -> np.ndarray:
        """Current covariance."""
        return self._ekf.P.copy()

    def update(self, y: np.ndarray) -> None:
        """Measurement update with ``y_k = C x_k + v_k`` (linear measurement: H = C)."""
        C = self._plant.C
        self._ekf.update(np.asarray(y, dtype=float).reshape(-1, 1), HJacobian=lambda x: C, Hx=lambda x: C @ x)

    def predict(self, u: np.ndarray, x_next: np.ndarray | None = None) -> None:
        """One step: ``x_hat <- A x_hat + B u + f(x_hat)`` (or ``x_next`` when the caller computed it) and
        ``P <- J P J' + Q``, ``J = A + df/dx(x_hat)`` at the estimate before the step.

        Parameters
        ----------
        u : ndarray (m,)
        x_next : ndarray (n,), optional
            The model step, if the caller has it (the continuous filter's signature); computed otherwise.
        """
        pl = self._plant
        x = self.x
        u = np.asarray(u, dtype=float).reshape(-1)
        if x_next is None:
            x_next = pl.A @ x + pl.B @ u + np.asarray(pl.f(x), dtype=float).reshape(-1)
        self._ekf.F = pl.A + pl.jacobian_at(x)
        self._ekf.x_next = np.asarray(x_next, dtype=float).reshape(-1, 1).copy()
        self._ekf.predict(u=u.reshape(-1, 1))  # filterpy: x <- x_next, P <- F P F' + Q
