"""python-control at the boundary: plants, observers and closed loops as python-control systems.

Plant (1) ``x' = A x + B u + f(x)``, ``y = C x`` and controller (6) ``x_hat' = A x_hat + B u +
f(x_hat) + K (y - C x_hat)``, ``u = F x_hat`` as ``control.StateSpace`` / ``NonlinearIOSystem``, for
python-control's tools (python-control's ``lqr`` gain is ``-F``); a discrete-time plant (``dt > 0``) gives
discrete-time systems with its ``dt`` (``x_{k+1} = ...``). Signals: plant ``u[i]`` -> ``y[i]``,
states ``x[i]``; controller ``y[i]`` -> ``u[i]``, states ``xhat[i]``. Every function raises TypeError
for a ``plant`` that is not a Plant and ValueError (naming it) for a K or F of the wrong shape or
with non-finite entries.
"""

from __future__ import annotations

import re

import numpy as np

from bench import checks
from plants import Plant

__all__ = ["closed_loop_nlsys", "controller_ss", "observer_nlsys", "plant_nlsys"]

def _names(prefix: str, count: int) -> list[str]:
    """Signal names ``prefix[0] .. prefix[count-1]``."""
    return [f"{prefix}[{i}]" for i in range(count)]


def _sysname(plant: Plant, suffix: str) -> str:
    """A python-control system name from the plant id (no '.', read as 'sys.signal')."""
    base = re.sub(r"[^0-9A-Za-z_]", "_", plant.id)
    return f"{base}_{suffix}" if suffix else base


def _check_plant(plant) -> Plant:
    """``plant``, or TypeError unless it is a :class:`plants.Plant`."""
    if not isinstance(plant, Plant):
        raise TypeError(f"plant: expected a plants.Plant, got {type(plant).__name__}")
    return plant


def _check_gains(plant, K, F) -> tuple[Plant, np.ndarray, np.ndarray]:
    """The plant, K (n x p) and F (m x n) checked (:func:`bench.checks.gains`), the gains read-only."""
    K, F = checks.gains(_check_plant(plant), K, F)
    K.setflags(write=False)
    F.setflags(write=False)
    return plant, K, F


def controller_ss(plant: Plant, K, F):
    """The linear part of the observer-based controller (6), from y to u, as a ``control.StateSpace``.

    ``x_hat' = (A + B F - K C) x_hat + K y``, ``u = F x_hat``: (6) without ``f(x_hat)``.

    Parameters
    ----------
    plant : Plant
    K, F : array_like, shapes (n, p), (m, n)
        Observer gain and feedback.

    Returns
    -------
    control.StateSpace
    """
    import control

    plant, K, F = _check_gains(plant, K, F)
    A, B, C = plant.A, plant.B, plant.C
    return control.ss(A + B @ F - K @ C, K, F, np.zeros((plant.m, plant.p)), plant.dt,
                      inputs=_names("y", plant.p), outputs=_names("u", plant.m),
                      states=_names("xhat", plant.n), name=_sysname(plant, "controller"))


def _affine_system(M: np.ndarray, G: np.ndarray, H: np.ndarray, f, *, signals: tuple[str, str, str],
                   state_outputs: bool, name: str, dt: float = 0.0):
    """``s' = M s + G w + f(s)`` (``dt > 0``: ``s_{k+1} = ...``), output ``H s`` (and ``s``), as a
    NonlinearIOSystem named by ``signals``."""
    import control

    k = G.shape[1]
    inp, out, st = signals

    def update(t, s, w, params):
        s = np.asarray(s, dtype=float)
        return M @ s + G @ np.asarray(w, dtype=float).reshape(k) + np.asarray(f(s), dtype=float)

    def output(t, s, w, params):
        s = np.asarray(s, dtype=float)
        return np.concatenate([H @ s, s]) if state_outputs else H @ s

    outputs = _names(out, H.shape[0]) + (_names(st, M.shape[0]) if state_outputs else [])
    return control.nlsys(update, output, inputs=_names(inp, k), outputs=outputs, states=_names(st, M.shape[0]),
                         name=name, dt=dt)


def _observer_system(plant: Plant, K: np.ndarray, F: np.ndarray, *, state_outputs: bool, name: str):
    """The controller (6) with ``u = F x_hat`` substituted: input y, output u (and x_hat), state x_hat."""
    M = plant.A + plant.B @ F - K @ plant.C
    return _affine_system(M, K, F, plant.f, signals=("y", "u", "xhat"), state_outputs=state_outputs, name=name,
                          dt=plant.dt)


def plant_nlsys(plant: Plant):
    """The plant (1) ``x' = A x + B u + f(x)``, ``y = C x`` as a ``control.NonlinearIOSystem`` (a discrete-time
    plant as a discrete-time system with its ``dt``: ``x_{k+1} = A x_k + B u_k + f(x_k)``).

    Parameters
    ----------
    plant : Plant

    Returns
    -------
    control.NonlinearIOSystem
    """
    plant = _check_plant(plant)
    return _affine_system(plant.A, plant.B, plant.C, plant.f, signals=("u", "y", "x"), state_outputs=False,
                          name=_sysname(plant, ""), dt=plant.dt)


def observer_nlsys(plant: Plant, K, F):
    """The nonlinear observer-based controller (6), from y to u, as a ``control.NonlinearIOSystem``.

    Parameters
    ----------
    plant : Plant
        Supplies A, B, C and f.
    K, F : array_like
        As for :func:`controller_ss`.

    Returns
    -------
    control.NonlinearIOSystem
    """
    plant, K, F = _check_gains(plant, K, F)
    return _observer_system(plant, K, F, state_outputs=False, name=_sysname(plant, "observer"))


def closed_loop_nlsys(plant: Plant, K, F):
    """Plant (1) in feedback with the observer-based controller (6), as a ``control.NonlinearIOSystem``.

    The system :func:`bench.simulate.simulate` integrates, built with ``control.interconnect``.

    Parameters
    ----------
    plant : Plant
    K, F : array_like
        As for :func:`controller_ss`.

    Returns
    -------
    control.InterconnectedSystem
        No inputs; states ``(x, xhat)``; outputs ``(x, xhat, u)``.

    Examples
    --------
    >>> import control, numpy as np
    >>> from bench.registry import PLANTS
    >>> from plants.flexible_link import PAPER_K, PAPER_F
    >>> plant = PLANTS.create("flexible_link")
    >>> loop = closed_loop_nlsys(plant, PAPER_K, PAPER_F)
    >>> resp = control.input_output_response(loop, np.linspace(0, 5, 101),
    ...                                      initial_state=np.concatenate([plant.x0, plant.x_hat0]))
    >>> resp.outputs.shape
    (9, 101)
    """
    import control

    plant, K, F = _check_gains(plant, K, F)
    n, m = plant.n, plant.m
    psys = _affine_system(plant.A, plant.B, plant.C, plant.f, signals=("u", "y", "x"), state_outputs=True,
                          name=_sysname(plant, "plant"), dt=plant.dt)
    osys = _observer_system(plant, K, F, state_outputs=True, name=_sysname(plant, "observer"))
    return control.interconnect(  # u and y connected by their names
        [psys, osys], inplist=[], outlist=["x", "xhat", "u"], inputs=0,
        outputs=_names("x", n) + _names("xhat", n) + _names("u", m),
        states=_names("x", n) + _names("xhat", n), name=_sysname(plant, "closed_loop"),
        check_unused=False)
