"""Data association with unknown correspondences on the loop-closing runs.

Usage::

    python benchmarks/association.py --seeds 3 --filters ekf,seif      # all scenarios x seeds 0..2
    python benchmarks/association.py --first-seed 3 --seeds 6          # seeds 3..8: runs the design never saw
    python benchmarks/association.py --preset likelihood --first-seed 9 --seeds 6   # a preset of Associator

Runs :data:`seif_gym.slam.scenarios.FIDELITY_SCENARIOS` (seed ``s`` of a
scenario is ``make_loop_run(scenario, s)``) with the correspondences hidden:
each scan goes through an :class:`~seif_gym.slam.association.Associator` of
``--preset`` (default ``"joint"``, ``Associator()``) and ``--options``
(``make_associator(...).update(filt, ranges, bearings)``), and
:class:`~seif_gym.slam.association.AssociationAudit` scores every decision
against the true ids. Filters: ``EKF(motion, sensor, pose)``,
``SEIF(motion, sensor, pose, max_active=8)`` and ``ESEIF(..., max_active=8)``,
all with their default options.

Columns (per scenario and filter, over the seeds):

* **correct %**: measurements given the filter landmark created for their
  true landmark, or starting a new landmark when their true landmark had none
  (a discarded measurement is not correct);
* **dup %**: landmarks created for a true landmark that already had one, over
  the true landmarks measured;
* **disc %**: measurements discarded (id -1);
* **pose err m**: position error at the end of the run (after the loop closed), mean;
* **ms/scan**: mean wall time of ``Associator.associate`` per scan (the
  filter's own update excluded), and its maximum (the compiled kernels are
  compiled before the first run, so no compilation is timed).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy is imported: stable timings, no thread contention

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402

import numpy as np  # noqa: E402

from seif_gym.slam import EKF, ESEIF, SEIF  # noqa: E402
from seif_gym.slam.association import ASSOCIATOR_PRESETS, AssociationAudit, jcbb, make_associator  # noqa: E402
from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run  # noqa: E402

#: filter name -> (class, options)
FILTERS = {"ekf": (EKF, {}), "seif": (SEIF, {"max_active": 8}), "eseif": (ESEIF, {"max_active": 8})}


def parse_options(text: str) -> dict[str, object]:
    """``"a=1,b=true"`` -> ``{"a": 1, "b": True}`` (Associator keyword arguments)."""
    options: dict[str, object] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, _, value = item.partition("=")
        lowered = value.strip().lower()
        if lowered in ("true", "false"):
            options[key.strip()] = lowered == "true"
        else:
            try:
                number = float(value)
            except ValueError:  # a word: a string option (e.g. joint_objective=likelihood)
                options[key.strip()] = value.strip()
                continue
            options[key.strip()] = int(number) if number.is_integer() and "." not in value else number
    return options


def run_one(
    scenario_name: str, seed: int, filter_name: str, options: dict | None = None, max_active: int | None = None
) -> dict[str, float]:
    """One run with unknown correspondences; the audit's counts and timings.

    ``max_active`` overrides the SEIF's and ESEIF's ``k`` (8 by default).
    """
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS[scenario_name], seed)
    cls, filter_options = FILTERS[filter_name]
    if max_active is not None and "max_active" in filter_options:
        filter_options = {**filter_options, "max_active": max_active}
    filt = cls(motion, sensor, run.initial_pose, **filter_options)
    associator = make_associator(**(options or {}))
    audit = AssociationAudit()
    times = []
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        ranges, bearings = run.ranges[t], run.bearings[t]
        start = time.perf_counter()
        ids = associator.associate(filt, ranges, bearings)
        times.append(time.perf_counter() - start)
        keep = ids >= 0
        filt.update(ranges[keep], bearings[keep], ids[keep])
        audit.record(associator, ids, run.ids[t])
    error = float(np.hypot(*(filt.pose[:2] - run.true_poses[-1][:2])))
    return {
        "agree": audit.agree, "total": audit.total, "discarded": audit.discarded,
        "duplicates": audit.duplicates, "true_landmarks": audit.true_landmarks,
        "started": audit.duplicates_started, "merged": audit.merges_right, "wrong_merges": audit.merges_wrong,
        "pose_error": error, "seconds": float(np.sum(times[1:])), "scans": len(times) - 1,
        "max_seconds": float(np.max(times[1:])),
    }  # fmt: skip


def warm_up() -> None:
    """Compile the branch and bound's kernels (both objectives) before any scan is timed."""
    nu, cov = np.zeros((2, 2)), np.eye(4)
    pair_meas, pair_landmark = np.array([0, 1]), np.array([0, 1])
    jcbb(nu, cov, pair_meas, pair_landmark)
    jcbb(nu, cov, pair_meas, pair_landmark, gains=np.zeros(2), noise_logdet=0.0)


