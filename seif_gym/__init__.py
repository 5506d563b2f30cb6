"""seif_gym: a Gymnasium environment for learning active SLAM with a SEIF in the loop.

Importing the package registers every task (:data:`VARIANTS`) with gymnasium,
each with the native vector env as its vector entry point, so that
``gym.make("SeifExplore-v2")`` and ``gym.make_vec("SeifExplore-v2", num_envs=8)``
work after ``import seif_gym``, and ``gym.make("seif_gym:SeifExplore-v2")``
without it. The env is :class:`seif_gym.envs.explore.SeifExploreEnv`; the
filter library, usable alone, is :mod:`seif_gym.slam`.

The tasks, their arguments and their versions are documented on the docs'
Tasks pages (one page per registered id) and in ``CHANGELOG.md``, section
"Environment versions".
"""

from gymnasium.envs.registration import register, registry

from seif_gym.envs.mrclam import mrclam_kwargs

__version__ = "1.1.0"

ENTRY_POINT = "seif_gym.envs.explore:SeifExploreEnv"
#: ``gym.make_vec(id, num_envs=N)`` builds this: N envs advanced by compiled kernels (seif_gym/envs/vector.py).
VECTOR_ENTRY_POINT = "seif_gym.envs.vector:SeifExploreVectorEnv"

#: name -> (kwargs, max_episode_steps) of every layout variant, whatever the version.
_LAYOUTS: dict[str, tuple[dict, int]] = {
    "SeifExplore": ({}, 400),
    "SeifExploreLoop": ({"layout": "loop", "num_landmarks": 40}, 400),
    "SeifExploreClustered": ({"layout": "clustered"}, 400),
    "SeifExploreLarge": ({"arena_size": 40.0, "num_landmarks": 120}, 1000),
    # The loop under a step budget (seif_gym 0.3): at 400 steps every explorer closes the ring and the
    # baselines tie; at 150 they separate (docs/benchmark/protocol.md, "Tasks"). Registered in every version,
    # like the other layouts, so that every version stays a complete family.
    "SeifExploreLoopBudget": ({"layout": "loop", "num_landmarks": 40}, 150),
    # The same fix for the uniform and clustered layouts (seif_gym 0.3), which saturate at 400 steps too:
    # 150 steps separate the uniform layout's baselines, the clusters need 100 (at 150 revisit ties
    # info_gain). docs/benchmark/protocol.md, "Tasks", gives the validation figures behind each budget.
    "SeifExploreBudget": ({}, 150),
    "SeifExploreClusteredBudget": ({"layout": "clustered"}, 100),
}

#: The variants registered in every version (``{name}-v{version}``).
VERSIONED_VARIANTS: tuple[str, ...] = tuple(_LAYOUTS)

#: What each version pins beyond the layout (kwargs of ``SeifExploreEnv``).
VERSIONS: dict[int, dict] = {
    0: {"mean_recovery": "amortized", "ml_association": "individual", "sensor_min_range": 0.0},
    1: {"mean_recovery": "wavefront", "ml_association": "individual", "sensor_min_range": 0.0},
    2: {"mean_recovery": "wavefront", "ml_association": "individual", "sensor_min_range": 0.3},
}

#: The newest version, what ``SeifExploreEnv()`` builds with its defaults.
LATEST_VERSION = max(VERSIONS)
#: The default task at the newest version: what the command-line tools run when no ``--env`` is given.
LATEST_ID = f"SeifExplore-v{LATEST_VERSION}"

#: id -> (kwargs, max_episode_steps) of every registered variant, every version.
VARIANTS: dict[str, tuple[dict, int]] = {
    f"{name}-v{version}": ({**kwargs, **pinned}, steps)
    for version, pinned in VERSIONS.items()
    for name, (kwargs, steps) in _LAYOUTS.items()
}

# The env matched to the robots of the UTIAS MRCLAM dataset (seif_gym/envs/mrclam.py): the surveyed
# landmarks, the walls, the robots' limits, the camera and the calibrated noise of Dataset 6, with the
# current version's filter settings (its own version numbers start at 0, as Gymnasium's do; it has no
# seif_gym 0.1 behaviour to keep). 1200 steps of 0.25 s: five minutes.
# -v1 adds the sensor's blind zone of the -v2 family; -v0 (the 0.2 family's settings) stays reproducible.
VARIANTS["SeifExploreMRCLAM-v0"] = ({**mrclam_kwargs(), **VERSIONS[1]}, 1200)
VARIANTS["SeifExploreMRCLAM-v1"] = ({**mrclam_kwargs(), **VERSIONS[LATEST_VERSION]}, 1200)
#: The MRCLAM world's id at its newest version.
MRCLAM_ID = "SeifExploreMRCLAM-v1"

for _env_id, (_kwargs, _steps) in VARIANTS.items():
    if _env_id not in registry:
        register(
            id=_env_id,
            entry_point=ENTRY_POINT,
            vector_entry_point=VECTOR_ENTRY_POINT,
            kwargs=_kwargs,
            max_episode_steps=_steps,
        )

__all__ = [
    "VARIANTS",
    "VERSIONED_VARIANTS",
    "VERSIONS",
    "LATEST_VERSION",
    "LATEST_ID",
    "ENTRY_POINT",
    "VECTOR_ENTRY_POINT",
    "MRCLAM_ID",
    "__version__",
]
