"""Episodes of one sub-task policy in its own env, and their summary (``seqdex rollout``, benchmarks).

:func:`run_episode` plays one episode with a policy (any callable from observation to action) and records its
seed, target object, return, length and outcome; :func:`summarize` gives the success rate, return statistics and
the counts per object kind (block type or tool).
"""

import math


def run_episode(env, policy, seed: int, initial_state=None) -> dict:
    """One episode from ``env.reset(seed=seed)`` (from ``initial_state`` if given) with ``policy``: its seed,
    return, length and outcome."""
    options = None if initial_state is None else {"initial_state": initial_state}
    observation, info = env.reset(seed=seed, options=options)
    target = getattr(env.unwrapped, "target_object", None)
    episode_return, length = 0.0, 0
    while True:
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        episode_return += float(reward)
        length += 1
        if terminated or truncated:
            return {"seed": seed, "object": target, "return": episode_return, "length": length,
                    "success": bool(info.get("success", False)), "terminated": bool(terminated),
                    "simulator_error": bool(info.get("simulator_error", False))}


def summarize(records: list[dict]) -> dict:
    """Success rate, mean / std of the return and mean length of the episode ``records``, and episodes and
    successes per object kind (:func:`object_kind` of each episode's target)."""
    returns = [record["return"] for record in records]
    mean = sum(returns) / len(returns)
    per_object: dict[str, dict] = {}
    for record in records:
        counts = per_object.setdefault(object_kind(record.get("object")), {"episodes": 0, "successes": 0})
        counts["episodes"] += 1
        counts["successes"] += int(record["success"])
    return {"success_rate": sum(record["success"] for record in records) / len(records), "mean_return": mean,
            "std_return": math.sqrt(sum((value - mean) ** 2 for value in returns) / len(returns)),
            "mean_length": sum(record["length"] for record in records) / len(records),
            "per_object": dict(sorted(per_object.items()))}


def object_kind(name: str | None) -> str:
    """The kind of a target object: ``"block 6"`` for ``block_6_3`` (its type), a tool's own name, ``"-"`` for
    none (a task without a target object)."""
    if not name:
        return "-"
    parts = name.split("_")
    return f"block {parts[1]}" if parts[0] == "block" and len(parts) >= 2 else name
