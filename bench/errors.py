"""The errors of oslbench. Everything raised for a caller derives from :class:`OslbenchError`; a bad input is
also a :class:`ValueError` (an unknown id a :class:`KeyError`) whose message names the input.
:class:`SimulationStopped` and :class:`DeadlineExceeded` are the runner's control flow and never reach a caller.
"""

from __future__ import annotations

__all__ = ["DesignError", "ExecutorError", "OslbenchError", "OutDirError", "PlantError", "PluginError",
           "RegistryError", "StudyError", "UnknownIdError"]


class OslbenchError(Exception):
    """Base class of the errors oslbench raises."""


class PlantError(OslbenchError, ValueError):
    """A plant (or one of its fields) is invalid. The message names the field."""


class DesignError(OslbenchError, ValueError):
    """A design parameter is invalid; the message names the parameter."""


class PluginError(OslbenchError, ValueError):
    """A plugin file could not be loaded; the message names the file."""


class RegistryError(OslbenchError, ValueError):
    """A registration problem (duplicate id, bad id)."""


class UnknownIdError(OslbenchError, KeyError):
    """An id or glob that matches nothing in a registry ("unknown plant 'x'", "plant glob 'x*' matches nothing")."""

    def __init__(self, kind: str, pattern: str, suggestions: list[str]):
        self.kind = kind
        self.pattern = pattern
        self.suggestions = suggestions
        hint = f"; did you mean {' or '.join(repr(s) for s in suggestions)}?" if suggestions else ""
        is_glob = isinstance(pattern, str) and any(ch in pattern for ch in "*?[")
        what = f"{kind} glob {pattern!r} matches nothing" if is_glob else f"unknown {kind} {pattern!r}"
        super().__init__(what + hint)

    def __str__(self) -> str:  # KeyError quotes its message otherwise
        return self.args[0]


class StudyError(OslbenchError, ValueError):
    """A bad argument ``param`` of a study; ``str(error)`` is ``"<param>: <message>"``."""

    def __init__(self, param: str, message: str):
        self.param = param
        self.message = message
        super().__init__(f"{param}: {message}")


class OutDirError(OslbenchError, ValueError):
    """An output folder that cannot be used, or a write that could not be completed."""


class ExecutorError(OslbenchError, RuntimeError):
    """The requested executor cannot be created (bad job count, unreachable scheduler, ...)."""


# -- the runner's control flow (not exported from ``bench``) --------------------------------------
class SimulationStopped(Exception):
    """A simulation stopped by its right-hand side; ``status`` is the trajectory's (budget, timeout, diverged)."""

    def __init__(self, status: str, message: str):
        super().__init__(message)
        self.status = status


class DeadlineExceeded(BaseException):
    """The time limit of the current :func:`bench.limits.time_limit` scope ran out (``where``: what was running)."""

    def __init__(self, where: str):
        super().__init__(where)
        self.where = where


class HardStop(DeadlineExceeded):
    """:class:`DeadlineExceeded` raised into a thread by :func:`bench.limits.hard_stop` (built without arguments)."""

    def __init__(self, where: str = "code that checks no time limit (hard stop in a thread)"):
        super().__init__(where)
