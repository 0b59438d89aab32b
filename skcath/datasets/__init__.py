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

__all__ = [
    "MECHANISMS",
    "SIMULATOR_VERSION",
    "Catheter",
    "ShaftSetting",
    "SimulatedCatheter",
    "benchmark_catheter",
    "clear_data_home",
    "get_data_home",
    "make_benchmark",
    "sample_catheter",
    "setting_parameters",
    "shaft_settings",
    "simulate_run",
]
