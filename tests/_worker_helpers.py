"""Module-level tasks for the start-method tests: a worker started by spawn or forkserver imports them by name."""

import os


def pid_and_size(plant_id: str) -> tuple[int, int]:
    """The process that ran the task, and the state dimension of the plant ``plant_id`` built there."""
    from bench.registry import PLANTS

    return os.getpid(), PLANTS.create(plant_id).n


def design_ids() -> list[str]:
    """The design ids the worker's registry holds."""
    from bench.registry import DESIGNS

    return DESIGNS.ids()
