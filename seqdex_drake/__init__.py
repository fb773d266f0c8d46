"""seqdex_drake: Sequential Dexterity (Chen, Wang, Fei-Fei, Liu; CoRL 2023) on the Drake toolbox.

Public API::

    from seqdex_drake import LoadScenario, MakeStation
    scenario = LoadScenario("building_blocks/grasp")
    station = MakeStation(scenario, meshcat=None)

    import gymnasium as gym
    env = gym.make("seqdex/Grasp-v0")          # every sub-task: seqdex_drake.envs.registration.GYM_IDS

    from seqdex_drake import load_policy
    policy = load_policy("runs/grasp/last.pt")  # numpy observation(s) in, action(s) out
"""

from seqdex_drake import numerics as _numerics

_numerics.pin()  # Before anything loads numpy or torch: the same bits on every x86-64 machine (numerics.py).

from seqdex_drake.envs import registration as _registration  # noqa: E402 - after the pin, on purpose.
from seqdex_drake.scenario import LoadScenario, Scenario, ScenarioError, ScenarioNames  # noqa: E402
from seqdex_drake.station import (  # noqa: E402
    CANONICAL_JOINTS,
    MakeControllerPlant,
    MakeStation,
    RefreshSampledOutputs,
)

# The sub-task envs' gymnasium ids (lazy entry points: nothing is built until gym.make).
_registration.register_envs()

#: Exported lazily (PEP 562): the chain controller needs torch, which ``import seqdex_drake.<module>`` must not load.
_CHAIN_EXPORTS = ("ChainParams", "ConnectChainController", "MakeChainController", "SetChainTarget")
_POLICY_EXPORTS = ("load_policy", "Policy")


def __getattr__(name: str):
    if name == "LoadChainCheckpoints":  # Only looks for files: no torch.
        from seqdex_drake.chaining import chain_files

        return chain_files.LoadChainCheckpoints
    if name in _CHAIN_EXPORTS:  # Needs torch.
        from seqdex_drake.controller import chain_controller

        return getattr(chain_controller, name)
    if name in _POLICY_EXPORTS:  # Needs torch too.
        from seqdex_drake.rl import policy_loading

        return getattr(policy_loading, name)
    raise AttributeError(f"module 'seqdex_drake' has no attribute {name!r}")

__all__ = [
    "CANONICAL_JOINTS",
    "ChainParams",
    "ConnectChainController",
    "LoadChainCheckpoints",
    "MakeChainController",
    "LoadScenario",
    "load_policy",
    "MakeControllerPlant",
    "MakeStation",
    "Policy",
    "RefreshSampledOutputs",
    "Scenario",
    "ScenarioError",
    "ScenarioNames",
    "SetChainTarget",
]
