"""Time per step and memory of SEIF, EIF and EKF SLAM as the map grows.

Usage::

    python benchmarks/bench_filters.py                      # n = 50, 200, 1000, 5000
    python benchmarks/bench_filters.py --quick              # n = 50, 200 (smoke test)
    python benchmarks/bench_filters.py --sizes 50,1000 --json results.json

Prints the environment, then a Markdown table with, for each filter and map
size n, the mean and median wall time of one ``predict`` + ``update`` and the
bytes the filter holds (``memory_bytes``), then the ratio SEIF(n_max)/SEIF(n_min)
of time per step and the memory per landmark of each filter.

Scenario: a long landmark corridor
----------------------------------
``n`` landmarks lie along the x axis at a regular spacing (``--spacing``, 2 m;
x jittered by up to a quarter spacing, y alternately left and right of the
centre line at 1 to 3 m; seeded ``numpy.random.Generator``). The range-bearing
sensor sees all around up to ``max_range``, chosen so that about
``--visible`` (8) landmarks are in range wherever the robot is on the
corridor. The robot drives straight along the centre line at a constant
``--stride`` (4) landmark spacings per step, so each step maps about 4 new
landmarks and sees every landmark about twice on the way. A proportional
heading controller, computed from the *true* pose while simulating, keeps the
robot on the centre line against the motion noise; its commands are the
controls the filters receive. Motion and measurement noise are low but not
zero (``VelocityMotionModel`` with small alphas, range sigma 2 cm, bearing
sigma 0.1 deg), so every filter has to correct real errors. As a check that
each filter ran properly the table gives, after the last timed step, the pose
error with the filter's own 1-sigma (position) and the *local map error*: the
RMS error of the landmarks seen in that step, in the robot frame. (Along a
corridor without loop closure the heading error, and with it the whole map's
rotation, slowly drifts, so absolute errors far from the robot grow with the
corridor's length for every filter, EKF included; the local map is what a
working filter keeps accurate, and the script checks it is under 10 cm. The
SEIF's 1-sigma is known to be overconfident: docs/filters/math.md, "Sparsification".) Every
filter gets exactly the same controls and measurements for a given n.

Phases of one (filter, n) run
-----------------------------
1. **Build** (not in the per-step times): drive forward until all ``n``
   landmarks are in the map. Its total wall time is reported separately.
2. **Timed window**: the map now holds exactly ``n`` landmarks. The robot
   drives on *in reverse* (``v < 0``) back along the corridor, and shuttles
   back and forth (forward again, and so on) within the part of the corridor
   where the full ``--visible`` landmarks are in range, for ``--window`` steps
   (1000) or until ``--window-seconds`` (20 s) of timed steps have passed,
   whichever comes first, at least 5 steps. So every timed step sees the same
   number of landmarks (about 8, all already mapped, none added) and the map
   size is exactly n during the whole window: the step cost is measured at
   map size n, not at an average over a growing map. Each step is timed with
   ``time.perf_counter`` around ``predict`` + ``update`` only (the simulation
   is precomputed; the garbage collector is paused during the window).

The numba kernels of the SEIF (and the first scipy calls of EKF/EIF) are
warmed up on a small corridor before anything is timed.

Budgets: never a made-up number
-------------------------------
EKF steps cost O(n^2) and EIF steps O(n^3) (dense Cholesky every update), so
they get slow at n = 5000. Each (filter, n) has a wall-time budget
(``--budget``, 480 s) for build + window. Before a run, its cost is estimated
from the filter's per-step times at the smaller sizes already measured
(per-step time ~ c n^p, p fitted from the last two sizes but at least the
nominal 2 for EKF and 3 for EIF), integrated over the build. The estimate is
rough (the fitted p is inflated where the smaller matrices still fit in the
CPU caches), so a run is skipped only when estimated at over twice the
budget; any other run is started, and aborted if its build passes the budget.
Either way the table says "not run" and a note gives the reason (the estimate,
or how far the build got) and the last measured size and time. Estimates only
decide what to skip; they never appear in the table.

Other work on the machine slows every filter (and the EKF/EIF builds most);
the environment section and the last line print the load average so that a
disturbed run can be recognised.

BLAS threads
------------
The script runs numpy/scipy with one BLAS thread (``--blas-threads 1``, set
through ``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS``
before numpy is imported). The SEIF's compiled kernels are single-threaded, so
this compares the filters' algorithms like for like. It also avoids a
pathology seen on the 2-vCPU development VM: with two OpenBLAS threads, a
rank-16 update of a 10^4 x 10^4 matrix took 2.2 s instead of 0.27 s, and small
EKF steps 10-50x longer than single-threaded. Pass ``--blas-threads 2`` to
measure with threads.

Numbers depend on the machine: compare rows of one run, not runs on different
machines.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path


def _blas_threads_from_argv(argv: list[str]) -> int:
    """``--blas-threads`` must act before numpy loads OpenBLAS, so it is read here first."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--blas-threads", type=int, default=1)
    return pre.parse_known_args(argv)[0].blas_threads


BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
if __name__ == "__main__":
    for _name in BLAS_THREAD_VARS:
        os.environ[_name] = str(_blas_threads_from_argv(sys.argv[1:]))

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seif_gym.slam import EIF, EKF, RangeBearingSensor, VelocityMotionModel  # noqa: E402
from seif_gym.slam.models import wrap_angle  # noqa: E402
from seif_gym.slam.seif import SEIF  # noqa: E402

DT = 1.0
#: low motion noise (Thrun Table 5.3 alphas); with v = 8 m/s: sigma_v = 2.5 cm, sigma_omega = 0.05 deg per step
MOTION_ALPHAS = (1e-5, 1e-5, 1e-8, 1e-5, 1e-8, 1e-5)
SIGMA_RANGE = 0.02
SIGMA_BEARING = math.radians(0.1)
#: y of the landmarks: |y| uniform in this range, alternately left and right
LATERAL_RANGE = (1.0, 3.0)
#: a filter whose local map error (see the module docstring) exceeds this failed the sanity check
LOCAL_MAP_TOLERANCE = 0.10
#: nominal exponent of the per-step time in n, used to estimate a run's cost from one measured size
NOMINAL_EXPONENT = {"SEIF": 0.0, "EIF": 3.0, "EKF": 2.0}
FILTER_ORDER = ("SEIF", "EIF", "EKF")
#: a run is skipped when estimated at more than this times the budget (the estimate is rough); else it is
#: started, and aborted if its build passes the budget
ESTIMATE_SLACK = 2.0


def make_filter(name: str, motion, sensor, pose):
    if name == "SEIF":
        return SEIF(motion, sensor, pose, max_active=8)  # default amortized mean recovery
    if name == "EIF":
        return EIF(motion, sensor, pose)
    if name == "EKF":
        return EKF(motion, sensor, pose)
    raise ValueError(name)


# ---------------------------------------------------------------------------
# Scenario
# ---------------------------------------------------------------------------
@dataclass
class Corridor:
    """A precomputed run: controls and measurements of the build and the window."""

    n: int
    landmarks: np.ndarray
    sensor: RangeBearingSensor
    motion: VelocityMotionModel
    initial_pose: np.ndarray
    build: list  # (control, ranges, bearings, ids) per step
    window: list
    true_pose_build_end: np.ndarray
    true_poses_window: list  # true pose after each window step
    visible_counts_window: np.ndarray


def corridor_landmarks(n: int, spacing: float, rng: np.random.Generator) -> np.ndarray:
    x = spacing * np.arange(n) + rng.uniform(-0.25, 0.25, n) * spacing
    side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    y = side * rng.uniform(*LATERAL_RANGE, n)
    order = np.argsort(x, kind="stable")
    return np.column_stack([x[order], y[order]])


def sensor_range(visible: int, spacing: float) -> float:
    """``max_range`` so that about ``visible`` landmarks lie within it (chord length ``visible * spacing``)."""
    lo, hi = LATERAL_RANGE
    mean_y2 = (hi**3 - lo**3) / (3.0 * (hi - lo))
    return math.sqrt((0.5 * visible * spacing) ** 2 + mean_y2)


