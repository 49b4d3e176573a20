# %% [markdown]
# # oslbench from a notebook
#
# A tour in cells (`# %%`, as Jupyter, VS Code and Spyder read them): a plant from a
# python-control system, three designs through `bench.run`, the norms plotted, the table
# printed, and the designed controller handed back to python-control. Run it whole with
# `python examples/notebook_tour.py` (it writes `notebook_tour.png` beside the current folder
# unless `OSLBENCH_TOUR_OUT` names another file).

# %%
import os

import control
import matplotlib

matplotlib.use(os.environ.get("MPLBACKEND", "Agg"))
import matplotlib.pyplot as plt
import numpy as np

import bench
from bench import Channels, Constants, Plant

# %% [markdown]
# ## A plant from python-control
# A damped pendulum-like oscillator, x = (angle, rate), u a torque, y the angle, with the
# nonlinearity f(x) = (0, -c sin(x1)). What is known about f: the scalar constants (Lipschitz
# c, one-sided Lipschitz c/2, QIB (c^2, 0)) and, sharper, its channel structure
# f = G phi(H x) with phi(z) = -c sin(z) of slope in [-c, c].

# %%
c = 2.0
sys = control.ss([[0.0, 1.0], [-1.0, -0.4]], [[0.0], [1.0]], [[1.0, 0.0]], 0, name="tour_oscillator")
plant = Plant.from_statespace(
    sys,
    f=lambda x: np.stack([0.0 * x[0], -c * np.sin(x[0])]),  # x: (2,) or (2, N)
    x0=[1.0, 0.0],
    x_hat0=[0.0, 0.0],
    bounds=Constants(alpha=c, rho=c / 2, beta=c**2, gamma=0.0),
    channels=Channels(G=[[0.0], [1.0]], H=[[1.0, 0.0]], phi=lambda z: -c * np.sin(z), lo=-c, hi=c),
    source="examples/notebook_tour.py",
)
print(plant.summary())

# %% [markdown]
# ## Three designs
# Corrected Theorem 1 (scalar constants), the structured design (channels), and LQR with a
# Kalman-gain observer (python-control). `jobs=1` runs in this process.

# %%
results = bench.run(plants=[plant], designs=["thm1", "structured", "lqr+lqe"], jobs=1, progress=False)
cols = ["design", "status", "certified", "cert_level", "decay_rate", "converged", "peak_u"]
print(results.table[cols].to_string(index=False))

# %% [markdown]
# ## A design's setting swept with objects
# Objects need no registration (a cell runs again): each is named by its design's id and the
# settings that differ from the defaults, here the structured design's bound on the gains
# (default 20): a tighter bound, a slower certified rate.

# %%
from designs.structured import Structured  # noqa: E402 - a cell of its own

sweep = bench.run(plants=[plant], designs=[Structured(max_gain=g) for g in (2.0, 5.0)], jobs=1, progress=False)
print(sweep.table[["design", "status", "certified", "decay_rate"]].to_string(index=False))

# %% [markdown]
# ## The norms, from the stored trajectories

# %%
fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
for (pid, did), g in results.gains.items():
    tr = g["trajectory"]
    if tr is None:
        continue
    axes[0].semilogy(tr.t, np.linalg.norm(tr.x, axis=0) + 1e-16, label=did)
    axes[1].semilogy(tr.t, np.linalg.norm(tr.e, axis=0) + 1e-16, label=did)
axes[0].set(title="||x(t)||", xlabel="t [s]")
axes[1].set(title="||e(t)||", xlabel="t [s]")
axes[0].legend()
fig.tight_layout()
out = os.environ.get("OSLBENCH_TOUR_OUT", "notebook_tour.png")
fig.savefig(out, dpi=90)
print(f"wrote {out}")

# %% [markdown]
# ## The controller as a python-control system
# The observer-based controller from y to u (linear part), and the nonlinear closed loop as a
# `control.nlsys`, simulated by python-control itself.

# %%
ctrl = results.controller(plant.id, "structured")
print(ctrl)
loop = results.closed_loop(plant.id, "structured")
resp = control.input_output_response(loop, np.linspace(0, 10, 501), 0,
                                     X0=np.concatenate([plant.x0, plant.x_hat0]))
print(f"python-control: ||x(10)|| = {np.linalg.norm(resp.states[:2, -1]):.2e}")
