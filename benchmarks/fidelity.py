"""Fidelity of the approximate filters: SEIF and ESEIF against the EKF on loop-closing runs.

Usage::

    python benchmarks/fidelity.py                              # 6 scenarios x 3 seeds, k = 4, 8, 16
    python benchmarks/fidelity.py --seeds 5 --ks 8 --json fidelity.json --markdown fidelity.md

Runs: the family :data:`seif_gym.slam.scenarios.FIDELITY_SCENARIOS` (a circle,
a rounded rectangle and a figure eight, each with a dense landmark field and an
all-round sensor, and once sparse or with a narrow field of view; a robot
drives a little more than one lap, drift builds up, the loop closes). Seed
``s`` of a scenario is ``make_loop_run(scenario, s)``; every filter gets the
same controls and measurements (known correspondences).

Filters, for each ``k`` of ``--ks``:

* ``EKF``: the exact reference (independent of ``k``);
* ``SEIF``: the default SEIF (wavefront mean recovery);
* ``SEIF amortized``: Thrun's round-robin recovery (what ``SeifExplore-v0`` runs);
* ``SEIF exact mean``: ``mean_recovery="exact"`` (a sparse solve every update);
* ``ESEIF``: the default ESEIF; ``ESEIF amortized`` and ``ESEIF exact mean`` likewise.

Columns (means over all runs):

* **map RMSE**: root mean square landmark error at the end of the run, per
  run, then averaged; **× EKF**: that average over the EKF's.
* **to EKF map**: RMS distance of the filter's final landmark estimates from
  the EKF's on the same data: fidelity itself, without the drift that
  both share (absolute errors vary from run to run far more than this does).
* **pose RMSE**: position error over all steps of a run, root mean square.
* **ANEES**: pose NEES with the filter's own ``pose_covariance`` (the exact
  marginal of its information matrix), averaged over steps and runs; 3 is
  consistent, the 95% band of the average over ``R`` runs and ``T`` steps is
  far narrower than the per-step one (printed).
* **lag**: RMS distance between the filter's landmark means and its own
  ``Omega^-1 xi`` at the end (how far mean recovery is behind).
* **µs/step**: median wall time of one ``predict`` + ``update``.

Where each filter loses accuracy is read off the rows: *recovery lag* is
``SEIF`` against ``SEIF exact mean``; *sparsification* is ``SEIF exact mean``
against the EKF; the ESEIF's *relocalization* is ``ESEIF exact mean`` against
the EKF (its relocalizations, the measurements it withholds, splits and
discards are counted per run).
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
from concurrent.futures import ProcessPoolExecutor  # noqa: E402

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from seif_gym.metrics import pose_nees  # noqa: E402
from seif_gym.slam import EKF, ESEIF, SEIF  # noqa: E402
from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run  # noqa: E402

#: (label, class, options); ``max_active`` is added per k (not for the EKF).
FILTERS = [
    ("EKF", EKF, {}),
    ("SEIF", SEIF, {}),
    ("SEIF amortized", SEIF, {"mean_recovery": "amortized"}),
    ("SEIF exact mean", SEIF, {"mean_recovery": "exact"}),
    ("ESEIF", ESEIF, {}),
    ("ESEIF amortized", ESEIF, {"mean_recovery": "amortized"}),
    ("ESEIF exact mean", ESEIF, {"mean_recovery": "exact"}),
]


def score_run(
    filt, run, reference: dict[int, np.ndarray] | None = None
) -> tuple[dict[str, float], dict[int, np.ndarray]]:
    """Feed ``run`` through ``filt``; its metrics (map RMSE, pose RMSE, ANEES, lag, time per step) and final map.

    ``reference``: the EKF's final landmark estimates by id, for the distance to the EKF's map.
    """
    steps = run.steps
    nees = np.empty(steps)
    position_errors = np.empty(steps)
    seconds = np.empty(steps)
    for t in range(steps):
        started = time.perf_counter()
        filt.predict_trusted(run.controls[t], run.dt)
        filt.update_trusted(run.ranges[t], run.bearings[t], run.ids[t])
        seconds[t] = time.perf_counter() - started
        pose = filt.pose
        truth = run.true_poses[t + 1]
        position_errors[t] = np.hypot(*(truth[:2] - pose[:2]))
        nees[t] = pose_nees(truth, pose, filt.pose_covariance)
    ids = np.asarray(filt.landmark_ids)
    estimates = np.asarray(filt.landmarks)
    result = {
        "map_rmse": float(np.sqrt(np.mean(np.sum((estimates - run.landmarks[ids]) ** 2, axis=1)))),
        "pose_rmse": float(np.sqrt(np.mean(position_errors**2))),
        "anees": float(np.mean(nees)),
        "us_per_step": float(np.median(seconds) * 1e6),
        "landmarks": len(ids),
        "steps": steps,
    }
    if reference is not None:
        against = np.array([reference[int(i)] for i in ids])
        result["to_ekf"] = float(np.sqrt(np.mean(np.sum((estimates - against) ** 2, axis=1))))
    exact_mean = getattr(filt, "exact_mean", None)
    if exact_mean is not None:
        exact = exact_mean()[3:].reshape(-1, 2)
        result["lag"] = float(np.sqrt(np.mean(np.sum((exact - estimates) ** 2, axis=1))))
    for counter in ("relocalizations", "split_relocalizations", "discarded_measurements"):
        if hasattr(filt, counter):
            result[counter] = int(getattr(filt, counter))
    return result, {int(i): estimates[k] for k, i in enumerate(ids)}


def run_job(job: tuple[str, int, tuple[int, ...]]) -> tuple[str, int, dict[str, dict[str, float]]]:
    """All filters and every k on one run (one process)."""
    name, seed, ks = job
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS[name], seed)
    out: dict[str, dict[str, float]] = {}
    reference = None
    for label, cls, options in FILTERS:  # the EKF first: it is the reference of "to EKF"
        for k in ks if cls is not EKF else (None,):
            filt_options = dict(options) if cls is EKF else {**options, "max_active": k}
            key = label if cls is EKF else f"{label} k={k}"
            out[key], final_map = score_run(cls(motion, sensor, run.initial_pose, **filt_options), run, reference)
            if cls is EKF:
                reference = final_map
    return name, seed, out


def summarize(results: list[tuple[str, int, dict]], ks: tuple[int, ...]) -> list[dict[str, float | str]]:
    """One row per filter and k: means over all runs, and the ratio of map RMSE to the EKF's."""
    keys = list(results[0][2])
    ekf_map = float(np.mean([r[2]["EKF"]["map_rmse"] for r in results]))
    rows = []
    for key in keys:
        values = [r[2][key] for r in results]
        row: dict[str, float | str] = {"filter": key}
        for metric in {metric for v in values for metric in v}:
            row[metric] = float(np.mean([v[metric] for v in values if metric in v]))
        row["map_vs_ekf"] = float(row["map_rmse"]) / ekf_map
        rows.append(row)
    return rows