def _steer(pose: np.ndarray, v: float) -> float:
    """Turn rate that brings the true robot back to the centre line ``y = 0``, heading 0."""
    # lateral speed v sin(theta): aim for -0.3 y per step
    target = math.asin(max(-0.5, min(0.5, -0.3 * pose[1] / (v * DT))))
    return 0.5 * float(wrap_angle(target - float(pose[2]))) / DT


def _observe(sensor, landmarks, pose, rng):
    """Noisy measurement of the landmarks in range (only those near the robot are tested)."""
    r = sensor.max_range
    lo, hi = np.searchsorted(landmarks[:, 0], [pose[0] - r, pose[0] + r])
    ids = np.arange(lo, hi, dtype=np.int64)
    if hi == lo:
        return np.empty(0), np.empty(0), ids
    return sensor.sample(pose, landmarks[lo:hi], rng, ids=ids)


def make_corridor(n: int, args, window_steps: int, seed: int) -> Corridor:
    rng = np.random.default_rng([seed, n])
    landmarks = corridor_landmarks(n, args.spacing, rng)
    max_range = sensor_range(args.visible, args.spacing)
    sensor = RangeBearingSensor(sigma_range=SIGMA_RANGE, sigma_bearing=SIGMA_BEARING, max_range=max_range)
    motion = VelocityMotionModel(alphas=MOTION_ALPHAS)
    speed = args.stride * args.spacing / DT
    pose = np.array([landmarks[0, 0] - max_range + 0.5 * speed * DT, 0.0, 0.0])
    initial_pose = pose.copy()
    seen = np.zeros(n, dtype=bool)
    build = []
    while not seen.all():
        control = np.array([speed, _steer(pose, speed)])
        pose = motion.sample(pose, control, DT, rng)
        ranges, bearings, ids = _observe(sensor, landmarks, pose, rng)
        seen[ids] = True
        build.append((control, ranges, bearings, ids))
        if len(build) > 10 * n + 100:
            raise RuntimeError("the robot does not reach the end of the corridor")
    pose_build_end = pose.copy()
    # the window: shuttle within the part of the corridor where the full sensor range is covered
    x_min = landmarks[0, 0] + max_range
    x_max = landmarks[-1, 0] - max_range
    if x_max - x_min < 2.0 * speed * DT:  # very short corridor: use all of it
        x_min, x_max = landmarks[0, 0], landmarks[-1, 0]
    direction = -1.0
    window, true_poses, counts = [], [], []
    for _ in range(window_steps):
        step = direction * speed * DT
        if not x_min <= pose[0] + step <= x_max:
            direction = -direction
        v = direction * speed
        control = np.array([v, _steer(pose, v)])
        pose = motion.sample(pose, control, DT, rng)
        ranges, bearings, ids = _observe(sensor, landmarks, pose, rng)
        window.append((control, ranges, bearings, ids))
        true_poses.append(pose.copy())
        counts.append(len(ids))
    return Corridor(
        n=n,
        landmarks=landmarks,
        sensor=sensor,
        motion=motion,
        initial_pose=initial_pose,
        build=build,
        window=window,
        true_pose_build_end=pose_build_end,
        true_poses_window=true_poses,
        visible_counts_window=np.array(counts),
    )


# ---------------------------------------------------------------------------
# Running one (filter, n)
# ---------------------------------------------------------------------------
@dataclass
class Result:
    filter: str
    n: int
    status: str = "ok"  # "ok" or "not run"
    reason: str = ""
    build_steps: int = 0
    build_seconds: float = float("nan")
    window_steps: int = 0
    mean_us: float = float("nan")
    median_us: float = float("nan")
    p90_us: float = float("nan")
    memory_bytes: int = 0
    landmarks_in_map: int = 0
    mean_visible: float = float("nan")
    pose_error_m: float = float("nan")
    heading_error_deg: float = float("nan")
    pose_sigma_m: float = float("nan")
    local_map_rmse_m: float = float("nan")
    step_us: list = field(default_factory=list)


