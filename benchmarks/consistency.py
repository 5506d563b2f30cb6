"""Monte-Carlo consistency (pose NEES) of EKF, EIF-equivalent SEIF and sparsified SEIFs.

Usage::

    python benchmarks/consistency.py                    # 50 runs x 200 steps, seed 0
    python benchmarks/consistency.py --runs 10 --steps 100 --json consistency.json

Scenario (the loop of ``examples/seif_demo.py``, sparser and quieter): a robot
drives a circle of radius 10 m 1.2 times in ``--steps`` steps of 0.1 s (so its
heading crosses +-pi and the loop closes); ``--landmarks`` (30) landmarks lie
on a ring between 7.5 and 12.5 m from the centre, redrawn for every run; the
range-bearing sensor (default noise) sees ``--max-range`` (4 m) around, about
3.5 landmarks per step, so that active-set bounds of 2, 4 and 8 differ. The
motion noise is ``--noise-scale`` (0.25) times the ``VelocityMotionModel``
default alphas: with the defaults and 200 steps (3.8 m/s) the EKF itself is
inconsistent from linearization (ANEES ~4.8 with 50 landmarks), which would
blur what sparsification does; at 0.25 the EKF reference is consistent.
Run ``r`` uses ``numpy.random.default_rng([seed, r])`` for its landmarks and
all its noise, and every filter gets exactly the same controls and
measurements of that run.

Filters: EKF SLAM (the exact reference); SEIF without sparsification and with
exact mean recovery (equal to the EKF to round-off, docs/filters/math.md); SEIFs with
``max_active`` 8, 4 and 2 and amortized mean recovery (the default SEIF); and
SEIF(4) and SEIF(8) with exact mean recovery, which separate the effect of
sparsification from that of amortized recovery.

Columns
-------
* **ANEES**: pose NEES ``e^T P^-1 e`` (``e = true - estimate``, heading error
  wrapped), averaged over all runs and steps 1..T. A consistent filter has 3.
* **ANEES last 25%**: the same over the last quarter of the steps (after the
  loop closure).
* **in band**: the fraction of steps whose run-averaged NEES lies in the 95%
  two-sided band ``chi2.ppf([0.025, 0.975], 3 runs) / runs`` (printed above the
  table). A consistent filter has about 95%; an overconfident one falls above.
* **final pos / heading RMSE**: at the last step, root mean square over runs.
* **map RMSE**: root mean square landmark position error over runs and mapped
  landmarks at the last step, with the filter's own mean; *exact mean*: the
  same with ``Omega^-1 xi`` (the SEIF's ``exact_mean()``), i.e. what a fully
  converged amortized recovery would give.
* **sigma ratio**: ``sqrt(trace P_xy / trace P_xy(EKF))`` of the pose position
  covariance, averaged over runs and steps: below 1 means the filter claims
  to be more certain than the exact filter on the same data.
* **ms/step**: median wall time of one predict + update (BLAS pinned to one
  thread; covariance queries not timed).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy is imported: stable timings, no thread contention

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from seif_gym.metrics import pose_nees  # noqa: E402
from seif_gym.slam import EKF, SEIF, RangeBearingSensor, VelocityMotionModel  # noqa: E402
from seif_gym.slam.simulation import (  # noqa: E402
    loop_controls,
    loop_start_pose,
    ring_landmarks,
    run_filter,
    simulate_run,
)

RADIUS, DT = 10.0, 0.1
DEFAULT_ALPHAS = VelocityMotionModel().alphas

#: (label, filter class, options); the first is the reference of "sigma ratio".
FILTERS = [
    ("EKF", EKF, {}),
    ("SEIF(max_active=None, exact)", SEIF, {"max_active": None, "mean_recovery": "exact"}),
    ("SEIF(max_active=8)", SEIF, {"max_active": 8}),
    ("SEIF(max_active=4)", SEIF, {"max_active": 4}),
    ("SEIF(max_active=2)", SEIF, {"max_active": 2}),
    ("SEIF(max_active=4, exact)", SEIF, {"max_active": 4, "mean_recovery": "exact"}),
    ("SEIF(max_active=8, exact)", SEIF, {"max_active": 8, "mean_recovery": "exact"}),
]


def make_run(seed: int, index: int, steps: int, num_landmarks: int, motion, sensor):
    rng = np.random.default_rng([seed, index])
    landmarks = ring_landmarks(num_landmarks, RADIUS - 2.5, RADIUS + 2.5, rng)
    return simulate_run(motion, sensor, landmarks, loop_controls(steps, DT, RADIUS), DT, loop_start_pose(RADIUS), rng)


def landmark_errors(filt, run) -> tuple[np.ndarray, np.ndarray]:
    """Squared landmark position errors with the filter's mean and with the exact mean."""
    truth = run.landmarks[filt.landmark_ids]
    own = np.sum((filt.landmarks - truth) ** 2, axis=1)
    if isinstance(filt, SEIF):
        exact = np.sum((filt.exact_mean()[3:].reshape(-1, 2) - truth) ** 2, axis=1)
    else:
        exact = own
    return own, exact


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=50, help="Monte-Carlo runs (default 50)")
    parser.add_argument("--steps", type=int, default=200, help="steps per run (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    parser.add_argument("--landmarks", type=int, default=30, help="landmarks per run (default 30)")
    parser.add_argument("--max-range", type=float, default=4.0, help="sensor range, m (default 4)")
    parser.add_argument("--noise-scale", type=float, default=0.25, help="motion noise alphas x this (default 0.25)")
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON")
    args = parser.parse_args()
    if min(args.runs, args.steps, args.landmarks) < 1 or args.max_range <= 0 or args.noise_scale <= 0:
        parser.error("--runs, --steps, --landmarks, --max-range and --noise-scale must be positive")

    start_wall = time.perf_counter()
    motion = VelocityMotionModel(alphas=tuple(args.noise_scale * a for a in DEFAULT_ALPHAS))
    sensor = RangeBearingSensor(max_range=args.max_range)
    warm = make_run(args.seed + 1_000_003, 0, 20, args.landmarks, motion, sensor)
    for _, cls, options in FILTERS:  # compile the numba kernels / first scipy calls outside the timings
        run_filter(cls(motion, sensor, warm.initial_pose, **options), warm)

    labels = [label for label, _, _ in FILTERS]
    nees = {label: np.empty((args.runs, args.steps)) for label in labels}
    position_var = {label: np.empty((args.runs, args.steps)) for label in labels}
    final_pos_sq = {label: np.empty(args.runs) for label in labels}
    final_heading_sq = {label: np.empty(args.runs) for label in labels}
    map_sq: dict[str, list[np.ndarray]] = {label: [] for label in labels}
    map_exact_sq: dict[str, list[np.ndarray]] = {label: [] for label in labels}
    step_seconds: dict[str, list[np.ndarray]] = {label: [] for label in labels}
    max_pose_gap = 0.0  # SEIF(None, exact) vs EKF
    seen = []
    for r in range(args.runs):
        run = make_run(args.seed, r, args.steps, args.landmarks, motion, sensor)
        seen.append(run.measurement_counts.mean())
        poses = {}
        for label, cls, options in FILTERS:
            filt = cls(motion, sensor, run.initial_pose, **options)
            result = run_filter(filt, run)
            poses[label] = result["poses"]
            truth, est, cov = run.true_poses[1:], result["poses"][1:], result["pose_covariances"][1:]
            nees[label][r] = pose_nees(truth, est, cov)
            position_var[label][r] = np.trace(cov[:, :2, :2], axis1=1, axis2=2)
            error = run.true_poses[-1] - result["poses"][-1]
            final_pos_sq[label][r] = error[0] ** 2 + error[1] ** 2
            final_heading_sq[label][r] = float((error[2] + np.pi) % (2 * np.pi) - np.pi) ** 2
            own, exact = landmark_errors(filt, run)
            map_sq[label].append(own)
            map_exact_sq[label].append(exact)
            step_seconds[label].append(result["step_seconds"])
        gap = poses["SEIF(max_active=None, exact)"] - poses["EKF"]
        gap[:, 2] = (gap[:, 2] + np.pi) % (2 * np.pi) - np.pi
        max_pose_gap = max(max_pose_gap, float(np.max(np.abs(gap))))

    low, high = chi2.ppf([0.025, 0.975], 3 * args.runs) / args.runs
    rows = []
    for label in labels:
        averaged = nees[label].mean(axis=0)  # run-averaged NEES per step
        rows.append(
            {
                "filter": label,
                "anees": float(nees[label].mean()),
                "anees_last_quarter": float(nees[label][:, -max(1, args.steps // 4) :].mean()),
                "in_band": float(np.mean((averaged >= low) & (averaged <= high))),
                "above_band": float(np.mean(averaged > high)),
                "final_position_rmse": float(np.sqrt(final_pos_sq[label].mean())),
                "final_heading_rmse_deg": float(np.degrees(np.sqrt(final_heading_sq[label].mean()))),
                "map_rmse": float(np.sqrt(np.concatenate(map_sq[label]).mean())),
                "map_rmse_exact_mean": float(np.sqrt(np.concatenate(map_exact_sq[label]).mean())),
                "sigma_ratio": float(np.mean(np.sqrt(position_var[label] / position_var["EKF"]))),
                "ms_per_step": float(1e3 * np.median(np.concatenate(step_seconds[label]))),
            }
        )
    wall = time.perf_counter() - start_wall

    print(f"# Pose NEES consistency: {args.runs} runs x {args.steps} steps, seed {args.seed}")
    print()
    print(
        f"Loop of radius {RADIUS:g} m driven 1.2 times, {args.landmarks} landmarks per run, sensor range "
        f"{args.max_range:g} m ({np.mean(seen):.1f} seen per step on average), motion noise "
        f"{args.noise_scale:g} x default alphas. Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}, {platform.machine()}."
    )
    print(
        f"95% band of the run-averaged NEES per step (chi2, {3 * args.runs} dof, / {args.runs}): "
        f"[{low:.3f}, {high:.3f}]; a consistent filter has ANEES 3 and ~95% of steps in the band."
    )
    print()
    print(
        "| filter | ANEES | ANEES last 25% | in band | above band | final pos RMSE (m) | final heading RMSE (deg) "
        "| map RMSE (m) | map RMSE, exact mean (m) | sigma ratio vs EKF | ms/step |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        print(
            f"| {row['filter']} | {row['anees']:.2f} | {row['anees_last_quarter']:.2f} | {100 * row['in_band']:.0f}% | {100 * row['above_band']:.0f}% "
            f"| {row['final_position_rmse']:.3f} | {row['final_heading_rmse_deg']:.2f} | {row['map_rmse']:.3f} "
            f"| {row['map_rmse_exact_mean']:.3f} | {row['sigma_ratio']:.2f} | {row['ms_per_step']:.3f} |"
        )
    print()
    print(f"SEIF(max_active=None, exact) vs EKF: max |pose difference| over all runs and steps = {max_pose_gap:.2e}")
    print(f"Wall time {wall:.0f} s.")

    if args.json:
        payload = {
            "runs": args.runs, "steps": args.steps, "seed": args.seed, "landmarks": args.landmarks,
            "max_range": args.max_range, "noise_scale": args.noise_scale, "band": [float(low), float(high)],
            "max_pose_gap_eif_ekf": max_pose_gap, "wall_seconds": wall, "argv": sys.argv[1:], "rows": rows,
        }  # fmt: skip
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(payload, handle, indent=2)


if __name__ == "__main__":
    main()