def _run(args: tuple) -> tuple[tuple[str, int, str], dict[str, float]]:
    return args[:3], run_one(*args)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds per scenario (default 3)")
    parser.add_argument(
        "--first-seed",
        type=int,
        default=0,
        help="the first seed (default 0: seeds 0..N-1; the design used 0..2, so fresh runs start at 3)",
    )
    parser.add_argument("--filters", default="ekf,seif", help="comma-separated, of " + ", ".join(FILTERS))
    parser.add_argument("--scenarios", default=",".join(FIDELITY_SCENARIOS), help="comma-separated scenario names")
    parser.add_argument("--preset", default="joint", choices=sorted(ASSOCIATOR_PRESETS),
                        help="the Associator preset (default joint: Associator()); --options override it")  # fmt: skip
    parser.add_argument("--options", default="", help="Associator keyword arguments, e.g. landmark_density=0.5")
    parser.add_argument("--max-active", type=int, default=None, help="k of the SEIF and ESEIF (default 8)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes")
    args = parser.parse_args(argv)
    filters = [f.strip().lower() for f in args.filters.split(",") if f.strip()]
    scenarios = [s.strip() for s in args.scenarios.split(",") if s.strip()]
    for name in filters:
        if name not in FILTERS:
            parser.error(f"--filters: unknown filter {name!r} (choose from {', '.join(FILTERS)})")
    for name in scenarios:
        if name not in FIDELITY_SCENARIOS:
            parser.error(f"--scenarios: unknown scenario {name!r}")
    if args.seeds < 1:
        parser.error("--seeds must be at least 1")
    if args.first_seed < 0:
        parser.error("--first-seed must be non-negative")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    options = {**ASSOCIATOR_PRESETS[args.preset], **parse_options(args.options)}
    make_associator(**options)  # bad options fail here, before the workers start
    if args.max_active is not None and args.max_active < 1:
        parser.error("--max-active must be at least 1")
    jobs = [(s, seed, f, options, args.max_active) for s in scenarios for f in filters for seed in seeds]
    started = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs, initializer=warm_up) as pool:
            results = dict(pool.map(_run, jobs))
    else:
        warm_up()
        results = dict(map(_run, jobs))
    print(f"# {' '.join([sys.executable.split('/')[-1], *sys.argv])}")
    print(f"# seeds {seeds[0]}..{seeds[-1]}; {time.perf_counter() - started:.0f} s")
    header = f"{'scenario':18s} {'filter':6s} {'correct %':>9s} {'dup %':>6s} {'disc %':>6s} {'pose err m':>10s} " \
             f"{'ms/scan':>7s} {'max ms':>7s} {'started':>7s} {'merged':>6s} {'wrong':>5s}"  # fmt: skip
    print(header)
    print("-" * len(header))

    def line(label: str, name: str, rows: list[dict[str, float]]) -> None:
        s = {k: sum(r[k] for r in rows) for k in rows[0]}
        print(
            f"{label:18s} {name:6s} {100 * s['agree'] / s['total']:9.2f} "
            f"{100 * s['duplicates'] / s['true_landmarks']:6.2f} {100 * s['discarded'] / s['total']:6.2f} "
            f"{s['pose_error'] / len(rows):10.2f} {1e3 * s['seconds'] / s['scans']:7.2f} "
            f"{1e3 * max(r['max_seconds'] for r in rows):7.1f} {s['started']:7.0f} {s['merged']:6.0f} "
            f"{s['wrong_merges']:5.0f}"
        )

    for scenario in scenarios:
        for name in filters:
            line(scenario, name, [results[(scenario, seed, name)] for seed in seeds])
    print("-" * len(header))
    for name in filters:
        line("all", name, [results[(s, seed, name)] for s in scenarios for seed in seeds])
    return 0


if __name__ == "__main__":
    sys.exit(main())
