"""The design flow shared by the corrected Theorem 1 and Corollary 1 (``docs/paper.md``).

Both are one LMI in the Young layout (:func:`designs._separated.young_layout`), solved jointly or side
by side (:class:`YoungDesign`'s ``method``). A subclass names its Young weight (:attr:`YoungDesign.phi_name`)
and provides ``form(plant, constants)``, its :class:`designs._separated.YoungForm`, and
``solved_params(vals, constants, phi=None)``, the scalars a joint solve at the Young weight ``phi`` (None: a
separated solve) reports.

On a discrete plant (``plant.dt > 0``) both methods solve the discrete x-side and e-side apart and rebuild the
joint certificate (:mod:`designs._discrete`; the joint discrete LMI is feasible iff both sides are, so the two
methods coincide there). A subclass provides ``discrete_forms(plant, constants)``: the candidate forms
``(YoungForm, multipliers, params)``, where ``multipliers(xv, ev)`` gives ``(Gx, Pix, Ge, Pie)`` of
:func:`designs._discrete.joint_certificate` (several candidates: a grid, the one with the best x-side margin
is used), and ``cert_level`` / ``cert_uses``, the certificate level its own certificate stands at.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Callable, ClassVar

import numpy as np

from bench import lmi
from designs._core import Design, DesignResult, check_choice, check_int, check_positive, check_range
from designs._discrete import joint_certificate
from designs._separated import (SIDE_MATRIX, _scale_free_clause, concluded, paper_gains_from, separated_design,
                                settle_joint)
from plants import Constants, Plant


@dataclass(frozen=True, kw_only=True)
class YoungDesign(Design):
    """Base of :class:`designs.thm1.Thm1` and :class:`designs.cor1.Cor1`.

    Parameters
    ----------
    n_grid, n_refine : int
        The Young weight's search: a log grid of ``n_grid`` points, then ``n_refine`` golden steps on
        its log10 around the best, maximising the normalised margin ``slack``.
    cap : float
        Normalisation ``Q, R << cap I``.
    method : {"joint", "separated"}
        ``"joint"`` solves the 6n x 6n LMI; ``"separated"`` the two 2n x 2n sides apart, the joint
        certificate rebuilt (:mod:`designs._separated`).
    solver : {"auto", "CLARABEL", "SCS"}
        ``"auto"``: Clarabel for the joint LMI; for the sides SCS first, Clarabel if its point does not verify.
    """

    n_grid: int = 7
    n_refine: int = 5
    cap: float = 1e3
    method: str = "joint"
    solver: str = "auto"

    #: The Young weight's name: the subclass has the fields ``phi_name`` (None: searched) and
    #: ``{phi_name}_range``.
    phi_name: ClassVar[str] = "phi"
    #: The design that searches a state scaling first (named in the reason of a failure).
    scaled_variant: ClassVar[str] = ""
    #: Continuous and discrete forms (module docstring).
    time_domains = ("continuous", "discrete")
    #: The certificate level of the discrete design's own joint certificate and the constants it rests on.
    cert_level: ClassVar[str] = "paper"
    cert_uses: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        check_choice("solver", self.solver, ("auto", "CLARABEL", "SCS"))
        check_choice("method", self.method, ("joint", "separated"))
        if self._fixed_phi is not None:
            check_positive(self.phi_name, self._fixed_phi)
        check_range(f"{self.phi_name}_range", getattr(self, f"{self.phi_name}_range"))
        check_positive("cap", self.cap)
        check_int("n_grid", self.n_grid, minimum=2)
        check_int("n_refine", self.n_refine, minimum=0)

    @property
    def _fixed_phi(self) -> float | None:
        return getattr(self, self.phi_name)

    @property
    def _joint_solver(self) -> str:
        return "CLARABEL" if self.solver == "auto" else self.solver

    def design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Solve the design for ``plant`` with ``constants``; a failure's reason names the scaled variant."""
        res = self._design_discrete(plant, constants) if plant.discrete else self._design(plant, constants)
        if res.status in ("infeasible", "marginal") and plant.channels is not None and not plant.id.endswith(".scaled"):
            res.reason += (f"; the scalar constants depend on the state's coordinates: {self.scaled_variant} searches "
                           "a diagonal scaling, and the structured design uses the channels themselves")
        return res

    def _design(self, plant: Plant, constants: Constants) -> DesignResult:
        """Separated, or the joint LMI with the Young weight searched (a marginal verdict settled side by side)."""
        if self.method == "separated":
            return self.separated(plant, constants)
        form = self.form(plant, constants)
        if self._fixed_phi is None:
            decided = self._decided_by_a_side(plant, form, constants)
            if decided is not None:
                return decided
        prog = form.joint_program(plant, cap=self.cap, phi_name=self.phi_name)
        phi, _, searched = self._search_phi(lambda phi: prog.solve(solver=self._joint_solver, phi=phi, iphi=1 / phi))
        if self._fixed_phi is None:
            searched += f" ({prog.n_solves} solves)"
        return concluded(prog, lambda vals: self.solved_params(vals, constants, phi), what=form.what, cap=self.cap,
                         searched=searched, settle=partial(settle_joint, plant, form, cap=self.cap, solver=self.solver))

    def _decided_by_a_side(self, plant: Plant, form, constants: Constants) -> DesignResult | None:
        """The joint LMI's verdict before its Young weight is searched, when a side decides it: each side (its
        x-side and e-side blocks are principal submatrices of the joint matrix for every weight) is solved as the
        separated design solves it (:func:`designs._separated.separated_design`, whose solves the programs' memo
        then answers), and one that does not verify is decided by its scale-free solve
        (:meth:`designs._separated.YoungForm.decide_side`). A side proven infeasible (an ``optimal`` solve) makes the
        joint LMI infeasible at every weight: that result, without the search. None otherwise (both sides verify,
        or one is left marginal or undecided): the search decides."""
        cost = [0.0, 0.0, 0]
        for side in SIDE_MATRIX:
            prog = form.side_program(plant, side, cap=self.cap)
            lmi.solve_side(prog, self.solver, plant.n)
            for i, k in enumerate(("compile_s", "solve_s", "n_solves")):
                cost[i] += getattr(prog, k)
            if prog.verified():
                continue
            got = form.decide_side(plant, side, cap=self.cap, solver=self.solver)
            for i, c in enumerate(got["cost"]):
                cost[i] += c
            if got["status"] != "infeasible" or got["solver_status"] != "optimal":
                return None
            lo, hi = getattr(self, f"{self.phi_name}_range")
            reason = (f"{form.what}: infeasible: its {side} block is a principal submatrix of the joint LMI at every "
                      f"{self.phi_name} and is {_scale_free_clause({side: got})} (decided before the {self.phi_name} "
                      f"search over [{lo:g}, {hi:g}], which it makes needless)")
            params = {"form": f"decided by the {side} (scale-free)", self.phi_name: float("nan"),
                      "slack": got.get("slack", float("nan")), "cap": self.cap}
            return DesignResult(status="infeasible", reason=reason, route="sdp", solver="CLARABEL" if self.solver ==
                                "auto" else self.solver, solver_status=got["solver_status"], compile_s=cost[0],
                                solve_s=cost[1], n_solves=cost[2], margin=got["margin"], lmi_size=got["lmi_size"],
                                min_eig=got["min_eig"], params=params)
        return None

    def _design_discrete(self, plant: Plant, constants: Constants) -> DesignResult:
        """The discrete sides solved apart, the candidate form with the best x-side margin, the joint discrete
        certificate rebuilt and verified, its contraction factor measured (:mod:`designs._discrete`)."""
        forms = self.discrete_forms(plant, constants)
        cost = [0.0, 0.0, 0]
        if len(forms) > 1:  # a grid (gamma < 0): the candidate whose x-side is most strictly feasible
            def slack(form):
                prog = form.side_program(plant, "x-side", cap=self.cap)
                lmi.solve_side(prog, self.solver, plant.n)
                for i, k in enumerate(("compile_s", "solve_s", "n_solves")):
                    cost[i] += getattr(prog, k)
                return float(prog.values()["slack"]) if prog.verified() else -np.inf
            forms = [max(forms, key=lambda f: slack(f[0]))]
        form, multipliers, extra = forms[0]
        got: dict = {}

        def verdict(B, xv, ev, form_, lx, le):
            K, F = paper_gains_from({**xv, **ev})
            P = np.linalg.inv(xv["Q"])
            P = (P + P.T) / 2
            Gx, Pix, Ge, Pie = multipliers(xv, ev)
            jc = joint_certificate(plant.A + plant.B @ F, plant.B @ F, plant.A - K @ plant.C, Gx, Ge, P, ev["R"],
                                   Pix, Pie, dt=plant.dt, Sx=xv["Q"])
            got.update(jc)
            out = {k: jc[k] for k in ("status", "reason", "margin", "raw_margin", "lmi_size", "phi", "scale")}
            out.update(min_eig={"Q": lmi.min_eig(xv["Q"]), "R": lmi.min_eig(ev["R"])}, values={**xv, **ev})
            if jc["status"] == "feasible":
                out["certificate"] = {
                    "level": self.cert_level, "P": jc["P"], "decay_rate": jc["decay_rate"], "margin": jc["margin"],
                    "radius": constants.radius, "contraction": jc["contraction"], "dt": plant.dt,
                    "uses": self.cert_uses or self.needs,
                    "how": (f"the design's own joint discrete certificate (V = x'Q^-1 x + s e'Re, the sides' "
                            f"multipliers), its contraction factor r = {jc['contraction']:.6g} by bisection")}
            return out

        res = separated_design(plant, form, solver=self.solver, cap=self.cap, phi_name=self.phi_name,
                               extra_params=lambda vals: {**self.solved_params(vals, constants), **extra},
                               joint_verdict=verdict,
                               form_name="discrete: x-side and e-side apart, joint discrete certificate rebuilt")
        res.compile_s += cost[0]
        res.solve_s += cost[1]
        res.n_solves += cost[2]
        res.params.update(dt=plant.dt, contraction=got.get("contraction", float("nan")),
                          decay_rate=got.get("decay_rate", float("nan")))
        return res

    def separated(self, plant: Plant, constants: Constants, *, decide: bool = True) -> DesignResult:
        """The sides solved apart and the joint certificate rebuilt; ``decide=False`` skips the scale-free solves."""
        return separated_design(plant, self.form(plant, constants), solver=self.solver, cap=self.cap,
                                phi_name=self.phi_name, extra_params=lambda vals: self.solved_params(vals, constants),
                                decide=decide)

    def joint_program(self, plant: Plant, constants: Constants) -> lmi.Program:
        """The joint program for ``plant`` with ``constants`` (compiled once per shape), the Young weight
        (``phi``, ``iphi`` = 1/phi) left to the caller: ``prog.solve(phi=phi, iphi=1 / phi)``."""
        return self.form(plant, constants).joint_program(plant, cap=self.cap, phi_name=self.phi_name)

    def _search_phi(self, obj: Callable[[float], float], *, n_grid: int | None = None,
                    n_refine: int | None = None) -> tuple[float, float, str]:
        """Search (or fix) the Young weight maximising ``obj(phi)``: the weight, its margin and where it was searched."""
        lo, hi = getattr(self, f"{self.phi_name}_range")
        if self._fixed_phi is not None:
            return self._fixed_phi, obj(self._fixed_phi), f"at {self.phi_name} = {self._fixed_phi:g}"
        phi, val = lmi.log_search(obj, lo, hi, n_grid=self.n_grid if n_grid is None else n_grid,
                                  n_refine=self.n_refine if n_refine is None else n_refine)
        return phi, val, f"over {self.phi_name} in [{lo:g}, {hi:g}]"
