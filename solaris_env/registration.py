"""The Gymnasium ids of our single-agent envs. Kept free of heavy imports: ``solaris_env/__init__`` runs
``register_envs`` while ``gymnasium`` itself may be mid-import from one of our modules, so the entry
points are strings resolved only by ``gymnasium.make``."""

ENV_IDS = {"solaris_env/Dream-v0": "solaris_env.wrappers.single_agent:make_dream",
           "solaris_env/Real-v0": "solaris_env.wrappers.single_agent:make_real"}


def register_envs() -> None:
    """Register the single-agent envs with Gymnasium (idempotent)."""
    from gymnasium.envs.registration import register, registry

    for env_id, entry_point in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=entry_point, disable_env_checker=False)
