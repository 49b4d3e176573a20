"""python-control at the boundary: plants, observers and closed loops as python-control systems.

The suite's own simulator is :func:`bench.simulate.simulate`; this module hands the same objects
to python-control (``control.StateSpace`` and ``control.NonlinearIOSystem``) so that its tools
(``input_output_response``, ``feedback``, ``interconnect``, frequency responses, ...) can be used
on them. Notation is the paper's: plant (1) ``x' = A x + B u + f(x)``, ``y = C x``; observer-based
controller (6) ``x_hat' = A x_hat + B u + f(x_hat) + K (y - C x_hat)``, ``u = F x_hat`` with
``K`` (n x p) and ``F`` (m x n). (python-control's ``lqr`` returns ``K_lqr`` for
``u = -K_lqr x``, so ``F = -K_lqr``.)

Signal names: plant inputs ``u[i]``, outputs ``y[i]``, states ``x[i]``; controller inputs
``y[i]``, outputs ``u[i]``, states ``xhat[i]``.
"""

from __future__ import annotations

import re
import textwrap

import numpy as np

from bench import checks
from plants import Plant

__all__ = ["closed_loop_nlsys", "controller_ss", "observer_nlsys", "plant_nlsys"]

_RAISES_PLANT = """\
Raises
------
TypeError
    If ``plant`` is not a Plant."""

#: numpydoc text that several docstrings below share, written once: a line ``%(name)s`` of a
#: docstring decorated with :func:`_doc` is replaced by the entry, indented like that line.
_DOC_ENTRIES = {
    "gains": """\
K : array_like, shape (n, p)
    Observer gain.
F : array_like, shape (m, n)
    State feedback, ``u = F x_hat``.""",
    # what a bad plant (:func:`_check_plant`), or a bad plant, K or F (:func:`_check_gains`) raises
    "raises_plant": _RAISES_PLANT,
    "raises_gains": _RAISES_PLANT + """
ValueError
    If K or F has the wrong shape or non-finite entries (the message names which).""",
}


def _doc(func):
    """Fill the shared entries of :data:`_DOC_ENTRIES` into ``func.__doc__`` (left alone under ``-OO``)."""
    if func.__doc__:
        func.__doc__ = re.sub(r"^( *)%\((\w+)\)s$", lambda m: textwrap.indent(_DOC_ENTRIES[m[2]], m[1]),
                              func.__doc__, flags=re.MULTILINE)
    return func


def _names(prefix: str, count: int) -> list[str]:
    """Signal names ``prefix[0] .. prefix[count-1]``."""
    return [f"{prefix}[{i}]" for i in range(count)]


def _sysname(plant: Plant, suffix: str) -> str:
    """A python-control system name from the plant id (no '.', which python-control reads as 'sys.signal')."""
    base = re.sub(r"[^0-9A-Za-z_]", "_", plant.id)
    return f"{base}_{suffix}" if suffix else base


def _check_plant(plant) -> Plant:
    """``plant``, or TypeError unless it is a :class:`plants.Plant`."""
    if not isinstance(plant, Plant):
        raise TypeError(f"plant: expected a plants.Plant, got {type(plant).__name__}")
    return plant


def _check_gains(plant, K, F) -> tuple[Plant, np.ndarray, np.ndarray]:
    """The plant (TypeError unless a Plant), K (n x p) and F (m x n) as read-only float arrays
    (:func:`bench.checks.gains`: ValueError naming the bad one and the expected shape)."""
    K, F = checks.gains(_check_plant(plant), K, F)
    K.setflags(write=False)
    F.setflags(write=False)
    return plant, K, F


@_doc
def controller_ss(plant: Plant, K, F):
    """The linear part of the observer-based controller (6), from y to u, as a ``control.StateSpace``.

    ``x_hat' = (A + B F - K C) x_hat + K y``, ``u = F x_hat`` (D = 0).

    This is only the linear part: the observer (6) also adds ``f(x_hat)`` to ``x_hat'`` (see
    :func:`observer_nlsys`). With ``f = 0`` it is the whole controller, and the closed loop with
    the plant's linear part has the eigenvalues of ``A + B F`` and ``A - K C`` (separation).

    Parameters
    ----------
    plant : Plant
        Supplies A (n x n), B (n x m), C (p x n).
    %(gains)s

    Returns
    -------
    control.StateSpace
        Inputs ``y[0..p-1]``, outputs ``u[0..m-1]``, states ``xhat[0..n-1]``.

    %(raises_gains)s

    Examples
    --------
    >>> from bench.registry import PLANTS
    >>> from plants.flexible_link import PAPER_K, PAPER_F
    >>> ctrl = controller_ss(PLANTS.create("flexible_link"), PAPER_K, PAPER_F)
    >>> ctrl.ninputs, ctrl.noutputs, ctrl.nstates
    (2, 1, 4)
    """
    import control

    plant, K, F = _check_gains(plant, K, F)
    A, B, C = plant.A, plant.B, plant.C
    return control.ss(A + B @ F - K @ C, K, F, np.zeros((plant.m, plant.p)),
                      inputs=_names("y", plant.p), outputs=_names("u", plant.m),
                      states=_names("xhat", plant.n), name=_sysname(plant, "controller"))


