"""Studies a researcher runs after the tables (``python -m bench study NAME``): ``admissible`` (the largest
scale of the nonlinearity each design certifies), ``sampling`` (the largest sample period of a digital
implementation), ``montecarlo`` (region of convergence from random initial conditions) and ``noise`` (estimation
error vs measurement noise). Each writes ``STUDY_<name>.md``, CSVs and figures atomically into the report folder.
"""
