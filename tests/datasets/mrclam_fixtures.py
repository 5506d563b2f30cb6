"""What the MRCLAM tests share: where Dataset 6 lies, the skip when it is absent, known calibration parameters."""

from __future__ import annotations

from shared_data import full_data  # tests/datasets/ is on sys.path under pytest

from seif_gym.datasets.mrclam import calibration as mc
from seif_gym.slam.noise_models import CommandCorrection

#: ``$SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6``, and the mark of the tests that read it.
DATA_DIR, requires_data = full_data("mrclam/MRCLAM_Dataset6", "MRCLAM Dataset 6")

#: Parameters of simulated logs (``mc.simulate_logs``) that the calibration must recover.
TRUTH = mc.Calibration(
    correction=CommandCorrection(speed_scale=1.05, turn_slowdown=1.1, turn_scale=0.94),
    command_latency=0.22,
    forward=(2e-5, 0.01, 0.0),
    turn=(5e-5, 0.02, 2e-3),
    lateral=(1e-6, 0.0, 0.0),
    range_slope=0.045,
    range_bounds=(0.06, 0.28),
    sigma_bearing=0.009,
    sensor_latency=0.035,
    robots={1: mc.RobotCalibration(0.008, 0.005, 0.0), 2: mc.RobotCalibration(-0.012, -0.014, 0.0)},
)
