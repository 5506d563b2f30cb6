"""seif_gym: a Gymnasium environment for learning active SLAM with a SEIF in the loop.

Importing the package registers the environments, so both
``gym.make("SeifExplore-v0")`` (after ``import seif_gym``) and
``gym.make("seif_gym:SeifExplore-v0")`` work.

========================== ================================================ ==================
id                         what changes (kwargs of ``SeifExploreEnv``)        max_episode_steps
========================== ================================================ ==================
``SeifExplore-v0``         defaults: 20 m arena, 30 uniform landmarks        400
``SeifExploreLoop-v0``     ``layout="loop"``, 40 landmarks on a ring: the    400
                           map only stays accurate if the loop is closed
``SeifExploreClustered-v0`` ``layout="clustered"``: empty space between       400
                           clusters of landmarks
``SeifExploreLarge-v0``    40 m arena, 120 landmarks                         1000
========================== ================================================ ==================
"""

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

ENTRY_POINT = "seif_gym.envs.explore:SeifExploreEnv"

#: id -> (kwargs, max_episode_steps) of every registered variant.
VARIANTS: dict[str, tuple[dict, int]] = {
    "SeifExplore-v0": ({}, 400),
    "SeifExploreLoop-v0": ({"layout": "loop", "num_landmarks": 40}, 400),
    "SeifExploreClustered-v0": ({"layout": "clustered"}, 400),
    "SeifExploreLarge-v0": ({"arena_size": 40.0, "num_landmarks": 120}, 1000),
}

for _env_id, (_kwargs, _steps) in VARIANTS.items():
    if _env_id not in registry:
        register(id=_env_id, entry_point=ENTRY_POINT, kwargs=_kwargs, max_episode_steps=_steps)

__all__ = ["VARIANTS", "ENTRY_POINT", "__version__"]