def warm_up(args) -> None:
    """Compile the SEIF kernels and touch the first scipy/numpy paths, untimed."""
    corridor = make_corridor(40, args, window_steps=10, seed=12345)
    for name in FILTER_ORDER:
        filt = make_filter(name, corridor.motion, corridor.sensor, corridor.initial_pose)
        for control, ranges, bearings, ids in corridor.build + corridor.window:
            filt.predict(control, DT)
            filt.update(ranges, bearings, ids)
        _ = filt.pose_covariance


def run_one(name: str, corridor: Corridor, args, budget: float) -> Result:
    result = Result(filter=name, n=corridor.n, build_steps=len(corridor.build))
    filt = make_filter(name, corridor.motion, corridor.sensor, corridor.initial_pose)
    gc.collect()
    start = time.perf_counter()
    for step, (control, ranges, bearings, ids) in enumerate(corridor.build):
        filt.predict(control, DT)
        filt.update(ranges, bearings, ids)
        elapsed = time.perf_counter() - start
        if elapsed > budget:
            result.status = "not run"
            result.reason = (
                f"build aborted: over the {budget:.0f} s budget after {elapsed:.0f} s, at step {step + 1} of "
                f"{len(corridor.build)} with {filt.num_landmarks} of {corridor.n} landmarks mapped"
            )
            result.landmarks_in_map = filt.num_landmarks
            result.memory_bytes = filt.memory_bytes
            return result
    result.build_seconds = time.perf_counter() - start
    assert filt.num_landmarks == corridor.n, (filt.num_landmarks, corridor.n)

    remaining = budget - result.build_seconds
    window_seconds = min(args.window_seconds, max(remaining, 0.0))
    times = []
    gc.collect()
    gc.disable()
    try:
        spent = 0.0
        for control, ranges, bearings, ids in corridor.window:
            t0 = time.perf_counter()
            filt.predict(control, DT)
            filt.update(ranges, bearings, ids)
            t1 = time.perf_counter()
            times.append(t1 - t0)
            spent += t1 - t0
            if len(times) >= args.min_window and spent >= window_seconds:
                break
    finally:
        gc.enable()
    assert filt.num_landmarks == corridor.n

    us = [1e6 * t for t in times]
    result.window_steps = len(us)
    result.mean_us = statistics.fmean(us)
    result.median_us = statistics.median(us)
    result.p90_us = float(np.percentile(us, 90))
    result.step_us = us
    result.memory_bytes = int(filt.memory_bytes)
    result.landmarks_in_map = filt.num_landmarks
    result.mean_visible = float(np.mean(corridor.visible_counts_window[: len(us)]))

    # sanity check of the estimate (untimed)
    true_pose = corridor.true_poses_window[len(us) - 1]
    est = np.asarray(filt.pose)
    result.pose_error_m = float(np.hypot(*(est[:2] - true_pose[:2])))
    result.heading_error_deg = float(np.degrees(abs(wrap_angle(float(est[2] - true_pose[2])))))
    cov = np.asarray(filt.pose_covariance)
    result.pose_sigma_m = float(math.sqrt(max(cov[0, 0] + cov[1, 1], 0.0)))
    # the map drifts as a whole (heading error grows along a corridor with no loop closure), so the map is
    # scored locally: the landmarks seen in the last step, in the robot frame, estimated vs true
    seen = corridor.window[len(us) - 1][3]
    order = np.array([filt.landmark_index(int(i)) for i in seen], dtype=np.int64)
    est_local = _robot_frame(est, np.asarray(filt.landmarks)[order])
    true_local = _robot_frame(true_pose, corridor.landmarks[seen])
    result.local_map_rmse_m = float(np.sqrt(np.mean(np.sum((est_local - true_local) ** 2, axis=1))))
    return result


