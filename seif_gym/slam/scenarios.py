"""Loop-closing scenarios: the runs on which the approximate filters are judged.

A robot drives a loop through a field of landmarks: drift builds up while it
maps new landmarks, and the loop closes when it sees the start again. This is
where an approximate filter loses accuracy against the exact one (the
correction must reach every landmark of the loop), so the fidelity benchmark
(``benchmarks/fidelity.py``) and the accuracy tests use these runs.

A :class:`LoopScenario` is a frozen description (path shape, size, sensor,
landmark density, noise); :func:`make_loop_run` draws one run of it from a
seed; :data:`FIDELITY_SCENARIOS` is the family of the benchmark.

>>> from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run
>>> motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["circle"], seed=0)
>>> run.steps, len(run.landmarks) > 30
(314, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from seif_gym.slam.models import RangeBearingSensor, VelocityMotionModel
from seif_gym.slam.simulation import SimulatedRun, simulate_run
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import as_count, as_finite_array, as_nonnegative_scalar, as_positive_scalar

__all__ = [
    "LoopScenario",
    "FIDELITY_SCENARIOS",
    "ASSOCIATION_SCENARIOS",
    "loop_path_controls",
    "loop_landmarks",
    "make_loop_run",
]


SHAPES = ("circle", "rectangle", "figure8")

#: The motion noise of ``SeifExplore`` (Thrun's alpha1..alpha6).
ENV_MOTION_NOISE = (0.01, 0.001, 0.001, 0.01, 0.0005, 0.0005)


@dataclass(frozen=True)
class LoopScenario:
    """One kind of loop-closing run.

    Attributes
    ----------
    shape : {"circle", "rectangle", "figure8"}
        The path: a circle of radius ``size``; a rectangle ``2 size`` by
        ``size`` with rounded corners (radius 2 m); a figure eight of two
        circles of radius ``size`` (the loop closes at the crossing twice).
    size : float
        Radius (circle, figure-eight lobes) or half the long side (rectangle), metres.
    laps : float
        Laps driven; more than 1 so that the start is seen again.
    speed, dt : float
        Forward speed (m/s) and step duration (s).
    landmark_spacing : float
        Mean distance between neighbouring landmarks of the field, metres
        (the density is ``1 / spacing^2``); never closer than ``min_separation``.
    band : float
        Landmarks lie within this distance of the path, metres.
    min_separation : float
        Smallest distance between two landmarks, metres.
    sensor_range, fov, sigma_range, sigma_bearing
        The range-bearing sensor (metres, radians).
    motion_noise : tuple of 6 floats
        Thrun's alphas of the velocity motion model.
    """

    shape: str = "circle"
    size: float = 10.0
    laps: float = 1.25
    speed: float = 1.0
    dt: float = 0.25
    landmark_spacing: float = 2.0
    band: float = 4.0
    min_separation: float = 1.0
    sensor_range: float = 5.0
    fov: float = 2.0 * math.pi
    sigma_range: float = 0.1
    sigma_bearing: float = math.radians(2.0)
    motion_noise: tuple[float, ...] = field(default=ENV_MOTION_NOISE)

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"shape must be one of {SHAPES}, got {self.shape!r}")
        for name in ("size", "laps", "speed", "dt", "landmark_spacing", "band", "sensor_range", "fov",
                     "sigma_range", "sigma_bearing"):  # fmt: skip
            as_positive_scalar(getattr(self, name), name)
        if self.fov > 2.0 * math.pi + 1e-12:
            raise ValueError(f"fov must be at most 2*pi, got {self.fov!r}")
        if not as_nonnegative_scalar(self.min_separation, "min_separation") < self.landmark_spacing:
            raise ValueError(f"min_separation must lie in [0, landmark_spacing), got {self.min_separation!r}")
        if self.shape == "rectangle" and self.size <= 2.0:
            raise ValueError(f"a rectangle needs size > 2 (the corner radius), got {self.size!r}")


#: The benchmark's family: three kinds of loop, each dense with an all-round sensor and sparse or narrow.
FIDELITY_SCENARIOS: dict[str, LoopScenario] = {
    "circle": LoopScenario(shape="circle", size=10.0),
    "circle-sparse": LoopScenario(shape="circle", size=12.0, landmark_spacing=3.5, band=3.0, sensor_range=4.5),
    "rectangle": LoopScenario(shape="rectangle", size=12.0),
    "rectangle-narrow": LoopScenario(shape="rectangle", size=14.0, landmark_spacing=2.5, sensor_range=6.0, fov=math.pi),
    "figure8": LoopScenario(shape="figure8", size=7.0, laps=1.15),
    "figure8-sparse": LoopScenario(
        shape="figure8", size=8.0, laps=1.15, landmark_spacing=3.5, band=3.0, sensor_range=4.5
    ),
    "circle-large": LoopScenario(
        shape="circle", size=18.0, landmark_spacing=2.5, band=3.5, sensor_range=6.0, laps=1.15
    ),
    "rectangle-large": LoopScenario(
        shape="rectangle", size=18.0, landmark_spacing=2.5, band=3.5, sensor_range=6.0, fov=math.pi, laps=1.15
    ),
}


#: Thrun's alphas of the association scenarios (Probabilistic Robotics, table 5.3's model).
THRUN_MOTION_NOISE = (0.01, 0.001, 0.001, 0.01, 1e-4, 1e-4)

#: Runs of unknown correspondences (``benchmarks/association.py``). ``"family-a"``: a circle of radius 8 m
#: driven at 1.2 m/s and 0.15 rad/s for 700 steps of 0.1 s (1.67 laps) through about 60 landmarks within
#: 3.5 m of the path, at least 1 m apart; a 3.5 m, 180 degree sensor with 0.1 m and 0.02 rad noise.
ASSOCIATION_SCENARIOS: dict[str, LoopScenario] = {
    "family-a": LoopScenario(
        shape="circle",
        size=8.0,
        laps=70.0 * 0.15 / (2.0 * math.pi),
        speed=1.2,
        dt=0.1,
        landmark_spacing=math.sqrt(2.0 * math.pi * 8.0 * 7.0 / 60.0),
        band=3.5,
        min_separation=1.0,
        sensor_range=3.5,
        fov=math.pi,
        sigma_range=0.1,
        sigma_bearing=0.02,
        motion_noise=THRUN_MOTION_NOISE,
    ),  # fmt: skip
}


def _check_scenario(scenario: object) -> None:
    if not isinstance(scenario, LoopScenario):
        raise TypeError(f"scenario must be a LoopScenario, got {type(scenario).__name__}")


def _segments(scenario: LoopScenario) -> list[tuple[float, float]]:
    """One lap as ``(duration, omega)`` arcs at ``scenario.speed``."""
    v, size = scenario.speed, scenario.size
    if scenario.shape == "circle":
        return [(2.0 * math.pi * size / v, v / size)]
    if scenario.shape == "figure8":
        return [(2.0 * math.pi * size / v, v / size), (2.0 * math.pi * size / v, -v / size)]
    corner = 2.0
    long_side, short_side = 2.0 * size - 2.0 * corner, size - 2.0 * corner
    turn = (0.5 * math.pi * corner / v, v / corner)
    return [(long_side / v, 0.0), turn, (short_side / v, 0.0), turn] * 2


def loop_path_controls(scenario: LoopScenario) -> tuple[FloatArray, FloatArray]:
    """Controls ``(T, 2)`` of ``scenario.laps`` laps and the start pose ``(3,)``.

    The start is on the path, heading along it; the path of one lap ends where
    it began.
    """
    _check_scenario(scenario)
    segments = _segments(scenario)
    lap_time = sum(duration for duration, _ in segments)
    steps = int(round(scenario.laps * lap_time / scenario.dt))
    times = (np.arange(steps) + 0.5) * scenario.dt % lap_time
    bounds = np.cumsum([duration for duration, _ in segments])
    omegas = np.array([omega for _, omega in segments])[np.minimum(np.searchsorted(bounds, times), len(segments) - 1)]
    controls = np.column_stack([np.full(steps, scenario.speed), omegas])
    if scenario.shape == "rectangle":
        start = np.array([-scenario.size + 2.0, -0.5 * scenario.size, 0.0])
    else:  # circles start at the bottom, heading east (the figure eight's crossing)
        start = np.array([0.0, -scenario.size if scenario.shape == "circle" else 0.0, 0.0])
    return controls, start


def _path_points(scenario: LoopScenario, controls: FloatArray, start: FloatArray) -> FloatArray:
    """Noise-free positions along the path, every step."""
    motion = VelocityMotionModel(alphas=scenario.motion_noise)
    pose = start.copy()
    points = [pose[:2].copy()]
    for control in controls:
        pose = motion.predict(pose, control, scenario.dt)
        points.append(pose[:2].copy())
    return np.array(points)


def loop_landmarks(scenario: LoopScenario, path: FloatArray, rng: np.random.Generator) -> FloatArray:
    """Landmarks within ``band`` of ``path`` at density ``1 / spacing^2``, ``min_separation`` apart.

    Points are drawn uniformly in the path's bounding box grown by ``band``
    and kept when they lie within ``band`` of the path and far enough from
    every kept landmark, until the expected count is reached (or the draws run out).
    """
    _check_scenario(scenario)
    path = as_finite_array(path, "path", (None, 2))
    if len(path) == 0:
        raise ValueError("path must hold at least one point")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    low = path.min(axis=0) - scenario.band
    high = path.max(axis=0) + scenario.band
    # area of the band, estimated on a grid of the bounding box
    grid = np.stack(np.meshgrid(np.linspace(low[0], high[0], 120), np.linspace(low[1], high[1], 120)), -1).reshape(
        -1, 2
    )
    near = _distance_to_path(grid, path) < scenario.band
    area = float(np.prod(high - low)) * float(np.mean(near))
    target = int(round(area / scenario.landmark_spacing**2))
    kept: list[FloatArray] = []
    min_sq = scenario.min_separation**2
    for _ in range(200):
        candidates = rng.uniform(low, high, size=(256, 2))
        candidates = candidates[_distance_to_path(candidates, path) < scenario.band]
        for point in candidates:
            if kept and np.min(np.sum((np.array(kept) - point) ** 2, axis=1)) < min_sq:
                continue
            kept.append(point)
            if len(kept) == target:
                return np.array(kept)
    return np.array(kept)


def _distance_to_path(points: FloatArray, path: FloatArray) -> FloatArray:
    """Distance of each point to the nearest path sample (the samples are dense: a step apart)."""
    out = np.empty(len(points))
    for start in range(0, len(points), 2048):
        chunk = points[start : start + 2048]
        d2 = np.sum((chunk[:, None, :] - path[None, :, :]) ** 2, axis=-1)
        out[start : start + 2048] = np.sqrt(d2.min(axis=1))
    return out


def make_loop_run(
    scenario: LoopScenario, seed: int, *, noise_free: bool = False
) -> tuple[VelocityMotionModel, RangeBearingSensor, SimulatedRun]:
    """One run of ``scenario``: its motion model, sensor and simulated run.

    ``numpy.random.default_rng(seed)`` draws the landmarks first and then all
    noise, so a seed gives the same run bit for bit.
    """
    _check_scenario(scenario)
    as_count(seed, "seed")
    rng = np.random.default_rng(int(seed))
    controls, start = loop_path_controls(scenario)
    landmarks = loop_landmarks(scenario, _path_points(scenario, controls, start), rng)
    motion = VelocityMotionModel(alphas=scenario.motion_noise)
    sensor = RangeBearingSensor(
        sigma_range=scenario.sigma_range,
        sigma_bearing=scenario.sigma_bearing,
        max_range=scenario.sensor_range,
        fov=scenario.fov,
    )
    run = simulate_run(motion, sensor, landmarks, controls, scenario.dt, start, rng, noise_free=noise_free)
    return motion, sensor, run
