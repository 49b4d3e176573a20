"""A chain of N masses on springs with inverted-pendulum terms: a physical family that grows with n.

Model (lumped mass-spring chain clamped at both ends [1]_, with a sine term on some masses)::

    m q_i'' = k (q_{i-1} - 2 q_i + q_{i+1}) + d (v_{i-1} - 2 v_i + v_{i+1}) - b v_i
              + c sin(q_i) [i in nonlinear] + sum_j u_j [i = inputs_j],     q_0 = q_{N+1} = 0,

``v_i = q_i'``: the Frenkel-Kontorova chain [2]_ with the substrate force reversed (``+c sin``:
coupled *inverted* pendula, as in Siljak's spring-coupled pendula [3]_). Ours: identical masses,
springs and dampers, the sign, and where the pendula, actuators and sensors sit.

State ``x = (q_1, v_1, ..., q_N, v_N)``, n = 2 N, so A is banded::

    A[2i, 2i+1] = 1,  A[2i+1, 2j] = -k K_ij / m,  A[2i+1, 2j+1] = -(d K_ij + b delta_ij) / m,

``K = tridiag(-1, 2, -1)``; ``B[:, j] = e_{v(inputs_j)} / m``, ``C[j, :] = e_{q(outputs_j)}'``. The
sine stays whole in f. The eigenvalues of K, ``4 sin^2(j pi / (2(N+1)))`` [1]_, are positive, so A is
Hurwitz when ``d > 0`` or ``b > 0``; the linearisation ``A + (c/m) sum_i e_{v_i} e_{q_i}'`` is
unstable once c exceeds the stiffness one pendulum mass sees, ``1 / [K^{-1}]_ii = k (N+1) / ((i+1)(N-i))``
(0-based i). (A, B) and (A, C) are checked by the PBH test when the plant is built.

f is :func:`plants._core.sine_terms` with ``acts = v(nonlinear)``, ``reads = q(nonlinear)``, ``coef = c``, ``scale = m``
(one channel per pendulum mass; its constants: :func:`chain_plant`, all 0 without a pendulum).

References
----------
.. [1] L. Meirovitch, Fundamentals of Vibrations, McGraw-Hill, 2001 (lumped multi-degree-of-freedom
   systems; the string as the limit of a chain of masses on springs).
.. [2] O. M. Braun and Y. S. Kivshar, The Frenkel-Kontorova Model: Concepts, Methods, and
   Applications, Springer, 2004.
.. [3] D. D. Siljak, Decentralized Control of Complex Systems, Academic Press, 1991.
"""

from __future__ import annotations

import numbers
from typing import Iterable

import numpy as np

from bench.registry import register_plant
from plants._core import Plant, PlantError, check_int, check_real, sine_terms

__all__ = ["chain_plant", "chain_v1"]

#: Largest number of masses accepted (n = 2 N states, dense A of 8 n^2 bytes: 8 MB at N = 512).
MAX_N = 2048

SOURCE = (
    "Mass-spring chain clamped at both ends (Meirovitch, Fundamentals of Vibrations, 2001) with "
    "inverted-pendulum sine terms (the Frenkel-Kontorova chain of Braun & Kivshar 2004 with the "
    "substrate force reversed; cf. Siljak 1991's spring-coupled inverted pendula); layout, sign and "
    "values picked here"
)


