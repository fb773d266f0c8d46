"""seqdex_drake: Sequential Dexterity (Chen, Wang, Fei-Fei, Liu; CoRL 2023) on the Drake toolbox.

Public API::

    from seqdex_drake import LoadScenario, MakeStation
    scenario = LoadScenario("building_blocks/grasp")
    station = MakeStation(scenario, meshcat=None)
"""

from seqdex_drake.scenario import LoadScenario, Scenario, ScenarioError, ScenarioNames
from seqdex_drake.station import CANONICAL_JOINTS, MakeControllerPlant, MakeStation, RefreshSampledOutputs

#: Exported lazily (PEP 562): the chain controller needs torch, which ``import seqdex_drake.<module>`` must not load.
_CHAIN_EXPORTS = ("ChainParams", "ConnectChainController", "LoadChainCheckpoints", "MakeChainController",
                  "SetChainTarget")


def __getattr__(name: str):
    if name in _CHAIN_EXPORTS:
        from seqdex_drake.systems import chain_controller

        return getattr(chain_controller, name)
    raise AttributeError(f"module 'seqdex_drake' has no attribute {name!r}")

__all__ = [
    "CANONICAL_JOINTS",
    "ChainParams",
    "ConnectChainController",
    "LoadChainCheckpoints",
    "MakeChainController",
    "LoadScenario",
    "MakeControllerPlant",
    "MakeStation",
    "RefreshSampledOutputs",
    "Scenario",
    "ScenarioError",
    "ScenarioNames",
    "SetChainTarget",
]
