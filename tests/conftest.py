"""Test-session settings.

One BLAS thread: the filters' matrices are small, so BLAS threads cost more in
synchronisation than they gain (docs/performance_notes.md), and results do not
depend on the machine's core count. Set before numpy is imported by any test
module.
"""

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")


import gymnasium  # noqa: E402
import gymnasium.envs.registration  # noqa: E402
import gymnasium.wrappers.common  # noqa: E402
import numpy as np  # noqa: E402  (after the BLAS settings above)
import pytest  # noqa: E402

from seif_gym.slam import RangeBearingSensor, VelocityMotionModel  # noqa: E402
from seif_gym.slam.simulation import loop_controls, loop_start_pose, ring_landmarks, simulate_run  # noqa: E402


@pytest.fixture(scope="session")
def ring_loop_run():
    """A noisy 300-step run (dt 0.1) around a ring of 40 landmarks that closes its loop (SEIF and ESEIF tests)."""
    rng = np.random.default_rng(7)
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(sigma_range=0.1, sigma_bearing=np.radians(1.0), max_range=5.0)
    landmarks = ring_landmarks(40, 6.0, 12.0, rng)
    run = simulate_run(motion, sensor, landmarks, loop_controls(300, 0.1, radius=9.0), 0.1, loop_start_pose(9.0), rng)
    return motion, sensor, run


#: gymnasium's own TimeLimit, captured before any test module is collected: importing rl_zoo3 (which
#: agents.train does) replaces it process-wide by a subclass that adds info["TimeLimit.truncated"]
_TIME_LIMIT = gymnasium.wrappers.common.TimeLimit


@pytest.fixture(autouse=True)
def gymnasium_time_limit():
    """Every test starts with gymnasium's own TimeLimit, whatever an earlier test imported."""
    for module in (gymnasium.wrappers, gymnasium.wrappers.common, gymnasium.envs.registration):
        module.TimeLimit = _TIME_LIMIT
    yield
