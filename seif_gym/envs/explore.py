"""SeifExplore: learn to explore with a SEIF in the loop."""

from __future__ import annotations

import inspect
import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import gymnasium as gym
import numpy as np
import scipy.sparse.linalg
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from seif_gym.metrics import filter_map_error, map_error
from seif_gym.metrics import nees_kernel as _nees
from seif_gym.observation import BeliefEncoder, ObservationConfig
from seif_gym.slam import (
    FILTERS,
    SEIF,
    InformationForm,
    RangeBearingSensor,
    SlamFilter,
    SparseInformationForm,
    VelocityMotionModel,
    make_filter,
)
from seif_gym.slam.association import ASSOCIATOR_PRESETS, AssociationAudit, make_associator
from seif_gym.slam.models import wrap_angle
from seif_gym.slam.noise_models import PerSecondVelocityMotionModel, RangeDependentSensor
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import as_nonnegative_scalar, as_positive_scalar
from seif_gym.world import World, WorldConfig, make_landmarks

if TYPE_CHECKING:
    from seif_gym.render import Renderer  # imports matplotlib: loaded on the first render()

__all__ = [
    "Measurements", "SeifExploreEnv", "RewardConfig", "RobotConfig", "SensorConfig", "FilterConfig",
    "map_error", "filter_map_error",
]  # fmt: skip


REWARDS = ("map_error", "information_gain")

#: Most landmarks the env accepts (:class:`~seif_gym.world.WorldConfig` alone takes more): a step's cost
#: grows with the landmarks each scan sees, through the dense block over their Markov blankets that the
#: observation inverts; ten times the largest registered task (120) keeps a step on the order of a second or less.
MAX_LANDMARKS = 1000

#: Most cells along each side of the swept-area grid (``ceil(arena_size / coverage_resolution)``):
#: the grid is one byte a cell, so this bounds it at 16 MiB.
MAX_COVERAGE_CELLS = 4096


class Measurements(NamedTuple):
    """One step's measurements: ranges (m), bearings (rad, robot frame) and landmark ids."""

    ranges: FloatArray
    bearings: FloatArray
    ids: NDArray[np.int64]


#: ``motion_model`` -> how many numbers its ``motion_noise`` holds.
MOTION_MODELS: dict[str, int] = {"thrun": 6, "per_second": 9}


@dataclass(frozen=True)
class RobotConfig:
    """Controls and motion noise of the robot (the velocity motion model).

    ``motion_model="thrun"``: Thrun's model, ``motion_noise`` = α1…α6
    (:class:`~seif_gym.slam.models.VelocityMotionModel`). ``"per_second"``:
    noise densities per second, so that the belief does not depend on the
    time step, ``motion_noise`` = forward (3), turn (3), lateral (3)
    (:class:`~seif_gym.slam.noise_models.PerSecondVelocityMotionModel`).
    """

    dt: float = 0.25
    max_speed: float = 1.0
    max_turn_rate: float = 1.0
    motion_noise: tuple[float, ...] = (0.01, 0.001, 0.001, 0.01, 0.0005, 0.0005)
    motion_model: str = "thrun"

    def __post_init__(self) -> None:
        for name in ("dt", "max_speed", "max_turn_rate"):  # kept as the checked float (a 0-d array is no config value)
            object.__setattr__(self, name, as_positive_scalar(getattr(self, name), name))
        if not isinstance(self.motion_model, str) or self.motion_model not in MOTION_MODELS:
            raise ValueError(f"motion_model must be one of {tuple(MOTION_MODELS)}, got {self.motion_model!r}")
        count = MOTION_MODELS[self.motion_model]
        try:
            noise = np.asarray(self.motion_noise, dtype=float)
        except (TypeError, ValueError):
            noise = np.empty(0)
        if noise.shape != (count,) or not np.all(np.isfinite(noise)) or np.any(noise < 0):
            raise ValueError(
                f"motion_noise must be {count} non-negative numbers for motion_model={self.motion_model!r}, "
                f"got {self.motion_noise!r}"
            )


