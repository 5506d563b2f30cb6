"""How the baselines read an observation: the env's own geometry (:class:`Geometry`), and env helpers."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np

from seif_gym.observation import (
    BeliefEncoder,
    ObservationDecoder,
)

__all__ = ["GEOMETRY_READS", "Geometry", "env_list", "heading", "to_robot_frame", "unwrapped_env"]

# -- geometry --------------------------------------------------------------------------------------
#: The env attributes :meth:`Geometry.from_env` reads (configuration, never the world).
GEOMETRY_READS = ("encoder", "sensor", "robot_config")


@dataclass(frozen=True)
class Geometry:
    """What an agent needs to read the observation in metres: the env's own numbers.

    Attributes
    ----------
    decoder : seif_gym.observation.ObservationDecoder
        The inverse of the env's observation encoder (the arena's size, the
        belief map's extent, the standard deviations' scale).
    sensor_range : float
        Range of the sensor, metres.
    fov : float
        Full opening angle of the sensor, radians.
    step_length : float
        Distance of one step at full forward speed (``max_speed·dt``), metres.
    """

    decoder: ObservationDecoder
    sensor_range: float
    fov: float
    step_length: float

    @property
    def arena_size(self) -> float:
        """Side of the square arena, metres."""
        return self.decoder.arena_size

    @property
    def half(self) -> float:
        """``h``, half the arena side, metres."""
        return self.decoder.half_arena

    @property
    def map_extent(self) -> float:
        """Half-width of ``obs["belief_map"]``, metres."""
        return self.decoder.map_extent

    @property
    def std_scale(self) -> float:
        """Divisor of the standard deviations in the observation."""
        return self.decoder.std_scale

    @classmethod
    def of(cls, base: Any) -> Geometry:
        """The geometry of one ``SeifExplore`` env (``env.unwrapped``, or a view with its attributes).

        Raises
        ------
        TypeError
            If ``base`` lacks one of :data:`GEOMETRY_READS` or its encoder is
            not a :class:`~seif_gym.observation.BeliefEncoder`.
        """
        missing = [name for name in GEOMETRY_READS if getattr(base, name, None) is None]
        if missing:
            raise TypeError(f"env must be a SeifExplore env; {type(base).__name__} has no {', '.join(missing)}")
        encoder, sensor, robot = base.encoder, base.sensor, base.robot_config
        if not isinstance(encoder, BeliefEncoder):
            raise TypeError(f"env must be a SeifExplore env; its encoder is a {type(encoder).__name__}")
        return cls(encoder.decoder(), float(sensor.max_range), float(sensor.fov), float(robot.max_speed * robot.dt))

    @classmethod
    def from_env(cls, env: Any) -> Geometry:
        """Read the geometry from the env the agent acts in (its configuration, never its world).

        Parameters
        ----------
        env : gymnasium.Env, vector env or sequence of envs
            A ``SeifExplore`` env (any wrapper), a gymnasium or
            Stable-Baselines3 vector env of them, or a list of them; every
            sub-env must have the same geometry.

        Raises
        ------
        TypeError
            If ``env`` is ``None`` or not a ``SeifExplore`` env: reading its
            observations with another env's numbers would misplace everything.
        ValueError
            If the sub-envs of a vector env differ in geometry.
        """
        if env is None:
            raise TypeError("env must be the SeifExplore env the agent acts in (its geometry decodes the observation), "
                            "got None")  # fmt: skip
        geometries = [cls.of(base) for base in geometry_sources(env)]
        if any(geometry != geometries[0] for geometry in geometries[1:]):
            raise ValueError(f"env: the sub-envs differ in geometry ({geometries[0]} and others); one agent reads one")
        return geometries[0]


def geometry_sources(env: Any) -> list[Any]:
    """The base env(s) of ``env`` whose configuration the agent reads."""
    base = unwrapped_env(env)
    if all(getattr(base, name, None) is not None for name in GEOMETRY_READS):
        return [base]
    if callable(getattr(env, "get_attr", None)) and isinstance(getattr(env, "num_envs", None), int):
        # a Stable-Baselines3 VecEnv: the sub-envs' attributes, one namespace per sub-env
        values = {name: env.get_attr(name) for name in GEOMETRY_READS}
        return [SimpleNamespace(**{name: values[name][i] for name in GEOMETRY_READS}) for i in range(env.num_envs)]
    envs = env_list(env)
    if len(envs) > 1 or (envs and envs[0] is not env):
        return [unwrapped_env(e) for e in envs]
    raise TypeError(f"env must be a SeifExplore env (with {', '.join(GEOMETRY_READS)}), got {type(base).__name__}")


def unwrapped_env(env: Any | None) -> Any | None:
    """``env.unwrapped`` if ``env`` is a gymnasium env, else ``env`` (or ``None``)."""
    if env is None:
        return None
    return getattr(env, "unwrapped", env)


def heading(pose: np.ndarray) -> float:
    return math.atan2(float(pose[3]), float(pose[2]))


def to_robot_frame(dx_h: float, dy_h: float, theta: float, half: float) -> tuple[float, float]:
    """World offset in units of ``h`` -> ``(forward, left)`` metres."""
    c, s = math.cos(theta), math.sin(theta)
    return (c * dx_h + s * dy_h) * half, (-s * dx_h + c * dy_h) * half


def env_list(env: Any) -> list[Any]:
    """``env`` as a list of envs: a single env, a sequence of envs, or a ``DummyVecEnv``'s ``envs``."""
    if env is None:
        return []
    if isinstance(env, gym.Env):
        return [env]
    if "envs" in getattr(env, "__dict__", {}):  # a DummyVecEnv (looked up without probing other envs)
        return list(env.envs)
    if isinstance(env, Sequence) and not isinstance(env, (str, bytes)):
        return list(env)
    return [env]
