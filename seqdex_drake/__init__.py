"""seqdex_drake: Sequential Dexterity (Chen, Wang, Fei-Fei, Liu; CoRL 2023) on the Drake toolbox.

Public API::

    from seqdex_drake import LoadScenario, MakeStation
    scenario = LoadScenario("building_blocks/grasp")
    station = MakeStation(scenario, meshcat=None)
"""

from seqdex_drake.scenario import LoadScenario, Scenario, ScenarioError, ScenarioNames
from seqdex_drake.station import CANONICAL_JOINTS, MakeControllerPlant, MakeStation

__all__ = [
    "CANONICAL_JOINTS",
    "LoadScenario",
    "MakeControllerPlant",
    "MakeStation",
    "Scenario",
    "ScenarioError",
    "ScenarioNames",
]