@dataclass(frozen=True)
class SensorConfig:
    """The range-bearing sensor."""

    sensor_range: float = 5.0
    fov: float = math.pi
    sigma_range: float = 0.1
    sigma_bearing: float = math.radians(2.0)
    #: ``(a, lo, hi)``: range noise ``clip(a r, lo, hi)`` (``RangeDependentSensor``) instead of ``sigma_range``.
    range_noise: tuple[float, ...] | None = None
    #: Correlation time of each landmark's range error, s (``None``: white errors).
    range_error_time: float | None = None
    #: Landmarks this close or closer are not seen, metres (``-v2``: 0.3; ``-v0``/``-v1``: 0).
    sensor_min_range: float = 0.3

    def __post_init__(self) -> None:
        for name in ("sensor_range", "fov", "sigma_range", "sigma_bearing"):
            object.__setattr__(self, name, as_positive_scalar(getattr(self, name), name))
        minimum = self.sensor_min_range
        if isinstance(minimum, bool) or not isinstance(minimum, (int, float)) or not 0.0 <= minimum < self.sensor_range:
            raise ValueError(f"sensor_min_range must be a number in [0, sensor_range), got {minimum!r}")
        if self.fov > 2.0 * math.pi + 1e-12:
            raise ValueError(f"fov must be at most 2*pi, got {self.fov!r}")
        if self.range_noise is not None:
            try:
                values = np.asarray(self.range_noise, dtype=float)
            except (TypeError, ValueError):
                values = np.empty(0)
            if (
                values.shape != (3,)
                or not np.all(np.isfinite(values))
                or not (values[0] > 0 and 0 < values[1] <= values[2])
            ):
                raise ValueError(
                    f"range_noise must be (a, lo, hi) with a > 0 and 0 < lo <= hi, got {self.range_noise!r}"
                )
        if self.range_error_time is not None:
            object.__setattr__(self, "range_error_time", as_positive_scalar(self.range_error_time, "range_error_time"))


def make_models(
    config: Mapping[str, Any],
) -> tuple[VelocityMotionModel | PerSecondVelocityMotionModel, RangeBearingSensor]:
    """The motion model and the sensor of the env keyword arguments ``config`` (as the env builds them).

    One home for both the env and the replay of recorded episodes
    (:func:`seif_gym.episodes.episode_models`): keys missing from ``config``
    (episodes recorded before they existed) take the env's defaults, but for
    ``sensor_min_range``, which takes 0 (what every env had before it existed).
    """
    robot = RobotConfig(
        dt=float(config.get("dt", 0.25)),
        motion_noise=tuple(config["motion_noise"]),
        motion_model=config.get("motion_model", "thrun"),
    )
    range_noise = config.get("range_noise")
    sensor_config = SensorConfig(
        sensor_range=config["sensor_range"], fov=config["fov"], sigma_range=config["sigma_range"],
        sigma_bearing=config["sigma_bearing"], range_noise=None if range_noise is None else tuple(range_noise),
        sensor_min_range=float(config.get("sensor_min_range", 0.0)),
    )  # fmt: skip
    motion: VelocityMotionModel | PerSecondVelocityMotionModel
    if robot.motion_model == "per_second":
        noise = robot.motion_noise
        motion = PerSecondVelocityMotionModel(forward=noise[0:3], turn=noise[3:6], lateral=noise[6:9])
    else:
        motion = VelocityMotionModel(alphas=robot.motion_noise)
    sensor: RangeBearingSensor
    if sensor_config.range_noise is not None:
        slope, low, high = sensor_config.range_noise
        sensor = RangeDependentSensor(
            range_slope=slope, range_bounds=(low, high), sigma_bearing=sensor_config.sigma_bearing,
            max_range=sensor_config.sensor_range, fov=sensor_config.fov, min_range=sensor_config.sensor_min_range,
        )  # fmt: skip
    else:
        sensor = RangeBearingSensor(
            sigma_range=sensor_config.sigma_range, sigma_bearing=sensor_config.sigma_bearing,
            max_range=sensor_config.sensor_range, fov=sensor_config.fov, min_range=sensor_config.sensor_min_range,
        )  # fmt: skip
    return motion, sensor


@dataclass(frozen=True)
class FilterConfig:
    """Which filter of :mod:`seif_gym.slam` runs inside, and its options."""

    filter: str = "seif"
    max_active: int | None = 8
    data_association: str = "known"
    mean_recovery: str = "wavefront"
    ml_association: str = "individual"
    #: The filters' ``innovation_gate`` (squared Mahalanobis distance, 2 dof; ``None``: no gate).
    innovation_gate: float | None = None

    def __post_init__(self) -> None:
        if self.filter not in FILTERS:
            raise ValueError(f"filter must be one of {tuple(FILTERS)}, got {self.filter!r}")
        if self.mean_recovery not in SEIF.MEAN_RECOVERIES:
            raise ValueError(f"mean_recovery must be one of {SEIF.MEAN_RECOVERIES}, got {self.mean_recovery!r}")
        if self.data_association not in ("known", "ml"):
            raise ValueError(f"data_association must be 'known' or 'ml', got {self.data_association!r}")
        if self.ml_association not in ASSOCIATOR_PRESETS:
            raise ValueError(f"ml_association must be one of {tuple(ASSOCIATOR_PRESETS)}, got {self.ml_association!r}")


