"""The learning stack: PPO with full-state checkpoints (``ppo``, ``networks``, ``buffer``, ``losses``,
``checkpoint``, ``config``, ``seeding``, ``episode_stats``) and a pure-numpy toy env (``toy_env``) for tests."""
