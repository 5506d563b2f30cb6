"""How SeifExploreMRCLAM-v0's readings compare with the real logs': the EKF's innovations on both.

    python benchmarks/mrclam_sim_vs_real.py [--data DIR] [--episodes 5]

(``--data``: an MRCLAM Dataset 6 folder; default ``$SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6``;
without data, only the simulated rows are printed.)

The same filter (the EKF, with the calibrated models and *no* noise
inflation, every reading used, no gate) runs over

* the five robots' real logs as episodes
  (``seif_gym.datasets.mrclam.episodes.log_to_episode``, ``noise_inflation=1``,
  ``min_interval=0``, ``innovation_gate=None``), and
* episodes of ``SeifExploreMRCLAM-v0`` driven by the ``frontier`` baseline
  (seeds 0 .. N-1, full length),

and the squared Mahalanobis distances of the innovations of the mapped
landmarks' readings (``filter.last_mahalanobis``, reported by a gate of
infinity, which rejects nothing) are pooled and summarised. For white
Gaussian errors and a consistent filter they are chi-square with 2 degrees of
freedom: mean 2, median 1.39, 95th percentile 5.99, 99th 9.21.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import gymnasium as gym
import numpy as np

import seif_gym  # noqa: F401  (registers the envs)
from agents.evaluate import build_agent
from agents.robustness import record_episode
from seif_gym.episodes import Episode, EpisodeRecorder, replay

QUANTILES = (0.5, 0.9, 0.95, 0.99)


def innovations(episode: Episode) -> np.ndarray:
    """The EKF's squared Mahalanobis distances over the episode (nothing rejected)."""
    found: list[np.ndarray] = []

    def collect(t: int, filt) -> None:
        d2 = np.array(filt.last_mahalanobis, dtype=np.float64)
        found.append(d2[np.isfinite(d2)])  # NaN: a reading that started a landmark

    replay(episode, "ekf", innovation_gate=math.inf, callback=collect)
    return np.concatenate(found) if found else np.empty(0)


def summary(label: str, d2: np.ndarray) -> str:
    q = np.quantile(d2, QUANTILES) if len(d2) else [math.nan] * len(QUANTILES)
    beyond = float(np.mean(d2 > 13.8)) if len(d2) else math.nan
    return (f"| {label} | {len(d2)} | {np.mean(d2):.2f} | " + " | ".join(f"{v:.2f}" for v in q)
            + f" | {100 * beyond:.1f}% |")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=None,
                        help="MRCLAM Dataset 6 folder (default: $SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6)")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=5, help="simulated episodes (default 5)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    print("| data | readings | mean d² | median | 90% | 95% | 99% | beyond 13.8 |")
    print("|---|--:|--:|--:|--:|--:|--:|--:|")
    print("| χ²₂ (white errors, consistent filter) | | 2.00 | 1.39 | 4.61 | 5.99 | 9.21 | 0.1% |")
    from seif_gym.datasets import DataNotFoundError, mrclam
    from seif_gym.datasets.mrclam.calibration import DATASET6, Calibration
    from seif_gym.datasets.mrclam.episodes import EpisodeConversion, log_to_episode

    try:
        logs = mrclam.load_all(args.data)
    except DataNotFoundError as error:
        print(f"(no real data: {error})", file=sys.stderr)
    else:
        calibration = Calibration.load(DATASET6)
        plain = EpisodeConversion(noise_inflation=1.0, min_interval=0.0, innovation_gate=None, filter="ekf")
        real = np.concatenate([innovations(log_to_episode(log, calibration, plain)) for log in logs.values()])
        print(summary("real logs, 5 robots", real))
    simulated = []
    for seed in range(args.episodes):
        env = EpisodeRecorder(gym.make("SeifExploreMRCLAM-v0"))
        agent = build_agent("frontier", env, "SeifExploreMRCLAM-v0", {}, 0)
        simulated.append(innovations(record_episode(env, agent, seed)))
        env.close()
    print(summary(f"SeifExploreMRCLAM-v0, frontier, {args.episodes} episodes", np.concatenate(simulated)))
    print(f"\n{time.perf_counter() - started:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
