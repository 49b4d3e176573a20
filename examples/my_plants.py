import numpy as np

from bench import Channels, Constants, Plant, register_plant


@register_plant("my_plant")
def my_plant(*, c: float = 0.5) -> Plant:
    """Damped oscillator with the nonlinearity f = (0, -c sin(x1))."""
    return Plant(
        id="my_plant",
        A=[[0.0, 1.0], [-1.0, -0.5]], B=[[0.0], [1.0]], C=[[1.0, 0.0]],
        f=lambda x: np.stack([0.0 * x[0], -c * np.sin(x[0])]),  # x: (2,) or (2, N)
        x0=[1.0, 0.0], x_hat0=[0.0, 0.0],
        bounds=Constants(alpha=c, rho=c / 2, beta=c**2, gamma=0.0),  # valid: Lipschitz, OSL, QIB
        # f = G phi(H x): one channel, phi(z) = -c sin(z) with slopes in [-c, c]
        channels=Channels(G=[[0.0], [1.0]], H=[[1.0, 0.0]], phi=lambda z: -c * np.sin(z), lo=-c, hi=c),
        source="my notes", params={"c": c},
    )
