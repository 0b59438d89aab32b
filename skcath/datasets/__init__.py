"""Simulated recordings: the physics-based benchmark that is skcath's default data."""

from ._benchmark import (
    SIMULATOR_VERSION,
    benchmark_catheter,
    clear_data_home,
    get_data_home,
    make_benchmark,
)
from ._catheter import Catheter, ShaftSetting, sample_catheter, setting_parameters, shaft_settings
from ._hysteresis import MECHANISMS
from ._rig import SimulatedCatheter
from ._simulator import simulate_run
from ._tasks import (
    Task,
    circle_task,
    figure_eight_task,
    reach_task,
    run_task,
    standard_tasks,
    task_scores,
)

__all__ = [
    "MECHANISMS",
    "SIMULATOR_VERSION",
    "Catheter",
    "ShaftSetting",
    "SimulatedCatheter",
    "Task",
    "benchmark_catheter",
    "circle_task",
    "clear_data_home",
    "figure_eight_task",
    "get_data_home",
    "make_benchmark",
    "reach_task",
    "run_task",
    "sample_catheter",
    "setting_parameters",
    "shaft_settings",
    "simulate_run",
    "standard_tasks",
    "task_scores",
]