def _affine_system(M: np.ndarray, G: np.ndarray, H: np.ndarray, f, *, signals: tuple[str, str, str],
                   state_outputs: bool, name: str):
    """``s' = M s + G w + f(s)`` with output ``H s`` (followed by ``s`` itself when ``state_outputs``) as a
    ``control.NonlinearIOSystem``; ``signals`` names the input, output and state signals (prefixes)."""
    import control

    k = G.shape[1]
    inp, out, st = signals

    def update(t, s, w, params):
        s = np.asarray(s, dtype=float)
        return M @ s + G @ np.asarray(w, dtype=float).reshape(k) + np.asarray(f(s), dtype=float)

    if state_outputs:
        def output(t, s, w, params):
            s = np.asarray(s, dtype=float)
            return np.concatenate([H @ s, s])
        outputs = _names(out, H.shape[0]) + _names(st, M.shape[0])
    else:
        def output(t, s, w, params):
            return H @ np.asarray(s, dtype=float)
        outputs = _names(out, H.shape[0])
    return control.nlsys(update, output, inputs=_names(inp, k), outputs=outputs, states=_names(st, M.shape[0]),
                         name=name)


def _plant_system(plant: Plant, *, state_outputs: bool, name: str):
    """The plant (1): input u, output y (and x), state x."""
    return _affine_system(plant.A, plant.B, plant.C, plant.f, signals=("u", "y", "x"), state_outputs=state_outputs,
                          name=name)


def _observer_system(plant: Plant, K: np.ndarray, F: np.ndarray, *, state_outputs: bool, name: str):
    """The observer-based controller (6) with ``u = F x_hat`` substituted: input y, output u (and x_hat),
    state x_hat."""
    M = plant.A + plant.B @ F - K @ plant.C  # linear part of x_hat' with u = F x_hat substituted
    return _affine_system(M, K, F, plant.f, signals=("y", "u", "xhat"), state_outputs=state_outputs, name=name)


@_doc
def plant_nlsys(plant: Plant):
    """The plant (1) ``x' = A x + B u + f(x)``, ``y = C x`` as a ``control.NonlinearIOSystem``.

    Parameters
    ----------
    plant : Plant

    Returns
    -------
    control.NonlinearIOSystem
        Continuous time; inputs ``u[0..m-1]``, outputs ``y[0..p-1]``, states ``x[0..n-1]``;
        named after ``plant.id``.

    %(raises_plant)s

    Examples
    --------
    >>> from bench.registry import PLANTS
    >>> sys = plant_nlsys(PLANTS.create("flexible_link"))
    >>> sys.ninputs, sys.noutputs, sys.nstates
    (1, 2, 4)
    """
    plant = _check_plant(plant)
    return _plant_system(plant, state_outputs=False, name=_sysname(plant, ""))


@_doc
def observer_nlsys(plant: Plant, K, F):
    """The nonlinear observer-based controller (6), from y to u, as a ``control.NonlinearIOSystem``.

    ``x_hat' = A x_hat + B F x_hat + f(x_hat) + K (y - C x_hat)``, ``u = F x_hat``.

    Parameters
    ----------
    plant : Plant
        Supplies A, B, C and f.
    %(gains)s

    Returns
    -------
    control.NonlinearIOSystem
        Inputs ``y[0..p-1]``, outputs ``u[0..m-1]``, states ``xhat[0..n-1]``.

    %(raises_gains)s

    See Also
    --------
    controller_ss : its linear part (without ``f(x_hat)``).
    """
    plant, K, F = _check_gains(plant, K, F)
    return _observer_system(plant, K, F, state_outputs=False, name=_sysname(plant, "observer"))


@_doc
def closed_loop_nlsys(plant: Plant, K, F):
    """Plant (1) in feedback with the observer-based controller (6), as a ``control.NonlinearIOSystem``.

    Built with ``control.interconnect`` from the plant (:func:`plant_nlsys`) and the observer
    (:func:`observer_nlsys`), each also exporting its state, with ``y`` and ``u`` connected.
    It is the system :func:`bench.simulate.simulate` integrates::

        x'     = A x + B F x_hat + f(x)
        x_hat' = A x_hat + B F x_hat + f(x_hat) + K C (x - x_hat)

    Parameters
    ----------
    plant : Plant
    %(gains)s

    Returns
    -------
    control.NonlinearIOSystem
        No inputs; 2n states in the order ``(x[0..n-1], xhat[0..n-1])`` (so
        ``initial_state=np.concatenate([x0, x_hat0])``); 2n + m outputs in the order
        ``(x[0..n-1], xhat[0..n-1], u[0..m-1])``.

    %(raises_gains)s

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
    n, m, p = plant.n, plant.m, plant.p
    pname, oname = _sysname(plant, "plant"), _sysname(plant, "observer")
    psys = _plant_system(plant, state_outputs=True, name=pname)
    osys = _observer_system(plant, K, F, state_outputs=True, name=oname)
    connections = ([[f"{pname}.u[{i}]", f"{oname}.u[{i}]"] for i in range(m)]
                   + [[f"{oname}.y[{j}]", f"{pname}.y[{j}]"] for j in range(p)])
    outlist = ([f"{pname}.x[{i}]" for i in range(n)] + [f"{oname}.xhat[{i}]" for i in range(n)]
               + [f"{oname}.u[{i}]" for i in range(m)])
    return control.interconnect(
        [psys, osys], connections=connections, inplist=[], outlist=outlist, inputs=0,
        outputs=_names("x", n) + _names("xhat", n) + _names("u", m),
        states=_names("x", n) + _names("xhat", n), name=_sysname(plant, "closed_loop"),
        check_unused=False)
