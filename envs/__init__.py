"""Gymnasium MuJoCo environments of mcpilco.

Importing this package registers the environments with string entry points, so that no
MuJoCo model is built and nothing from ``agents``/``models`` is imported at registration.
"""

import gymnasium

from mcpilco.envs.dmc import register_dmc_envs

gymnasium.register(
    id="mcpilco/CartpoleSwingUp-v0",
    entry_point="mcpilco.envs.cartpole:CartpoleSwingUpEnv",
    max_episode_steps=60,
)
gymnasium.register(
    id="mcpilco/DMCCartpoleSwingUp-v0",
    entry_point="mcpilco.envs.dmc_cartpole:DMCCartpoleSwingUpEnv",
    max_episode_steps=60,
)

# Every dm-control suite task: dm_control/<domain>-<task>-v0 (dm-control imported when made).
register_dmc_envs()

# Arms: joint-trajectory tracking behind a PD + gravity controller, 8 ms samples.
gymnasium.register(
    id="mcpilco/UR10-v0",
    entry_point="mcpilco.envs.arm_env:UR10Env",
    max_episode_steps=1250,
)
gymnasium.register(
    id="mcpilco/SCARA-v0",
    entry_point="mcpilco.envs.arm_env:SCARAEnv",
    max_episode_steps=1250,
)
gymnasium.register(
    id="mcpilco/MarkerCamera-v0",
    entry_point="mcpilco.envs.marker_camera:MarkerCameraEnv",
    max_episode_steps=100,
)
# The marker camera's reaching task for model-free learners: one robot, markers attached once.
gymnasium.register(
    id="mcpilco/MarkerCameraReach-v0",
    entry_point="mcpilco.envs.marker_camera:MarkerCameraEnv",
    max_episode_steps=20,
    kwargs=dict(
        max_increment=0.2,
        start_centre=(0.0, -1.5707963267948966, 1.5707963267948966, 0.0, 1.5707963267948966, 0.0),
        start_range=1.0,
        marker_seed=0,
        marker_facing_cone=40.0,
        shuffle=False,
    ),
)
