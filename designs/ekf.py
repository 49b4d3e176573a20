"""The extended Kalman filter (filterpy) as an estimator part: continuous-discrete, or discrete on a discrete plant.

The design only fixes the filter's specification (:class:`EKFSpec`); the harness runs it.

- Continuous plant (``bench.estimators.ContinuousDiscreteEKF``): at each sample ``t_k = k dt`` the filter
  updates with ``y_k = C x(t_k) + v_k``, ``u_k = F x_hat_k`` is held, and the filter predicts by integrating
  ``x_hat' = A x_hat + B u_k + f(x_hat)`` with ``P <- Phi P Phi' + q dt I``,
  ``Phi = expm((A + df/dx(x_hat_k)) dt)``.
- Discrete plant ``x_{k+1} = A x_k + B u_k + f(x_k)`` (``bench.estimators.DiscreteEKF``): the filter runs at
  the plant's own sample time (``dt = plant.dt``; the hyperparameter ``dt`` is not used): update with
  ``y_k = C x_k + v_k``, then predict ``x_hat <- A x_hat + B u_k + f(x_hat)``,
  ``P <- J P J' + q dt I`` with the Jacobian ``J = A + df/dx(x_hat)`` (the discrete EKF of Jazwinski 1970,
  ch. 8; Simon 2006, section 13.2).

References
----------
A. H. Jazwinski, *Stochastic Processes and Filtering Theory*, 1970 (continuous-discrete and discrete EKF).
D. Simon, *Optimal State Estimation*, Wiley 2006, ch. 13.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from designs._core import DesignError, DesignResult, check_positive
from designs._parts import Part, register_estimator
from plants import Constants, Plant

__all__ = ["EKFEstimator", "EKFSpec"]


@dataclass(frozen=True, kw_only=True)
class EKFSpec:
    """Specification of a continuous-discrete EKF.

    Parameters
    ----------
    dt : float
        Sample time (must divide the simulation horizon).
    q : float
        Process noise intensity: ``Q_d = q dt I``.
    r : float
        Measurement noise variance per sample: ``R = r I``.
    p0 : float
        Initial covariance ``P0 = p0 I``.
    """

    dt: float = 0.01
    q: float = 1e-3
    r: float = 1e-4
    p0: float = 10.0

    def __post_init__(self) -> None:
        check_positive("dt", self.dt)
        check_positive("q", self.q, allow_zero=True)
        check_positive("r", self.r)
        check_positive("p0", self.p0)

    def check_horizon(self, t_final: float) -> None:
        """Raise :class:`designs.DesignError` unless ``dt`` divides ``t_final``."""
        k = t_final / self.dt
        if abs(k - round(k)) > 1e-9 * max(1.0, k) or round(k) < 1:
            raise DesignError(f"dt: the sample time {self.dt:g} must divide the horizon t_final = {t_final:g}")


@register_estimator("ekf")
@dataclass(frozen=True, kw_only=True)
class EKFEstimator(EKFSpec, Part):
    """EKF via filterpy (the hyperparameters of :class:`EKFSpec`); no fixed gain. Continuous-discrete on a
    continuous plant, discrete at the plant's sample time on a discrete one (module docstring)."""

    time_domains = ("continuous", "discrete")

    def compute(self, plant: Plant, constants: Constants) -> DesignResult:
        """Return the filter specification (checked against the plant's horizon)."""
        dt = plant.dt if plant.discrete else self.dt  # a discrete plant's filter runs at its own sample time
        spec = EKFSpec(dt=dt, q=self.q, r=self.r, p0=self.p0)  # the spec alone, for the simulator
        spec.check_horizon(plant.t_final)
        jacobian = "analytic" if plant.jacobian is not None else "finite differences"
        form = "discrete (plant's sample time)" if plant.discrete else "continuous-discrete"
        return DesignResult(status="given", route="given", estimator=spec, solver=None,
                            params={**asdict(spec), "jacobian": jacobian, "form": form})
