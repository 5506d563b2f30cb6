"""SEIF vs EKF SLAM on one simulated loop: the first thing to run.

A robot drives a circle of radius 10 m a little more than once
(counter-clockwise, so its heading crosses +-pi and the loop closes on
landmarks mapped at the start). Landmarks lie on a ring around the circle; a
range-bearing sensor sees those within 4 m. The same controls and
measurements are fed to

* a SEIF (``max_active`` from ``--max-active``, amortized mean recovery), and
* EKF SLAM (dense covariance, the exact reference),

and one figure is saved (``--out``):

1. **Map and trajectories.** True path, SEIF and EKF estimated paths, true
   landmarks, and the SEIF landmark estimates with their 95% confidence
   ellipses (chi-square, 2 dof: 5.991). The robot's final estimated pose is
   joined by lines to the SEIF's *active* landmarks, the only landmarks the
   robot is linked to in the information matrix.
2. **SEIF vs EKF uncertainty, zoomed on the end of the run** (where the loop
   closed): the 95% ellipses of both filters for the same landmarks, and of
   the final pose (x, y). Sparsification approximates: the SEIF ellipses can
   be smaller than the EKF's (overconfidence, see docs/filters/math.md, "Sparsification").
3. **Sparsity of the SEIF information matrix** Omega (state order: robot,
   then landmarks in the order first seen, i.e. around the loop). The robot
   rows and columns are shaded: their few entries are the active links. The
   title gives nnz and the fill fraction, against the exact EIF (same data),
   whose Omega is dense.

It also prints a summary: final pose error and map RMSE of each filter, the
map size, the active set, nnz of Omega and the time per filter step.

Usage::

    python examples/seif_demo.py [--out seif_demo.png] [--seed 0] [--steps 400] [--max-active 4]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # small matrices: BLAS threads only add jitter to the timings

import argparse  # noqa: E402
import math  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse, Rectangle  # noqa: E402

from seif_gym.metrics import CHI2_95_2DOF  # noqa: E402
from seif_gym.slam import EIF, EKF, SEIF, RangeBearingSensor, VelocityMotionModel  # noqa: E402
from seif_gym.slam.simulation import (  # noqa: E402
    loop_controls,
    loop_start_pose,
    ring_landmarks,
    run_filter,
    simulate_run,
)

RADIUS, DT, MAX_RANGE, NUM_LANDMARKS = 10.0, 0.1, 4.0, 50
SEIF_COLOR, EKF_COLOR, TRUE_COLOR = "tab:blue", "tab:orange", "black"


def ellipse(mean, cov, color, **kwargs) -> Ellipse:
    """The 95% confidence ellipse of a 2-D Gaussian."""
    values, vectors = np.linalg.eigh(cov)  # ascending: the major axis is the last eigenvector
    minor, major = 2.0 * np.sqrt(CHI2_95_2DOF * np.maximum(values, 0.0))
    angle = math.degrees(math.atan2(vectors[1, 1], vectors[0, 1]))
    return Ellipse(mean, major, minor, angle=angle, fill=False, edgecolor=color, **kwargs)


def map_rmse(filt, true_landmarks) -> float:
    error = filt.landmarks - true_landmarks[filt.landmark_ids]
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def pose_error(est, true) -> tuple[float, float]:
    """Position error (m) and absolute wrapped heading error (deg)."""
    heading = (est[2] - true[2] + math.pi) % (2 * math.pi) - math.pi
    return float(np.hypot(*(est[:2] - true[:2]))), abs(math.degrees(heading))


def plot_map(ax, run, seif, results) -> None:
    """Panel 1: trajectories, landmarks, SEIF ellipses, active links."""
    ax.plot(*run.true_poses[:, :2].T, color=TRUE_COLOR, lw=1.2, label="true path")
    ax.plot(*results["SEIF"]["poses"][:, :2].T, color=SEIF_COLOR, lw=1.0, ls="--", label="SEIF path")
    ax.plot(*results["EKF"]["poses"][:, :2].T, color=EKF_COLOR, lw=1.0, ls=":", label="EKF path")
    ax.scatter(*run.landmarks.T, marker="+", s=40, color=TRUE_COLOR, lw=1, label="true landmarks", zorder=3)
    ax.scatter(*seif.landmarks.T, s=8, color=SEIF_COLOR, label="SEIF landmarks", zorder=3)
    for landmark_id, mean in zip(seif.landmark_ids, seif.landmarks):
        ax.add_patch(ellipse(mean, seif.landmark_covariance(landmark_id), SEIF_COLOR, lw=0.8))
    pose = seif.pose
    active = np.array([seif.landmarks[seif.landmark_index(i)] for i in seif.active_landmarks]).reshape(-1, 2)
    for k, point in enumerate(active):
        ax.plot(
            [pose[0], point[0]], [pose[1], point[1]], color="tab:red", lw=1.0, label="active links" if k == 0 else None
        )
    ax.scatter(*active.T, s=60, facecolors="none", edgecolors="tab:red", lw=1.2, zorder=4)
    ax.plot(
        *pose[:2], marker=(3, 0, math.degrees(pose[2]) - 90), color="tab:red", ms=11, ls="none", label="final SEIF pose"
    )
    ax.plot(*run.true_poses[0, :2], "ks", ms=5, label="start")
    ax.set_title(
        f"Map: SEIF (max_active={seif.max_active}) and EKF; 95% ellipses of SEIF landmarks\n"
        f"red: the {len(active)} active landmarks (all seen in the last step are kept active)"
    )
    ax.set_aspect("equal", adjustable="datalim")  # fill the panel: the limits give way, not the box
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="center", fontsize=8, frameon=False)  # the middle of the ring is empty


def plot_zoom(ax, run, filters, results, centre, half_width: float) -> None:
    """Panel 2: SEIF vs EKF 95% ellipses in a square around ``centre``."""
    for name, color, ls in (("SEIF", SEIF_COLOR, "-"), ("EKF", EKF_COLOR, "--")):
        filt = filters[name]
        ax.plot(*results[name]["poses"][:, :2].T, color=color, lw=0.8, ls=":")
        near = np.max(np.abs(filt.landmarks - centre), axis=1) < 1.2 * half_width
        for landmark_id, mean in zip(filt.landmark_ids[near], filt.landmarks[near]):
            ax.add_patch(ellipse(mean, filt.landmark_covariance(landmark_id), color, lw=1.2, ls=ls))
        ax.add_patch(ellipse(filt.pose[:2], filt.pose_covariance[:2, :2], color, lw=1.6, ls=ls))
        ax.scatter(*filt.landmarks[near].T, s=10, color=color, label=f"{name} estimate + 95% ellipse", zorder=3)
        ax.plot(*filt.pose[:2], marker="o", color=color, ms=4)
    ax.plot(*run.true_poses[:, :2].T, color=TRUE_COLOR, lw=1.0, label="true path")
    ax.scatter(*run.landmarks.T, marker="+", s=60, color=TRUE_COLOR, lw=1.2, label="true landmarks", zorder=4)
    ax.plot(*run.true_poses[-1, :2], "kx", ms=8, mew=2, label="true final pose")
    ax.set_xlim(centre[0] - half_width, centre[0] + half_width)
    ax.set_ylim(centre[1] - half_width, centre[1] + half_width)
    ax.set_aspect("equal")
    ax.set_title("Zoom on the loop closure, 95% ellipses:\nSEIF (solid) vs EKF (dashed); dotted: paths")
    ax.set_xlabel("x (m)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8, frameon=False)


def plot_sparsity(ax, seif, eif) -> None:
    """Panel 3: sparsity pattern of the SEIF information matrix."""
    omega = seif.information_matrix
    size = omega.shape[0]
    fill = omega.nnz / size**2
    eif_fill = eif.information_matrix.nnz / eif.information_matrix.shape[0] ** 2
    ax.spy(omega, markersize=1.2, color="tab:blue")
    ax.add_patch(Rectangle((-0.5, -0.5), size, 3, color="tab:red", alpha=0.15, lw=0))
    ax.add_patch(Rectangle((-0.5, -0.5), 3, size, color="tab:red", alpha=0.15, lw=0))
    ax.add_patch(Rectangle((-0.5, -0.5), 3, 3, fill=False, edgecolor="tab:red", lw=1.5))
    ax.annotate(
        "robot rows/columns (shaded):\nnon-zero only at the active landmarks",
        xy=(0.55 * size, 2),
        xytext=(0.71 * size, 0.24 * size),
        color="tab:red",
        fontsize=8,
        ha="center",
        arrowprops={"arrowstyle": "->", "color": "tab:red"},
    )
    ax.set_title(
        f"SEIF information matrix ({size}x{size})\nnnz = {omega.nnz}, fill = {100 * fill:.0f}%"
        f"  (exact EIF: {100 * eif_fill:.0f}%)"
    )
    ax.set_xlabel("state index (robot, then landmarks in order first seen)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="seif_demo.png", help="output image (default: seif_demo.png)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--steps", type=int, default=400, help="motion steps of 0.1 s, 1.2 turns (default: 400)")
    parser.add_argument("--max-active", type=int, default=4, help="SEIF active-set bound (default: 4)")
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    motion, sensor = VelocityMotionModel(), RangeBearingSensor(max_range=MAX_RANGE)
    landmarks = ring_landmarks(NUM_LANDMARKS, RADIUS - 2.5, RADIUS + 2.5, rng)
    controls = loop_controls(args.steps, DT, RADIUS)
    run = simulate_run(motion, sensor, landmarks, controls, DT, loop_start_pose(RADIUS), rng)

    filters = {
        "SEIF": SEIF(motion, sensor, run.initial_pose, max_active=args.max_active, mean_recovery="amortized"),
        "EKF": EKF(motion, sensor, run.initial_pose),
        "EIF": EIF(motion, sensor, run.initial_pose),  # for the dense fill fraction only
    }
    run_filter(SEIF(motion, sensor, run.initial_pose), run)  # warm up the compiled kernels: not timed below
    results = {name: run_filter(filt, run) for name, filt in filters.items()}
    seif, ekf = filters["SEIF"], filters["EKF"]

    print(
        f"Loop of radius {RADIUS:g} m, {run.steps} steps, {len(landmarks)} landmarks "
        f"({seif.num_landmarks} mapped), ~{run.measurement_counts.mean():.1f} seen per step, seed {args.seed}"
    )
    print(f"{'filter':<22} {'pose err (m)':>12} {'heading (deg)':>13} {'map RMSE (m)':>12} {'ms/step':>8}")
    for name in ("SEIF", "EKF"):
        position, heading = pose_error(filters[name].pose, run.true_poses[-1])
        label = f"SEIF(max_active={args.max_active})" if name == "SEIF" else name
        print(
            f"{label:<22} {position:12.3f} {heading:13.2f} {map_rmse(filters[name], landmarks):12.3f} "
            f"{1e3 * np.median(results[name]['step_seconds']):8.3f}"
        )
    omega = seif.information_matrix
    print(f"SEIF active landmarks ({len(seif.active_landmarks)}): {sorted(seif.active_landmarks.tolist())}")
    print(
        f"SEIF Omega: {omega.shape[0]}x{omega.shape[0]}, nnz {omega.nnz} ({100 * omega.nnz / omega.shape[0] ** 2:.1f}%); "
        f"EIF Omega nnz {filters['EIF'].information_matrix.nnz}"
    )
    exact = seif.exact_mean()[3:].reshape(-1, 2) - landmarks[seif.landmark_ids]
    print(
        f"SEIF map RMSE with the exact mean (Omega^-1 xi) instead of the amortized one: "
        f"{np.sqrt(np.mean(np.sum(exact**2, axis=1))):.3f} m"
    )
    print("(ms/step: median wall time of one predict + update)")

    fig, axes = plt.subplots(1, 3, figsize=(14, 6), layout="constrained", gridspec_kw={"width_ratios": [1.3, 1, 1]})
    plot_map(axes[0], run, seif, results)
    # zoom on the final pose and the active landmarks
    centre = np.mean(np.vstack([run.true_poses[-1, :2], landmarks[seif.active_landmarks]]), axis=0)
    plot_zoom(axes[1], run, {"SEIF": seif, "EKF": ekf}, results, centre, half_width=3.5)
    plot_sparsity(axes[2], seif, filters["EIF"])
    fig.savefig(args.out, dpi=110)
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
