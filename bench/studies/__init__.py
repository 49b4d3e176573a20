"""Studies a researcher runs after the tables: ``python -m bench study NAME``.

- ``admissible`` (:mod:`bench.studies.admissible`): the largest scale of the nonlinearity at which
  each LMI / Riccati design is feasible and certified (conservatism), by bisection;
- ``sampling`` (:mod:`bench.studies.sampling`): the largest sample period of a digital
  implementation (discrete observer and controller, zero-order hold, continuous plant);
- ``montecarlo`` (:mod:`bench.studies.montecarlo`): region of convergence from N seeded random
  initial conditions, simulated as one vectorised ODE (:mod:`bench.batch`);
- ``noise`` (:mod:`bench.studies.noise`): RMS estimation error and final state norm vs
  measurement noise, Luenberger-type observers vs the EKF.

Each study writes ``STUDY_<name>.md``, ``study_<name>.csv`` and ``figures/study_<name>*.png``
into the report folder, atomically, and never touches ``REPORT.md``. Heavy modules are
imported by the commands that need them.
"""

STUDIES = ("admissible", "sampling", "montecarlo", "noise")