def _robot_frame(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = points - pose[:2]
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def estimate_seconds(name: str, n: int, done: list[Result], build_steps: int, args) -> tuple[float, str] | None:
    """Estimated build + window time of (name, n) from the smaller sizes measured, or None."""
    measured = sorted((r for r in done if r.filter == name and r.status == "ok"), key=lambda r: r.n)
    if not measured:
        return None
    last = measured[-1]
    exponent = NOMINAL_EXPONENT[name]
    if len(measured) >= 2:
        prev = measured[-2]
        if prev.mean_us > 0 and last.n > prev.n:
            exponent = max(exponent, math.log(last.mean_us / prev.mean_us) / math.log(last.n / prev.n))
    per_step_at_n = 1e-6 * last.mean_us * (n / last.n) ** exponent
    # the map grows about linearly during the build: the mean of (m/n)^p over it is 1/(p + 1)
    build = build_steps * per_step_at_n / (exponent + 1.0)
    window = min(args.window * per_step_at_n, max(args.window_seconds, args.min_window * per_step_at_n))
    text = (
        f"~{build + window:.0f} s estimated from n={last.n} ({last.mean_us:,.0f} us/step) with time ~ n^{exponent:.2f}"
    )
    return build + window, text


# ---------------------------------------------------------------------------
# Output
# ---------------------------------------------------------------------------
def environment() -> dict:
    import numba
    import scipy

    cpu_model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu_model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "cpu_count": os.cpu_count(),
        "usable_cpus": usable,
        "cpu_model": cpu_model or platform.processor(),
        "blas_threads": {name: os.environ.get(name, "(unset)") for name in BLAS_THREAD_VARS},
        "platform": platform.platform(),
        "load_average": _load_average(),
    }


def _load_average() -> str:
    """The 1, 5 and 15 minute load averages: other work on the machine disturbs the timings."""
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