def markdown_table(rows: list[dict], runs: int, steps: int) -> str:
    low, high = chi2.ppf([0.025, 0.975], 3 * runs * steps) / (runs * steps)
    lines = [
        "| filter | map RMSE (m) | × EKF | to EKF map (m) | pose RMSE (m) | ANEES | lag (m) | µs/step | relocalizations (split, discarded) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lag = f"{row['lag']:.3f}" if "lag" in row else "–"
        to_ekf = f"{row['to_ekf']:.3f}" if "to_ekf" in row else "–"
        relocations = (
            f"{row['relocalizations']:.0f} ({row['split_relocalizations']:.1f}, {row['discarded_measurements']:.1f})"
            if "relocalizations" in row
            else "–"
        )
        lines.append(
            f"| {row['filter']} | {row['map_rmse']:.3f} | {row['map_vs_ekf']:.2f} | {to_ekf} | {row['pose_rmse']:.3f} "
            f"| {row['anees']:.2f} | {lag} | {row['us_per_step']:.0f} | {relocations} |"
        )
    lines.append("")
    lines.append(f"{runs} runs; ANEES band (95%, independent steps assumed, so only a guide): [{low:.2f}, {high:.2f}]")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=3, help="runs per scenario (seeds 0..N-1)")
    parser.add_argument("--ks", type=int, nargs="+", default=[4, 8, 16], help="active-set bounds k")
    parser.add_argument("--scenarios", nargs="+", default=list(FIDELITY_SCENARIOS), choices=list(FIDELITY_SCENARIOS))
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="worker processes")
    parser.add_argument("--json", help="write the per-run results and the summary here")
    parser.add_argument("--markdown", help="write the summary table here")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.jobs < 1 or any(k < 2 for k in args.ks):
        parser.error("--seeds and --jobs must be positive and every k at least 2")
    ks = tuple(args.ks)
    jobs = [(name, seed, ks) for name in args.scenarios for seed in range(args.seeds)]
    started = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_job, jobs))
    elapsed = time.perf_counter() - started
    rows = summarize(results, ks)
    table = markdown_table(rows, len(results), int(rows[0]["steps"]))  # the mean steps of a run
    print(f"# Fidelity: {len(args.scenarios)} scenarios x {args.seeds} seeds, k = {', '.join(map(str, ks))} "
          f"({elapsed:.0f} s, {args.jobs} jobs, Python {platform.python_version()})")  # fmt: skip
    print(table)
    if args.markdown:
        with open(args.markdown, "w") as handle:
            handle.write(table + "\n")
    if args.json:
        with open(args.json, "w") as handle:
            json.dump({"command": " ".join(sys.argv), "summary": rows,
                       "runs": [{"scenario": n, "seed": s, "filters": r} for n, s, r in results]}, handle, indent=1)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
