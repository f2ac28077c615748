"""Wrappers around our envs (each module one concept; import the module you need):

* ``single_agent``: ``SingleAgentEnv`` (one learning player, the others driven by opponents) and the
  Gymnasium ids ``solaris_env/Dream-v0`` / ``solaris_env/Real-v0``.
* ``opponents``: what drives non-learning players (scripted engine bot, random, no-op, frozen policy).
* ``actions``: ``FlatActions``, the Dict action flattened for SB3 (MultiDiscrete with camera bins, or Box).
* ``observations``: ``ResizeFrames`` and ``StackFrames`` for our ParallelEnvs.
* ``video``: ``RecordVideo``, an mp4 of all players side by side.
* ``rerun_log``: ``RerunRecorder``, frames, actions and rewards of every player on one Rerun timeline.
* ``sb3``: ``SB3VecEnv``, the dream vector env as a Stable-Baselines3 ``VecEnv`` (imports torch).
"""