def fmt_bytes(b: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(b) < 1024.0 or unit == "GiB":
            return f"{b:,.0f} {unit}" if unit == "B" else f"{b:,.1f} {unit}"
        b /= 1024.0
    return str(b)


def fmt_us(us: float) -> str:
    if us >= 1e6:
        return f"{us / 1e6:,.2f} s"
    if us >= 1e4:
        return f"{us / 1e3:,.1f} ms"
    return f"{us:,.0f} µs"


def print_table(results: list[Result], sizes: list[int]) -> list[str]:
    notes = []
    print(
        "| filter | n | mean / step | median / step | timed steps | landmarks seen / step | memory_bytes "
        "| memory / landmark | build (total) | final pose error (filter's 1σ) | local map error |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name in FILTER_ORDER:
        for n in sizes:
            r = next(r for r in results if r.filter == name and r.n == n)
            if r.status != "ok":
                notes.append(f"{name} n={n}: not run: {r.reason}")
                print(f"| {name} | {n:,} | not run [{len(notes)}] | | | | | | | | |")
                continue
            print(
                f"| {name} | {n:,} | {fmt_us(r.mean_us)} | {fmt_us(r.median_us)} | {r.window_steps} "
                f"| {r.mean_visible:.1f} | {fmt_bytes(r.memory_bytes)} | {fmt_bytes(r.memory_bytes / n)} "
                f"| {r.build_seconds:,.1f} s / {r.build_steps} steps "
                f"| {100 * r.pose_error_m:.1f} cm ({100 * r.pose_sigma_m:.1f} cm), {r.heading_error_deg:.3f}° "
                f"| {100 * r.local_map_rmse_m:.1f} cm |"
            )
    return notes


def summary(results: list[Result], sizes: list[int]) -> dict:
    ok = {(r.filter, r.n): r for r in results if r.status == "ok"}
    out: dict = {}
    lo, hi = min(sizes), max(sizes)
    seif_lo, seif_hi = ok.get(("SEIF", lo)), ok.get(("SEIF", hi))
    if seif_lo and seif_hi and hi > lo:
        out["seif_ratio_mean"] = seif_hi.mean_us / seif_lo.mean_us
        out["seif_ratio_median"] = seif_hi.median_us / seif_lo.median_us
        out["seif_ratio_sizes"] = [lo, hi]
    for name in FILTER_ORDER:
        runs = sorted((r for r in results if r.filter == name and r.status == "ok"), key=lambda r: r.n)
        if len(runs) >= 2:
            a, b = runs[0], runs[-1]
            out[f"{name}_time_exponent"] = math.log(b.mean_us / a.mean_us) / math.log(b.n / a.n)
            out[f"{name}_memory_exponent"] = math.log(b.memory_bytes / a.memory_bytes) / math.log(b.n / a.n)
            out[f"{name}_exponent_sizes"] = [a.n, b.n]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", default="50,200,1000,5000", help="comma-separated map sizes n (default %(default)s)")
    parser.add_argument("--quick", action="store_true", help="smoke test: sizes 50,200 only")
    parser.add_argument("--json", metavar="OUT.json", help="also write all results (per-step times included) here")
    parser.add_argument("--filters", default="SEIF,EIF,EKF", help="comma-separated subset of SEIF,EIF,EKF")
    parser.add_argument(
        "--blas-threads",
        type=int,
        default=1,
        help="OpenBLAS/OpenMP threads, set before numpy loads (default %(default)s; see the module docstring)",
    )
    parser.add_argument(
        "--budget", type=float, default=480.0, help="wall seconds per (filter, n), build + window (default %(default)s)"
    )
    parser.add_argument(
        "--window", type=int, default=1000, help="most timed steps per (filter, n) (default %(default)s)"
    )
    parser.add_argument(
        "--window-seconds", type=float, default=20.0, help="stop timing after this much step time (default %(default)s)"
    )
    parser.add_argument("--min-window", type=int, default=5, help="fewest timed steps (default %(default)s)")
    parser.add_argument(
        "--spacing", type=float, default=2.0, help="landmark spacing along the corridor, m (default %(default)s)"
    )
    parser.add_argument(
        "--visible", type=float, default=8.0, help="landmarks in sensor range per step (default %(default)s)"
    )
    parser.add_argument(
        "--stride", type=float, default=4.0, help="robot travel per step, in landmark spacings (default %(default)s)"
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    sizes = [50, 200] if args.quick else sorted({int(s) for s in args.sizes.split(",") if s.strip()})
    filters = [f for f in FILTER_ORDER if f in {x.strip().upper() for x in args.filters.split(",")}]
    if not sizes or min(sizes) < 10:
        parser.error("sizes must be at least 10")
    if not filters:
        parser.error("no known filter in --filters")

    wall_start = time.perf_counter()
    env = environment()
    print("## Environment\n")
    for key, value in env.items():
        print(f"- {key}: {value}")
    max_range = sensor_range(args.visible, args.spacing)
    print(
        f"\nCorridor: spacing {args.spacing} m, sensor max_range {max_range:.2f} m (~{args.visible:g} landmarks in range), "
        f"robot {args.stride:g} spacings = {args.stride * args.spacing:g} m per step; "
        f"noise: motion alphas {MOTION_ALPHAS}, range sigma {SIGMA_RANGE} m, bearing sigma {math.degrees(SIGMA_BEARING):g} deg; "
        f"seed {args.seed}. Timed window: reverse/shuttle over the mapped corridor, up to {args.window} steps or "
        f"{args.window_seconds:g} s, budget {args.budget:g} s per (filter, n).\n"
    )
    sys.stdout.flush()

    t0 = time.perf_counter()
    warm_up(args)
    print(f"warm-up (numba JIT / caches): {time.perf_counter() - t0:.1f} s", flush=True)

    results: list[Result] = []
    for n in sizes:
        t0 = time.perf_counter()
        corridor = make_corridor(n, args, args.window, args.seed)
        print(
            f"n={n}: simulated {len(corridor.build)} build + {len(corridor.window)} window steps in "
            f"{time.perf_counter() - t0:.1f} s",
            flush=True,
        )
        for name in filters:
            estimate = estimate_seconds(name, n, results, len(corridor.build), args)
            if estimate is not None and estimate[0] > ESTIMATE_SLACK * args.budget:
                result = Result(filter=name, n=n, status="not run", build_steps=len(corridor.build))
                result.reason = f"{estimate[1]} > {ESTIMATE_SLACK:g} x the budget of {args.budget:.0f} s"
                print(f"  {name:4s} n={n}: not run ({result.reason})", flush=True)
                results.append(result)
                continue
            t0 = time.perf_counter()
            result = run_one(name, corridor, args, args.budget)
            if result.status != "ok":
                last = max(
                    (r for r in results if r.filter == name and r.status == "ok"), key=lambda r: r.n, default=None
                )
                if last is not None:
                    result.reason += f"; last measured: n={last.n}, {fmt_us(last.mean_us)} per step"
            results.append(result)
            if result.status == "ok":
                print(
                    f"  {name:4s} n={n}: mean {fmt_us(result.mean_us)}, median {fmt_us(result.median_us)} "
                    f"({result.window_steps} steps), build {result.build_seconds:.1f} s, "
                    f"{fmt_bytes(result.memory_bytes)}, pose error {100 * result.pose_error_m:.1f} cm "
                    f"(sigma {100 * result.pose_sigma_m:.1f} cm), local map RMSE {100 * result.local_map_rmse_m:.1f} cm "
                    f"[{time.perf_counter() - t0:.1f} s]",
                    flush=True,
                )
            else:
                print(f"  {name:4s} n={n}: not run ({result.reason})", flush=True)
        del corridor
        gc.collect()

    results += [Result(filter=f, n=n, status="not run", reason="not selected (--filters)")
                for f in FILTER_ORDER if f not in filters for n in sizes]  # fmt: skip

    print("\n## Results\n")
    notes = print_table(results, sizes)
    if notes:
        print()
        for k, note in enumerate(notes, 1):
            print(f"[{k}] {note}")
    stats = summary(results, sizes)
    print()
    bad = [f"{r.filter} n={r.n} ({100 * r.local_map_rmse_m:.1f} cm)" for r in results
           if r.status == "ok" and not r.local_map_rmse_m < LOCAL_MAP_TOLERANCE]  # fmt: skip
    if bad:
        print(f"CHECK FAILED: local map error over {100 * LOCAL_MAP_TOLERANCE:.0f} cm: {', '.join(bad)}")
    else:
        print(
            f"Check: every filter that ran keeps its local map within {100 * LOCAL_MAP_TOLERANCE:.0f} cm of the truth."
        )
    if "seif_ratio_mean" in stats:
        lo, hi = stats["seif_ratio_sizes"]
        verdict = "meets" if stats["seif_ratio_mean"] <= 1.3 else "MISSES"
        print(
            f"SEIF time per step, n={hi} / n={lo}: mean {stats['seif_ratio_mean']:.2f}x, "
            f"median {stats['seif_ratio_median']:.2f}x ({verdict} the target <= 1.3x on the mean)"
        )
    for name in FILTER_ORDER:
        if f"{name}_time_exponent" in stats:
            a, b = stats[f"{name}_exponent_sizes"]
            print(
                f"{name}: time per step ~ n^{stats[f'{name}_time_exponent']:.2f}, memory ~ n^{stats[f'{name}_memory_exponent']:.2f} "
                f"(n = {a} to {b})"
            )
    print("\nMemory per landmark (memory_bytes / n; capacity doubling included):")
    for name in FILTER_ORDER:
        cells = [
            f"n={r.n}: {fmt_bytes(r.memory_bytes / r.n)}" for r in results if r.filter == name and r.status == "ok"
        ]
        if cells:
            print(f"- {name}: " + ", ".join(cells))
    wall = time.perf_counter() - wall_start
    print(
        f"\nwall time: {wall:.1f} s; load average at the end: {_load_average()} (at the start: {env['load_average']})"
    )

    if args.json:
        payload = {
            "environment": env,
            "config": {
                **vars(args),
                "sizes": sizes,
                "filters": filters,
                "max_range": max_range,
                "motion_alphas": MOTION_ALPHAS,
                "sigma_range": SIGMA_RANGE,
                "sigma_bearing": SIGMA_BEARING,
                "dt": DT,
            },  # fmt: skip
            "results": [asdict(r) for r in results],
            "summary": stats,
            "notes": notes,
            "wall_seconds": wall,
        }
        Path(args.json).write_text(json.dumps(payload, indent=1, default=float))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