@dataclass(frozen=True)
class RewardConfig:
    """The reward and the episode's end."""

    reward: str = "map_error"
    d_cap: float = 2.0
    wall_penalty: float = 0.005
    divergence_threshold: float = 5.0

    def __post_init__(self) -> None:
        if self.reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {self.reward!r}")
        for name in ("d_cap", "divergence_threshold"):
            object.__setattr__(self, name, as_positive_scalar(getattr(self, name), name))
        object.__setattr__(self, "wall_penalty", as_nonnegative_scalar(self.wall_penalty, "wall_penalty"))


def _no_clock() -> float:
    return 0.0


class SeifExploreEnv(gym.Env):
    """
    ## Description

    A robot with Thrun's velocity motion model and a range-bearing landmark
    sensor explores a square arena of point landmarks. A Sparse Extended
    Information Filter (SEIF, `seif_gym.slam.SEIF`) runs in every step: it
    is told the executed control and the noisy measurements (with known
    landmark ids) and keeps the belief over the robot pose and the map. The
    agent observes **only this belief** and is rewarded for making the
    estimated map accurate, so it learns where to go to map the landmarks
    well: exploration, and revisits that close loops.

    ## Action Space

    `Box(-1, 1, (2,), float32)`, scaled inside:

    | Num | Action          | Control                          | Min            | Max           |
    |-----|-----------------|----------------------------------|----------------|---------------|
    | 0   | forward speed   | `v = a0 * max_speed` (m/s)       | `-max_speed`   | `max_speed`   |
    | 1   | turn rate       | `w = a1 * max_turn_rate` (rad/s) | `-max_turn_rate` | `max_turn_rate` |

    Finite actions outside `[-1, 1]` are clipped; NaN or infinite actions
    raise `ValueError`.

    ## Observation Space

    A flat `Dict` of 1-D `float32` vectors and one `uint8` image, so that
    SB3's `MultiInputPolicy` and its `check_env` take it as is:

    | Key              | Shape       | Range   | Content |
    |------------------|-------------|---------|---------|
    | `pose`           | (7,)        | [-1, 1] | estimated `x/h`, `y/h` (`h` = half the arena), `cos θ`, `sin θ`, and the pose's standard deviations `σx/s`, `σy/s`, `σθ/π` (`s` = `std_scale`, clipped at 1) |
    | `landmarks`      | (4K,)       | [-1, 1] | the `K` mapped landmarks nearest to the estimated pose, nearest first, 4 numbers each (`reshape(K, 4)`): position ahead and to the left of the robot (divided by the arena diagonal), and the major and minor semi-axes of their 95% ellipse (divided by `std_scale`, clipped at 1); zeros pad |
    | `landmarks_mask` | (K,)        | {0, 1}  | 1 for the rows of `landmarks` that hold a landmark |
    | `belief_map`     | (3, H, H) `uint8` | [0, 255] | egocentric raster of `2·map_extent` metres, heading up (row 0 ahead, column 0 left): channel 0 the area the sensor has swept (from the *estimated* poses, 255 = swept), channel 1 the mapped landmarks weighted by certainty `255/(1 + std/s)`, channel 2 the outside of the arena (255) |

    Uncertainties come from the filter's `local_marginals`: exact for the EKF
    and EIF; for the SEIF the constant-time Markov-blanket covariance (the
    block of the robot, its active landmarks and the listed ones, conditioned
    on the rest of the map), which is tighter than the exact marginal.

    ## Rewards

    With `E_t` the map error, the mean over **all** `n` true landmarks of
    `min(‖m̂_i − m_i‖, d_cap)` (an unmapped landmark counts `d_cap`), the
    reward is `r_t = E_{t−1} − E_t − wall_penalty·[wall contact]`. The
    undiscounted return is therefore `E_0 − E_T` minus the penalties: the
    gain in map accuracy over the episode. `m̂` is the filter's current
    estimate, so a landmark whose estimate drifts costs reward again.

    `reward="information_gain"` replaces `E_{t−1} − E_t` by the decrease of
    the D-optimality criterion `log det Σ / n_dims` of the filter's
    covariance over the full map (an unmapped landmark counted with the
    prior variance `d_cap²` per axis), computed from the sparse information
    matrix by a sparse LU factorisation (never a dense inverse). Agents can
    exploit an overconfident filter under this reward, which is why the
    default stays the ground-truth map error.

    ## Starting State

    A new landmark layout is drawn at every reset (from the seed). The robot
    starts at a uniform position in the central half of the arena with a
    uniform heading; the filter starts at the true pose with a tiny
    covariance (the map frame is anchored at the start) and processes a
    first measurement before the first observation.

    ## Episode End

    * Truncation: the time limit of the registration (`max_episode_steps`):
      each registered id sets its own, given in the registry and on that
      task's page.
    * Termination: the estimate diverged, i.e. the estimated position is
      more than `divergence_threshold` metres from the true one;
      `info["diverged"]` is then `True`.

    At the wall the robot's translation is blocked: a step whose noise-free
    motion would leave the arena is executed as a turn in place (`v = 0`,
    the filter is told so), `info["wall_contact"]` is `True` and the step
    costs `wall_penalty`.

    ## Info

    | Key | Type | Content |
    |---|---|---|
    | `true_pose` | (3,) float | the true `(x, y, θ)` (for evaluation; agents must not use it) |
    | `pose_estimate` | (3,) float | the filter's pose estimate |
    | `pose_error` | float | distance between true and estimated position, m |
    | `map_error` | float | `E_t` of Rewards |
    | `pose_nees` | float | NEES of the pose against the filter's own `pose_covariance` (the exact marginal of its belief; for the SEIF a factorisation of Ω, so it costs more than the rest of the filter step on large maps); NaN with `exact_pose_nees=False` |
    | `pose_nees_blanket` | float | NEES against the covariance the observation shows (`local_marginals`: for the SEIF the Markov-blanket covariance, tighter than the marginal; the same as `pose_nees` for the exact filters) |
    | `landmarks_mapped`, `landmarks_total` | int | landmarks in the filter's map, and in the world |
    | `active_landmarks` | tuple of int | ids of the landmarks linked to the robot (all mapped ones for the exact filters) |
    | `control` | (2,) float | commanded `(v, ω)` after scaling and clipping |
    | `executed_control` | (2,) float | what the filter was told (`v = 0` at the wall) |
    | `measurements` | `Measurements` | named tuple `(ranges, bearings, ids)` of this step |
    | `step_time` | float | seconds in the filter this step with `measure_time=True`, else 0.0 |
    | `wall_contact`, `diverged` | bool | see Episode End |
    | `association_errors` | int | with `data_association="ml"`: this step's wrong, duplicate or discarded association decisions (0 with known ids) |

    Variable-length entries are tuples, so that `gym.make_vec` can batch
    the infos (as object arrays).

    ## Arguments

    ```python
    gym.make("SeifExplore-v0", layout="loop", num_landmarks=40, filter="ekf")
    ```

    | Argument | Default | Meaning |
    |---|---|---|
    | `arena_size` | 20.0 | side of the square arena, metres (more than 4 m, at most `seif_gym.world.MAX_ARENA_SIZE` = 1000) |
    | `layout` | `"uniform"` | `"uniform"`, `"clustered"`, `"loop"` or `"fixed"` (`seif_gym.world.make_landmarks`) |
    | `num_landmarks` | 30 | landmarks in the arena (at most `MAX_LANDMARKS` = 1000: a step's cost grows with the landmarks each scan sees) |
    | `arena_extent` | `None` | `(width, height)` of a walled rectangle centred in the square (each at most `arena_size`; the observation's frame stays the square) |
    | `landmark_positions` | `None` | with `layout="fixed"`: the `num_landmarks` landmark positions `(x, y)` |
    | `sensor_range` | 5.0 | metres |
    | `sensor_min_range` | 0.3 | metres: a landmark this close or closer is not seen (`-v2`; 0 in `-v0`/`-v1`, where a robot standing on a landmark made the SEIF's information matrix indefinite) |
    | `fov` | π | full opening angle of the sensor, radians |
    | `sigma_range`, `sigma_bearing` | 0.1, 2° | measurement noise |
    | `motion_noise` | (0.01, 0.001, 0.001, 0.01, 0.0005, 0.0005) | Thrun's α1…α6; with `motion_model="per_second"` nine noise densities per second: forward, turn and lateral, each `(constant, per v², per ω²)` (`PerSecondVelocityMotionModel`) |
    | `motion_model` | `"thrun"` | `"thrun"` (Thrun's model: its noise shrinks with `dt`) or `"per_second"` (dt-linear noise, as calibrated on real robots: `seif_gym.datasets.mrclam`) |
    | `range_error_time` | `None` | correlation time of each landmark's range error, s: an Ornstein-Uhlenbeck process (`exp(-dt/τ)` per step) scaled by the range noise, as real range errors drift (MRCLAM: 0.7 after 5 s); the filter still assumes white noise. `None`: white |
    | `range_noise` | `None` | `(a, lo, hi)`: range noise `clip(a·r, lo, hi)` growing with range (`RangeDependentSensor`), used instead of `sigma_range` |
    | `dt` | 0.25 | seconds per step |
    | `max_speed`, `max_turn_rate` | 1.0, 1.0 | action scaling, m/s and rad/s |
    | `filter` | `"seif"` | any of `seif_gym.slam.FILTERS` |
    | `max_active` | 8 | SEIF's active-landmark bound `k` (ignored by the exact filters) |
    | `ml_association` | `"individual"` | with `data_association="ml"`: the associator preset (`seif_gym.slam.association.ASSOCIATOR_PRESETS`): `"individual"` (individual compatibility, as in 0.1; every version) or `"joint"` (joint compatibility with deferred lone loop closures: fewer false closures for the EKF; slower, and it discards lone revisits) or `"revisable"` (joint, with duplicates merged back and deferred lone closures kept as tentative landmarks: `docs/filters/fidelity.md`) or `"likelihood"` (revisable, with joint hypotheses ranked by likelihood, `docs/filters/fidelity.md`) or `"tentative"` (likelihood, with open tentative landmarks: nothing discarded, the most faithful on loop closures and the library's `Associator()`, `docs/filters/index.md`) |
    | `innovation_gate` | `None` | every filter's gate: a measurement of a mapped landmark whose squared Mahalanobis distance exceeds it is left out of the update (13.8 = χ²₂ 99.9 %; real data's outliers) |
    | `mean_recovery` | `"wavefront"` | SEIF/ESEIF mean recovery: `"wavefront"` (`-v1`), Thrun's round-robin `"amortized"` (`-v0`), or `"exact"` (a sparse solve every step) |
    | `data_association` | `"known"` | `"known"`: the filter gets the true landmark ids; `"ml"`: maximum-likelihood association (`seif_gym.slam.Associator`: χ² gate, new-landmark threshold, mutual exclusion; SEIF covariances from the Markov blanket), so that agents and filters face association errors |
    | `reward` | `"map_error"` | or `"information_gain"` |
    | `d_cap` | 2.0 | cap of a landmark's error in `E_t`, metres |
    | `wall_penalty` | 0.005 | per step in contact with the wall |
    | `divergence_threshold` | 5.0 | pose error that ends the episode, metres |
    | `nearest_landmarks`, `map_size`, `map_extent`, `std_scale` | 8, 40, 8.0, 1.0 | observation shape (`ObservationConfig`) |
    | `coverage_resolution` | 0.5 | cell size of the swept-area grid, metres (at most `MAX_COVERAGE_CELLS` = 4096 cells along the arena's side) |
    | `measure_time` | `False` | fill `info["step_time"]` with the wall-clock seconds spent in the filter (otherwise 0.0: wall-clock time would make seeded episodes irreproducible) |
    | `exact_pose_nees` | `True` | fill `info["pose_nees"]` (otherwise NaN, and nothing else changes): the exact pose marginal factorises Ω every step, which on maps of more than 60 landmarks costs more than the rest of the step; `agents.train` and the evaluation tools, which never read it, turn it off |
    | `render_mode` | `None` | `"rgb_array"` or `"human"` |

    ## Version History

    Every version of the registered ids, and what changed in each, is listed
    in `CHANGELOG.md`, section "Environment versions".
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(
        self,
        *,
        arena_size: float = 20.0,
        layout: str = "uniform",
        num_landmarks: int = 30,
        arena_extent: tuple[float, float] | None = None,
        landmark_positions: tuple[tuple[float, float], ...] | None = None,
        sensor_range: float = 5.0,
        sensor_min_range: float = 0.3,
        fov: float = math.pi,
        sigma_range: float = 0.1,
        sigma_bearing: float = math.radians(2.0),
        motion_noise: tuple[float, ...] = (0.01, 0.001, 0.001, 0.01, 0.0005, 0.0005),
        motion_model: str = "thrun",
        range_noise: tuple[float, float, float] | None = None,
        range_error_time: float | None = None,
        dt: float = 0.25,
        max_speed: float = 1.0,
        max_turn_rate: float = 1.0,
        filter: str = "seif",
        max_active: int | None = 8,
        data_association: str = "known",
        mean_recovery: str = "wavefront",
        ml_association: str = "individual",
        innovation_gate: float | None = None,
        reward: str = "map_error",
        d_cap: float = 2.0,
        wall_penalty: float = 0.005,
        divergence_threshold: float = 5.0,
        nearest_landmarks: int = 8,
        map_size: int = 40,
        map_extent: float = 8.0,
        std_scale: float = 1.0,
        coverage_resolution: float = 0.5,
        measure_time: bool = False,
        exact_pose_nees: bool = True,
        render_mode: str | None = None,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.world_config = WorldConfig(
            arena_size=arena_size, layout=layout, num_landmarks=num_landmarks, arena_extent=arena_extent,
            landmark_positions=landmark_positions,
        )  # fmt: skip
        self.robot_config = RobotConfig(
            dt=dt, max_speed=max_speed, max_turn_rate=max_turn_rate, motion_noise=tuple(motion_noise),
            motion_model=motion_model,
        )  # fmt: skip
        self.sensor_config = SensorConfig(
            sensor_range=sensor_range, fov=fov, sigma_range=sigma_range, sigma_bearing=sigma_bearing,
            range_noise=None if range_noise is None else tuple(range_noise),
            range_error_time=range_error_time, sensor_min_range=sensor_min_range,
        )  # fmt: skip
        self.filter_config = FilterConfig(
            filter=filter, max_active=max_active, data_association=data_association,
            mean_recovery=mean_recovery, ml_association=ml_association, innovation_gate=innovation_gate,
        )  # fmt: skip
        self.reward_config = RewardConfig(
            reward=reward, d_cap=d_cap, wall_penalty=wall_penalty, divergence_threshold=divergence_threshold
        )
        self.observation_config = ObservationConfig(
            nearest_landmarks=nearest_landmarks,
            map_size=map_size,
            map_extent=map_extent,
            std_scale=std_scale,
            coverage_resolution=coverage_resolution,
        )
        if self.world_config.num_landmarks > MAX_LANDMARKS:
            raise ValueError(
                f"num_landmarks must be at most MAX_LANDMARKS = {MAX_LANDMARKS} (a step's cost grows with the "
                f"landmarks each scan sees), got {self.world_config.num_landmarks}"
            )
        cells = math.ceil(self.world_config.arena_size / self.observation_config.coverage_resolution)
        if cells > MAX_COVERAGE_CELLS:
            raise ValueError(
                f"arena_size / coverage_resolution = {self.world_config.arena_size} / "
                f"{self.observation_config.coverage_resolution} gives a coverage grid of {cells} cells a side, more than "
                f"MAX_COVERAGE_CELLS = {MAX_COVERAGE_CELLS}: use a smaller arena_size or a coarser coverage_resolution"
            )
        self.motion, self.sensor = make_models({**asdict(self.robot_config), **asdict(self.sensor_config)})
        # validate the filter options once, at construction
        make_filter(self.filter_config.filter, self.motion, self.sensor, np.zeros(3), **self._filter_options())
        self.encoder = BeliefEncoder(arena_size, self.sensor, self.observation_config)
        self.observation_space = self.encoder.observation_space
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._action_scale = np.array([max_speed, max_turn_rate])
        if not isinstance(measure_time, bool):
            raise TypeError(f"measure_time must be a bool, got {type(measure_time).__name__}")
        self.measure_time = measure_time
        self._clock = time.perf_counter if measure_time else _no_clock
        if not isinstance(exact_pose_nees, bool):
            raise TypeError(f"exact_pose_nees must be a bool, got {type(exact_pose_nees).__name__}")
        self.exact_pose_nees = exact_pose_nees
        self.render_mode = render_mode
        self._renderer: Renderer | None = None
        self.world: World | None = None
        self.filter: SlamFilter | None = None
        self.trajectory: list[FloatArray] = []
        self.estimated_trajectory: list[FloatArray] = []

    # -- configuration ---------------------------------------------------------
    def _filter_options(self) -> dict[str, Any]:
        config = self.filter_config
        options: dict[str, Any] = {}
        if config.innovation_gate is not None:  # every filter takes it; left out, the filter is as before
            options["innovation_gate"] = config.innovation_gate
        if config.filter not in ("seif", "eseif", "cseif"):
            return options
        return {"max_active": config.max_active, "mean_recovery": config.mean_recovery, **options}

    @property
    def config(self) -> dict[str, Any]:
        """All constructor arguments (``gym.make`` keyword arguments) but ``render_mode``."""
        merged: dict[str, Any] = {}
        for part in (
            self.world_config, self.robot_config, self.sensor_config,
            self.filter_config, self.reward_config, self.observation_config,
        ):  # fmt: skip
            merged.update(asdict(part))
        merged["measure_time"] = self.measure_time
        merged["exact_pose_nees"] = self.exact_pose_nees
        # only what the constructor takes, so that gym.make(env_id, **env.config) rebuilds the env
        return {key: value for key, value in merged.items() if key in _CONSTRUCTOR_ARGUMENTS}

    # -- gymnasium API -------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode; ``options`` must be ``None`` or empty (the env accepts no reset options).

        Raises
        ------
        TypeError
            If ``options`` is not a mapping.
        ValueError
            If ``options`` has any key; nothing is reset then.
        """
        if options is not None:
            if not isinstance(options, Mapping):
                raise TypeError(f"options must be a dict or None, got {type(options).__name__}")
            if options:
                raise ValueError(
                    f"options has unknown key(s) {sorted(map(str, options))}: SeifExploreEnv.reset accepts no options "
                    "(pass None or {}); the episode's set-up is fixed by the constructor's arguments"
                )
        super().reset(seed=seed)
        # one generator per source of randomness, all drawn from the env's seeded generator
        layout_rng, start_rng, motion_rng, sensor_rng = (
            np.random.Generator(np.random.PCG64(s)) for s in self.np_random.integers(0, 2**63, size=4)
        )
        self._motion_rng, self._sensor_rng = motion_rng, sensor_rng
        config = self.world_config
        landmarks = make_landmarks(config, layout_rng)
        if config.arena_extent is None:
            h = 0.5 * config.half_size
            start = np.array([*start_rng.uniform(-h, h, 2), start_rng.uniform(-math.pi, math.pi)])
        else:  # the middle half of the walled area in each direction
            hx, hy = (0.5 * half for half in config.half_extent)
            start = np.array([*start_rng.uniform((-hx, -hy), (hx, hy)), start_rng.uniform(-math.pi, math.pi)])
        error_time = self.sensor_config.range_error_time
        memory = 0.0 if error_time is None else math.exp(-self.robot_config.dt / error_time)
        self.world = World(config, self.motion, self.sensor, landmarks, start, range_error_memory=memory)
        self.filter = make_filter(self.filter_config.filter, self.motion, self.sensor, start, **self._filter_options())
        ml = self.filter_config.data_association == "ml"
        self.associator = make_associator(self.filter_config.ml_association) if ml else None
        self.audit = AssociationAudit() if ml else None
        self._association_errors = 0
        self.encoder.reset()
        self.trajectory = [start.copy()]
        self.estimated_trajectory = [start.copy()]
        self._elapsed_steps = 0
        ranges, bearings, ids = self.world.measure(self._sensor_rng)
        started = self._clock()
        self._filter_update(ranges, bearings, ids)
        step_time = self._clock() - started
        self.encoder.sweep(self.filter.pose)
        self._map_error = self.map_error()
        self._information = self._log_det_criterion() if self.reward_config.reward == "information_gain" else 0.0
        observation = self.encoder.encode(self.filter)
        info = self._info(np.zeros(2), np.zeros(2), (ranges, bearings, ids), step_time, wall=False, diverged=False)
        if self.render_mode == "human":
            self.render()
        return observation, info

    def step(self, action: ArrayLike) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        world, filt = self._require_state("step")
        if action is None or isinstance(action, (str, bytes)):
            raise TypeError(
                f"action must be 2 numbers in the action space {self.action_space}, got {type(action).__name__}"
            )
        try:
            action = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise TypeError(
                f"action must be 2 numbers in the action space {self.action_space}, got {type(action).__name__}"
            ) from error
        if action.shape != (2,):
            raise ValueError(f"action must have shape (2,), got {action.shape}")
        if not (math.isfinite(action[0]) and math.isfinite(action[1])):
            raise ValueError(f"action must be finite, got {action}")
        control = np.clip(action, -1.0, 1.0) * self._action_scale
        dt = self.robot_config.dt
        executed, wall = world.step(control, dt, self._motion_rng)
        measurement = world.measure(self._sensor_rng)
        started = self._clock()
        # the simulator's data are valid by construction: skip the filter's input checks
        filt.predict_trusted(executed, dt)
        self._filter_update(*measurement)
        step_time = self._clock() - started
        estimate = filt.pose
        self.encoder.sweep(estimate)
        self._elapsed_steps += 1
        self.trajectory.append(world.pose.copy())
        self.estimated_trajectory.append(estimate.copy())

        map_error = self.map_error()
        if self.reward_config.reward == "map_error":
            gain = self._map_error - map_error
        else:
            information = self._log_det_criterion()
            gain = information - self._information
            self._information = information
        self._map_error = map_error
        reward = gain - (self.reward_config.wall_penalty if wall else 0.0)
        pose_error = float(np.hypot(*(world.pose[:2] - estimate[:2])))
        diverged = pose_error > self.reward_config.divergence_threshold
        observation = self.encoder.encode(filt)
        info = self._info(control, executed, measurement, step_time, wall=wall, diverged=diverged)
        if self.render_mode == "human":
            self.render()
        return observation, float(reward), diverged, False, info

    def _require_state(self, method: str) -> tuple[World, SlamFilter]:
        """The world and the filter of the running episode (``RuntimeError`` before ``reset()``)."""
        if self.world is None or self.filter is None:
            raise RuntimeError(f"call reset() before {method}()")
        return self.world, self.filter

    def _filter_update(self, ranges: FloatArray, bearings: FloatArray, true_ids: NDArray[np.int64]) -> None:
        """The filter's measurement update, with the true ids or with ML data association."""
        _, filt = self._require_state("step")
        if self.associator is None:
            filt.update_trusted(ranges, bearings, true_ids)
            return
        ids = self.associator.update(filt, ranges, bearings)
        # scored outside the filter's time: wrong, duplicate or discarded decisions of this step
        assert self.audit is not None  # made together with the associator
        self._association_errors = self.audit.record(self.associator, ids, true_ids)

    # -- reward and info -------------------------------------------------------------
    def map_error(self) -> float:
        """``E_t``: mean over all true landmarks of ``min(error, d_cap)``, unmapped counted as ``d_cap``.

        With ``data_association="ml"`` the filter's landmarks carry the
        associator's ids: each is matched to the true landmark it was created
        from, and only the first landmark made for a true one counts
        (duplicates do not reduce the error).
        """
        world, filt = self._require_state("map_error")
        return filter_map_error(filt, world.landmarks, self.reward_config.d_cap, self.audit)

    def _log_det_criterion(self) -> float:
        """``-log det Sigma / dims`` over the whole map (unmapped landmarks at the prior ``d_cap^2``).

        Computed as ``log det Omega`` from a sparse LU factorisation of the
        information matrix (EKF: ``-log det Sigma``), so the reward
        ``criterion_t - criterion_{t-1}`` is the decrease of ``log det Sigma``.
        """
        _, filt = self._require_state("step")
        unmapped = self.world_config.num_landmarks - filt.num_landmarks
        prior = 2 * unmapped * -math.log(self.reward_config.d_cap**2)
        if not isinstance(filt, InformationForm):
            sign, log_det_cov = np.linalg.slogdet(filt.covariance())
            log_det_info = -log_det_cov
        else:
            lu = scipy.sparse.linalg.splu(filt.information_matrix.tocsc(), permc_spec="MMD_AT_PLUS_A")
            log_det_info = float(np.sum(np.log(np.abs(lu.U.diagonal()))))
        dims = 3 + 2 * self.world_config.num_landmarks
        return float((log_det_info + prior) / dims)

    def _info(
        self,
        control: ArrayLike,
        executed: ArrayLike,
        measurement: tuple[FloatArray, FloatArray, NDArray[np.int64]],
        step_time: float,
        *,
        wall: bool,
        diverged: bool,
    ) -> dict[str, Any]:
        world, filt = self._require_state("step")
        estimate = filt.pose
        error = world.pose - estimate
        error[2] = wrap_angle(float(error[2]))
        # the filter's own (exact marginal) pose covariance; and the constant-time one the observation shows
        nees = float(_nees(error, np.ascontiguousarray(filt.pose_covariance))) if self.exact_pose_nees else math.nan
        nees_blanket = float(_nees(error, self.encoder.pose_covariance))
        ranges, bearings, ids = measurement
        return {
            "true_pose": world.pose.copy(),
            "pose_estimate": estimate.copy(),
            "pose_error": float(math.hypot(error[0], error[1])),
            "map_error": self._map_error,
            "pose_nees": nees,
            "pose_nees_blanket": nees_blanket,
            "landmarks_mapped": int(filt.num_landmarks),
            "landmarks_total": int(self.world_config.num_landmarks),
            # the exact filters link the robot to every mapped landmark
            # (a tuple: its length varies, and vector envs stack arrays of one shape only)
            "active_landmarks": tuple(
                (filt.active_landmarks if isinstance(filt, SparseInformationForm) else filt.landmark_ids).tolist()
            ),
            "control": np.asarray(control, dtype=np.float64).copy(),
            "executed_control": np.asarray(executed, dtype=np.float64).copy(),
            "measurements": Measurements(ranges, bearings, ids),
            "step_time": step_time,
            "wall_contact": wall,
            "diverged": diverged,
            "association_errors": self._association_errors,
        }

    # -- rendering ------------------------------------------------------------------
    def render(self) -> Any:  # an RGB frame (uint8, FRAME_SHAPE) or None; gymnasium 1.2 types it as its RenderFrame
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human' to make()")
            return None
        if self.world is None:
            raise RuntimeError("call reset() before render()")
        from seif_gym.render import Renderer

        if self._renderer is None:
            self._renderer = Renderer(
                self.world_config.arena_size, self.sensor, human=self.render_mode == "human",
                extent=self.world_config.arena_extent,
            )  # fmt: skip
        frame = self._renderer.draw(self)
        return frame if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


#: The keyword arguments of SeifExploreEnv (what ``config`` returns, ``render_mode`` aside).
_CONSTRUCTOR_ARGUMENTS = frozenset(inspect.signature(SeifExploreEnv.__init__).parameters) - {"self", "render_mode"}
