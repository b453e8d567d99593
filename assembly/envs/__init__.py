"""Gymnasium environments with per-episode parameters xi; importing this registers the goflow/ ids.

Keep this module light: it imports only gymnasium. Each entry point is a string, so an
environment's module (and anything heavy it needs, e.g. pydrake) loads only when it is made.
"""

import gymnasium

_ENVS = {
    # id: (entry point, default kwargs, max_episode_steps: the env's own time limit at those kwargs,
    # t_max / control_dt, or the locomotion horizon; None for Toy2D, whose task ends every episode
    # after one step). The envs truncate themselves there; gymnasium.make's TimeLimit then fires on
    # the same step (docs/envs.md, "Rendering and episode length").
    "goflow/Toy2D-v0": ("assembly.envs.toy2d:Toy2DEnv", {"layout": "circle"}, None),
    "goflow/Cartpole-v0": ("assembly.envs.cartpole:CartpoleEnv", {}, 120),
    "goflow/Quadrotor-v0": ("assembly.envs.quadrotor:QuadrotorEnv", {}, 100),
    "goflow/Ant-v0": ("assembly.envs.ant:AntEnv", {}, 128),
    "goflow/Anymal-v0": ("assembly.envs.anymal:AnymalEnv", {}, 250),
    "goflow/Hopper-v0": ("assembly.envs.locomotion:HopperEnv", {}, 1000),
    "goflow/Walker2d-v0": ("assembly.envs.locomotion:Walker2dEnv", {}, 1000),
    "goflow/HalfCheetah-v0": ("assembly.envs.locomotion:HalfCheetahEnv", {}, 1000),
    "goflow/Humanoid-v0": ("assembly.envs.locomotion:HumanoidEnv", {}, 1000),
    "goflow/GearInsertion-v0": (
        "assembly.envs.gear_insertion:GearInsertionEnv",
        {"gear": "medium", "variant": "fast"},
        100,
    ),
}

# Batched vector envs (N copies in one Drake diagram, assembly/envs/batched.py): what
# `gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")` builds.
VECTOR_ENVS = {
    "goflow/Cartpole-v0": "assembly.envs.cartpole_vector:CartpoleVectorEnv",
    "goflow/Quadrotor-v0": "assembly.envs.quadrotor_vector:QuadrotorVectorEnv",
    "goflow/Ant-v0": "assembly.envs.ant_vector:AntVectorEnv",
    "goflow/Anymal-v0": "assembly.envs.anymal_vector:AnymalVectorEnv",
    "goflow/GearInsertion-v0": "assembly.envs.gear_insertion_vector:GearInsertionVectorEnv",
}

for _env_id, (_entry_point, _kwargs, _steps) in _ENVS.items():
    if _env_id not in gymnasium.registry:  # importing twice (e.g. importlib test mode) must not warn
        gymnasium.register(
            id=_env_id,
            entry_point=_entry_point,
            kwargs=dict(_kwargs),
            max_episode_steps=_steps,
            vector_entry_point=VECTOR_ENVS.get(_env_id),
        )