def _masses(name: str, value, N: int, *, allow_empty: bool) -> tuple[int, ...]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
        raise PlantError(f"{name}: expected a sequence of mass indices (0 .. {N - 1}), got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise PlantError(f"{name}: mass indices must be integers, got {v!r}")
        if not 0 <= int(v) < N:
            raise PlantError(f"{name}: mass index {int(v)} is outside 0 .. {N - 1} (N = {N})")
        out.append(int(v))
    if len(set(out)) != len(out):
        raise PlantError(f"{name}: repeated mass index in {out}")
    if not out and not allow_empty:
        raise PlantError(f"{name}: at least one mass is required")
    return tuple(sorted(out))


def default_masses(N: int, stride: int = 5) -> tuple[int, ...]:
    """The default layout of N masses: every ``stride``-th mass (0-based) from ``min(stride // 2, (N - 1) // 2)``."""
    N = check_int("N", N, 1, MAX_N)
    stride = check_int("stride", stride, 1, MAX_N)
    return tuple(range(min(stride // 2, (N - 1) // 2), N, stride))


def chain_plant(
    *,
    N: int = 3,
    m: float = 1.0,
    k: float = 1.0,
    d: float = 0.02,
    b: float = 0.0,
    c: float = 2.0,
    nonlinear: Iterable[int] | None = None,
    inputs: Iterable[int] | None = None,
    outputs: Iterable[int] | None = None,
    stride: int = 5,
    amplitude: float = 0.5,
    t_final: float = 20.0,
    id: str | None = None,
) -> Plant:
    """A chain of N spring-coupled masses with inverted-pendulum terms ``c sin(q_i)`` (n = 2 N).

    Parameters
    ----------
    N : int
        Number of masses, 1 .. :data:`MAX_N`; n = 2 N.
    m, k : float
        Mass and spring stiffness (> 0).
    d, b : float
        Damper coefficient in parallel with each spring, and viscous friction to ground (>= 0).
    c : float
        Force ``c sin(q_i)`` on each mass in ``nonlinear``: ``c > 0`` an inverted pendulum, ``c < 0``
        a hanging one.
    nonlinear, inputs, outputs : sequence of int, optional
        Masses (0-based) carrying a pendulum term, driven by a force, measured (position).
        Default: :func:`default_masses` ``(N, stride)`` for each. ``nonlinear`` may be empty.
    stride : int
        Spacing of the default layout (>= 1).
    amplitude : float
        Initial positions ``q_i(0) = amplitude sin(pi (i + 1) / (N + 1))`` (the first mode
        shape), velocities 0; ``x_hat(0) = 0``.
    t_final : float
        Simulation horizon in seconds.
    id : str, optional
        Plant id (default ``chain_v1_N{N}``).

    Returns
    -------
    Plant
        Claimed = bounds: alpha = |c|/m, rho = |c|/(2m), (beta, gamma) = (c^2/m^2, 0), global.

    Raises
    ------
    PlantError
        On a bad argument, or when (A, B) or (A, C) fails the PBH test.
    """
    N = check_int("N", N, 1, MAX_N)
    m = check_real("m", m, lo=0.0, strict=True)
    k = check_real("k", k, lo=0.0, strict=True)
    d = check_real("d", d, lo=0.0)
    b = check_real("b", b, lo=0.0)
    c = check_real("c", c)
    amplitude = check_real("amplitude", amplitude)
    layout = default_masses(N, stride)
    nl = layout if nonlinear is None else _masses("nonlinear", nonlinear, N, allow_empty=True)
    ins = layout if inputs is None else _masses("inputs", inputs, N, allow_empty=False)
    outs = layout if outputs is None else _masses("outputs", outputs, N, allow_empty=False)
    n = 2 * N
    A, B, C = _linear_part(N, m, k, d, b, ins, outs)
    qi = np.array([2 * i for i in nl], dtype=np.intp)
    pendula = sine_terms(n, acts=qi + 1, reads=qi, coef=c, scale=m)

    x0 = np.zeros(n)
    x0[0::2] = amplitude * np.sin(np.pi * np.arange(1, N + 1) / (N + 1))
    return Plant(
        id=id or f"chain_v1_N{N}",
        A=A, B=B, C=C, x0=x0, x_hat0=np.zeros(n), **pendula, claimed=pendula["bounds"], t_final=t_final,
        family="chain",
        params={"N": N, "n": n, "m": m, "k": k, "d": d, "b": b, "c": c, "amplitude": amplitude,
                "n_inputs": len(ins), "n_outputs": len(outs), "n_channels": len(nl), "version": 1},
        source=SOURCE,
        notes=(f"chain of {N} masses, pendula (c sin q) at {list(nl)}, forces at {list(ins)}, "
               f"positions measured at {list(outs)}; alpha = |c|/m, rho = |c|/(2m), "
               "(beta, gamma) = (c^2/m^2, 0), global"),
        state_names=tuple(s for i in range(1, N + 1) for s in (f"q{i} [-]", f"v{i} = q{i}' [1/s]")),
    )


def _linear_part(N: int, m: float, k: float, d: float, b: float, ins, outs) -> tuple[np.ndarray, ...]:
    """``(A, B, C)`` of the chain (module docstring); PlantError when (A, B) or (A, C) fails the PBH test."""
    from plants.random_families import is_detectable, is_stabilizable, pbh_margin

    n, i, j = 2 * N, np.arange(N), np.arange(N - 1)
    A = np.zeros((n, n))
    A[2 * i, 2 * i + 1] = 1.0
    A[2 * i + 1, 2 * i], A[2 * i + 1, 2 * i + 1] = -2 * k / m, -(2 * d + b) / m
    for v, w in ((j, j + 1), (j + 1, j)):  # the spring and the damper between neighbours v, w
        A[2 * v + 1, 2 * w], A[2 * v + 1, 2 * w + 1] = k / m, d / m
    B = np.zeros((n, len(ins)))
    B[[2 * v + 1 for v in ins], range(len(ins))] = 1.0 / m
    C = np.zeros((len(outs), n))
    C[range(len(outs)), [2 * v for v in outs]] = 1.0
    if not is_stabilizable(A, B):
        raise PlantError(f"inputs: (A, B) is not stabilizable with inputs at masses {list(ins)} "
                         f"(PBH margin {pbh_margin(A, B):.3g})")
    if not is_detectable(A, C):
        raise PlantError(f"outputs: (A, C) is not detectable with outputs at masses {list(outs)} "
                         f"(PBH margin {pbh_margin(A.T, C.T):.3g})")
    return A, B, C


@register_plant("chain_v1")
def chain_v1(*, N: int = 3, c: float = 2.0, t_final: float = 20.0) -> Plant:
    """Chain of 3 spring-coupled masses, inverted pendulum 2 sin(q) on the end mass, collocated (n = 6).

    Parameters
    ----------
    N : int
        Number of masses; pendulum, force and position sensor all on the end mass 0.
    c : float
        Pendulum coefficient (2: above the end mass's threshold ``k (N+1) / N``, so unstable).
    t_final : float
        Simulation horizon in seconds.

    Returns
    -------
    Plant
    """
    return chain_plant(N=N, c=c, nonlinear=(0,), inputs=(0,), outputs=(0,), t_final=t_final, id="chain_v1")
