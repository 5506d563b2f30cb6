"""Frames of :class:`~seif_gym.envs.explore.SeifExploreEnv`.

One frame (:data:`FRAME_SHAPE`, RGB ``uint8``) shows, in the arena:

* the walls, and the sensor's footprint at the true pose (a wedge of radius
  ``max_range`` and opening ``fov``, clipped to the arena);
* the true trajectory (a broad grey line), the true robot (a black
  outline) and the true landmarks (black crosses);
* the estimated trajectory, the estimated robot with the 95% ellipse of its
  position, the estimated landmarks and their 95% ellipses (blue);
* the SEIF's *active links*: lines from the estimated robot to its active
  landmarks, which are ringed (red); filters without ``active_landmarks``
  (EKF, EIF) have none;

and beside it the step, the map error, the mapped landmarks and the pose
error, and, for filters with an ``information_matrix`` (SEIF, EIF), the
sparsity pattern of the information matrix with its number of non-zeros
(robot rows and columns in red).

Drawing uses matplotlib's object API on an Agg canvas (``Figure`` +
``FigureCanvasAgg``): no pyplot state and no change of the global backend,
so ``rgb_array`` rendering needs no display. The figure and its static parts
(walls, legend, axes) are rendered once and cached; each frame updates the
moving artists in place and draws them over the cached background (blitting).
``human=True`` shows the same frames in a pyplot window
(interactive mode); pyplot is imported only then.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import EllipseCollection, LineCollection
from matplotlib.colors import ListedColormap, to_rgba
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Ellipse, Patch, Polygon, Rectangle, Wedge
from numpy.typing import ArrayLike, NDArray

from seif_gym.metrics import CHI2_95_2DOF as _CHI2_95_2DOF
from seif_gym.slam.base import InformationForm, SparseInformationForm

if TYPE_CHECKING:  # pragma: no cover
    import scipy.sparse

    from seif_gym.envs.explore import SeifExploreEnv
    from seif_gym.slam.base import SlamFilter
    from seif_gym.slam.models import RangeBearingSensor

__all__ = ["FRAME_SHAPE", "CHI2_95_2DOF", "Renderer", "ellipse_parameters"]

#: (height, width, channels) of every frame.
FRAME_SHAPE = (600, 600, 3)
#: 95% quantile of the chi-square distribution with 2 degrees of freedom (the exact value, as the
#: observation's ellipses; its home is :mod:`seif_gym.metrics`, re-exported here).
CHI2_95_2DOF = _CHI2_95_2DOF
#: Up to this many mapped landmarks, the ellipses come from one call of
#: ``filter.local_marginals(all landmarks)`` (exact marginals for all filters,
#: the SEIF's blanket then being the whole map: one dense inverse of the
#: (3 + 2n)-square information matrix). Beyond it, filters with an
#: information matrix use each landmark's own 2x2 block, ``inv(Omega_ii)``:
#: the covariance conditioned on the rest of the state (tighter), in O(nnz).
EXACT_ELLIPSES_LIMIT = 400

_DPI = 100
_TRUE = "#222222"
_TRUE_PATH = "#8c8c8c"
_ESTIMATE = "#1f6fd1"
_ACTIVE = "#e8402a"
_SENSOR = "#f5c518"
_ARENA = "#fbfbf8"
_OUTSIDE = "#e6e6e6"


def ellipse_parameters(
    covs: ArrayLike, chi2: float = CHI2_95_2DOF
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Full widths, heights and angles (degrees) of the ``chi2`` ellipses of covariances ``covs`` (k, 2, 2)."""
    covs = np.asarray(covs, dtype=np.float64).reshape(-1, 2, 2)
    if len(covs) == 0:
        empty = np.empty(0)
        return empty, empty, empty
    values, vectors = np.linalg.eigh(0.5 * (covs + covs.transpose(0, 2, 1)))
    values = np.clip(values, 0.0, None)
    widths = 2.0 * np.sqrt(chi2 * values[:, 1])
    heights = 2.0 * np.sqrt(chi2 * values[:, 0])
    angles = np.degrees(np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1]))
    return widths, heights, angles


def _robot_outline(pose: NDArray[np.float64], size: float) -> NDArray[np.float64]:
    """An isosceles triangle pointing along the heading, centred on the position."""
    x, y, theta = float(pose[0]), float(pose[1]), float(pose[2])
    local = size * np.array([[0.6, 0.0], [-0.4, 0.35], [-0.25, 0.0], [-0.4, -0.35]])
    c, s = math.cos(theta), math.sin(theta)
    return local @ np.array([[c, s], [-s, c]]) + (x, y)


def _block_diagonal_covariances(information: scipy.sparse.csr_array, n: int) -> NDArray[np.float64]:
    """``inv(Omega_ii)`` of every landmark's own 2x2 block of a sparse information matrix."""
    diag = information.diagonal()[3 : 3 + 2 * n]
    off = information.diagonal(1)[3 : 3 + 2 * n : 2]
    a, d, b = diag[0::2], diag[1::2], off
    det = a * d - b * b
    covs = np.empty((n, 2, 2))
    covs[:, 0, 0] = d / det
    covs[:, 1, 1] = a / det
    covs[:, 0, 1] = covs[:, 1, 0] = -b / det
    return covs


def _covariances(filt: SlamFilter) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pose covariance (3, 3) and landmark covariances (n, 2, 2), cheaply (see :data:`EXACT_ELLIPSES_LIMIT`)."""
    n = filt.num_landmarks
    if n <= EXACT_ELLIPSES_LIMIT or not isinstance(filt, InformationForm):
        return filt.local_marginals(np.arange(n, dtype=np.int64))
    pose_cov, _ = filt.local_marginals(np.empty(0, dtype=np.int64))
    return pose_cov, _block_diagonal_covariances(filt.information_matrix, n)


class Renderer:
    """Draws frames of a :class:`~seif_gym.envs.explore.SeifExploreEnv`.

    Parameters
    ----------
    arena_size : float
        Side of the square arena, metres (the walls are at ``±arena_size/2``).
    sensor : RangeBearingSensor
        Its ``max_range`` and ``fov`` give the footprint.
    human : bool
        Also show each frame in a pyplot window (interactive mode).
    extent : (float, float), optional
        ``(width, height)`` of the walls when narrower than the square
        (``WorldConfig.arena_extent``); outside them is drawn as outside.
    """

    def __init__(
        self,
        arena_size: float,
        sensor: RangeBearingSensor,
        *,
        human: bool = False,
        extent: tuple[float, ...] | None = None,
    ) -> None:
        self.arena_size = float(arena_size)
        self.half = 0.5 * self.arena_size
        # the walled area (the whole square unless the env has narrower walls)
        self.extent = (self.arena_size, self.arena_size) if extent is None else (float(extent[0]), float(extent[1]))
        self.max_range = float(sensor.max_range)
        self.fov = float(sensor.fov)
        self.human = bool(human)
        self._window: Any = None
        self._window_image: Any = None
        self._moving: list[Any] = []
        # the rendered static parts, per (header, visibility of the information-matrix panel)
        self._backgrounds: dict[tuple[str, bool], Any] = {}
        self._build()

    # -- static layout ---------------------------------------------------------------
    def _build(self) -> None:
        height, width, _ = FRAME_SHAPE
        self.figure = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")
        self.canvas = FigureCanvasAgg(self.figure)
        fig = self.figure

        # the arena: a square of 456 px at the top left
        ax = fig.add_axes((0.012, 0.19, 0.76, 0.76))
        margin = 0.02 * self.arena_size
        ax.set_xlim(-self.half - margin, self.half + margin)
        ax.set_ylim(-self.half - margin, self.half + margin)
        ax.set_aspect("equal", adjustable="box")
        ax.set_facecolor(_OUTSIDE)
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_visible(False)
        wall_width, wall_height = self.extent
        self._arena = Rectangle(
            (-0.5 * wall_width, -0.5 * wall_height), wall_width, wall_height,
            facecolor=_ARENA, edgecolor="#111111", linewidth=2.5, zorder=0.5,
        )  # fmt: skip
        ax.add_patch(self._arena)
        # a scale bar of a round number of metres
        bar = 10.0 ** math.floor(math.log10(self.arena_size / 4))
        bar *= 5 if 5 * bar <= self.arena_size / 4 else (2 if 2 * bar <= self.arena_size / 4 else 1)
        x0, y0 = -self.half + 0.04 * self.arena_size, -self.half + 0.035 * self.arena_size
        ax.plot([x0, x0 + bar], [y0, y0], color="#555555", linewidth=2, solid_capstyle="butt", zorder=6)
        ax.text(
            x0 + bar / 2, y0 + 0.012 * self.arena_size, f"{bar:g} m",
            ha="center", va="bottom", fontsize=7, color="#555555", zorder=6,
        )  # fmt: skip
        self.ax = ax

        # the information matrix's sparsity pattern, right column
        spy = fig.add_axes((0.795, 0.43, 0.19, 0.19))
        spy.set_xticks([])
        spy.set_yticks([])
        spy.set_facecolor("white")
        for spine in spy.spines.values():
            spine.set_color("#888888")
        # 0 empty, 1 an entry, 2 an entry of the robot's rows or columns
        self._spy_image = spy.imshow(
            np.zeros((1, 1), dtype=np.uint8), cmap=ListedColormap(["white", _ESTIMATE, _ACTIVE]), vmin=0, vmax=2,
            interpolation="nearest", aspect="equal", animated=True,
        )  # fmt: skip
        self._spy_title = spy.set_title("", fontsize=8, pad=3)
        self._spy_title.set_animated(True)
        self._spy_caption = spy.text(
            0.5,
            -0.05,
            "red: robot rows/cols",
            transform=spy.transAxes,
            ha="center",
            va="top",
            fontsize=7,
            color="#555555",
        )
        self.spy_ax = spy

        # text: header and statistics
        self._header = fig.text(0.012, 0.988, "", ha="left", va="top", fontsize=10, fontweight="bold")
        self._stats = fig.text(
            0.795, 0.948, "", ha="left", va="top", fontsize=8.5, family="monospace", linespacing=1.6, animated=True
        )

        # legend of proxy artists, along the bottom
        handles = [
            Line2D([], [], color=_TRUE_PATH, linewidth=3.2, alpha=0.7, label="true path"),
            Line2D([], [], color=_ESTIMATE, linewidth=1.2, label="estimated path"),
            Line2D([], [], color=_TRUE, marker="x", linestyle="none", markersize=6, label="true landmark"),
            Line2D([], [], color=_ESTIMATE, marker="o", linestyle="none", markersize=4, label="estimated landmark"),
            Patch(facecolor=to_rgba(_ESTIMATE, 0.12), edgecolor=_ESTIMATE, label="95% ellipse"),
            Patch(facecolor="none", edgecolor=_TRUE, linewidth=1.8, label="true robot"),
            Patch(facecolor=_ESTIMATE, edgecolor="#0b3d7a", alpha=0.85, label="estimated robot"),
            Line2D(
                [],
                [],
                color=_ACTIVE,
                linewidth=1.6,
                marker="o",
                markerfacecolor="none",
                markersize=7,
                label="active link",
            ),
            Patch(facecolor=to_rgba(_SENSOR, 0.3), edgecolor=to_rgba(_SENSOR, 0.9), label="sensor footprint"),
        ]
        fig.legend(
            handles=handles, loc="lower left", bbox_to_anchor=(0.01, 0.005, 0.98, 0.175), mode="expand", ncol=3,
            fontsize=8.5, frameon=False, handlelength=2.2, columnspacing=1.0, labelspacing=0.8, borderaxespad=0.3,
        )  # fmt: skip

        self._build_moving_artists()

    def _build_moving_artists(self) -> None:
        """The artists of the state, created once and updated in place by :meth:`draw`."""
        ax = self.ax
        size = self.arena_size
        marker = float(np.clip(6.5 * 20.0 / size, 3.5, 6.5))
        empty = np.empty((0, 2))
        moving = self._moving
        # sensor footprint at the true pose, clipped to the arena
        if self.fov >= 2.0 * math.pi - 1e-9:
            self._footprint: Circle | Wedge = Circle((0.0, 0.0), self.max_range)
        else:
            self._footprint = Wedge((0.0, 0.0), self.max_range, 0.0, math.degrees(self.fov))
        self._footprint.set(facecolor=to_rgba(_SENSOR, 0.22), edgecolor=to_rgba(_SENSOR, 0.9), linewidth=1.0, zorder=1)
        moving.append(ax.add_artist(self._footprint))
        self._footprint.set_clip_path(self._arena)
        # trajectories
        self._true_path = Line2D([], [], color=_TRUE_PATH, linewidth=3.2, alpha=0.7, solid_capstyle="round", zorder=2)
        self._est_path = Line2D([], [], color=_ESTIMATE, linewidth=1.2, zorder=2.1)
        # landmarks: truth, estimates with their 95% ellipses
        self._true_landmarks = Line2D(
            [], [], linestyle="none", marker="x", color=_TRUE, markersize=marker, markeredgewidth=1.3, zorder=3
        )
        self._ellipses = EllipseCollection(
            [], [], [], units="xy", offsets=empty, offset_transform=ax.transData,
            facecolors=to_rgba(_ESTIMATE, 0.12), edgecolors=_ESTIMATE, linewidths=0.9, zorder=3.5,
        )  # fmt: skip
        self._estimates = Line2D(
            [], [], linestyle="none", marker="o", color=_ESTIMATE, markersize=0.6 * marker, markeredgewidth=0, zorder=4
        )
        # active links: estimated robot -> active landmarks (ringed)
        self._links = LineCollection([], colors=_ACTIVE, linewidths=1.4, alpha=0.85, zorder=4.5)
        self._rings = Line2D(
            [], [], linestyle="none", marker="o", markerfacecolor="none", markeredgecolor=_ACTIVE,
            markeredgewidth=1.4, markersize=1.5 * marker, zorder=4.6,
        )  # fmt: skip
        # robots: the estimate with its 95% position ellipse, the truth as an outline on top
        self._pose_ellipse = Ellipse(
            (0.0, 0.0), 0.0, 0.0, facecolor=to_rgba(_ESTIMATE, 0.12), edgecolor=_ESTIMATE, linewidth=0.9,
            linestyle="--", zorder=5,
        )  # fmt: skip
        self._robot_size = float(np.clip(0.06 * size, 0.9, 2.0))
        outline = _robot_outline(np.zeros(3), self._robot_size)
        self._est_robot = Polygon(
            outline, closed=True, facecolor=_ESTIMATE, edgecolor="#0b3d7a", linewidth=1.0, alpha=0.85, zorder=6
        )
        self._true_robot = Polygon(outline, closed=True, facecolor="none", edgecolor=_TRUE, linewidth=1.8, zorder=6.5)
        for artist in (
            self._true_path, self._est_path, self._true_landmarks, self._ellipses, self._estimates,
            self._links, self._rings, self._pose_ellipse, self._est_robot, self._true_robot,
        ):  # fmt: skip
            moving.append(ax.add_artist(artist))
        for artist in moving:
            artist.set_animated(True)  # left out of the static background; drawn by _blit
        moving.sort(key=lambda artist: artist.get_zorder())

    # -- one frame -------------------------------------------------------------------
    def draw(self, env: SeifExploreEnv) -> NDArray[np.uint8]:
        """Draw the env's current state; returns an RGB frame of :data:`FRAME_SHAPE`, ``uint8``."""
        world, filt = env.world, env.filter
        if world is None or filt is None:
            raise RuntimeError("call reset() before render()")
        true_pose = np.asarray(world.pose, dtype=np.float64)
        est_pose = np.asarray(filt.pose, dtype=np.float64)

        self._footprint.set_center((float(true_pose[0]), float(true_pose[1])))
        if isinstance(self._footprint, Wedge):
            heading, half_fov = math.degrees(true_pose[2]), math.degrees(0.5 * self.fov)
            self._footprint.set_theta1(heading - half_fov)
            self._footprint.set_theta2(heading + half_fov)

        for line, poses in ((self._true_path, env.trajectory), (self._est_path, env.estimated_trajectory)):
            path = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
            line.set_data(path[:, 0], path[:, 1])

        truth = np.asarray(world.landmarks)
        self._true_landmarks.set_data(truth[:, 0], truth[:, 1])
        estimates = np.asarray(filt.landmarks, dtype=np.float64).reshape(-1, 2)
        pose_cov, covs = _covariances(filt)
        widths, heights, angles = ellipse_parameters(covs)
        self._ellipses.set_offsets(estimates)
        self._ellipses.set_widths(widths)
        self._ellipses.set_heights(heights)
        self._ellipses.set_angles(angles)
        self._estimates.set_data(estimates[:, 0], estimates[:, 1])

        active_ids = filt.active_landmarks if isinstance(filt, SparseInformationForm) else None
        if active_ids is not None and len(active_ids):
            active = estimates[[filt.landmark_index(int(i)) for i in np.asarray(active_ids)]]
        else:
            active = np.empty((0, 2))
        self._links.set_segments([np.array([est_pose[:2], point]) for point in active])
        self._rings.set_data(active[:, 0], active[:, 1])

        (width,), (height,), (angle,) = ellipse_parameters(pose_cov[:2, :2][None])
        self._pose_ellipse.set_center((float(est_pose[0]), float(est_pose[1])))
        self._pose_ellipse.set_width(width)
        self._pose_ellipse.set_height(height)
        self._pose_ellipse.set_angle(angle)
        self._est_robot.set_xy(_robot_outline(est_pose, self._robot_size))
        self._true_robot.set_xy(_robot_outline(true_pose, self._robot_size))

        spy_visible = self._draw_information(filt)
        self._draw_text(env, filt, true_pose, est_pose)
        self._blit(spy_visible)
        frame = np.asarray(self.canvas.buffer_rgba())[..., :3]
        if frame.shape != FRAME_SHAPE:  # Agg rounds the figure size; never expected at 100 dpi
            padded = np.full(FRAME_SHAPE, 255, dtype=np.uint8)
            h, w = min(frame.shape[0], FRAME_SHAPE[0]), min(frame.shape[1], FRAME_SHAPE[1])
            padded[:h, :w] = frame[:h, :w]
            frame = padded
        frame = np.ascontiguousarray(frame, dtype=np.uint8)
        if self.human:
            self._show(frame)
        return frame

    def _blit(self, spy_visible: bool) -> None:
        """Render the frame: the cached static background, then the moving artists."""
        key = (self._header.get_text(), spy_visible)
        background = self._backgrounds.get(key)
        if background is None:
            self.canvas.draw()  # animated artists are skipped
            background = self._backgrounds[key] = self.canvas.copy_from_bbox(self.figure.bbox)
        else:
            self.canvas.restore_region(background)
        for artist in self._moving:
            self.ax.draw_artist(artist)
        if spy_visible:
            for artist in (self._spy_image, self._spy_title):
                self.spy_ax.draw_artist(artist)
        self.figure.draw_artist(self._stats)

    def _draw_information(self, filt: SlamFilter) -> bool:
        spy = self.spy_ax
        if not isinstance(filt, InformationForm):
            spy.set_visible(False)
            return False
        information = filt.information_matrix
        spy.set_visible(True)
        coo = information.tocoo()
        dim = information.shape[0]
        # at most one cell per pixel of the panel, so that no entry is lost when it is shown
        bins = max(1, min(dim, int(spy.bbox.width)))
        rows, cols = coo.row * bins // dim, coo.col * bins // dim
        robot = (coo.row < 3) | (coo.col < 3)
        pattern = np.zeros((bins, bins), dtype=np.uint8)
        pattern[rows[~robot], cols[~robot]] = 1
        pattern[rows[robot], cols[robot]] = 2
        self._spy_image.set_data(pattern)
        self._spy_image.set_extent((-0.5, dim - 0.5, dim - 0.5, -0.5))
        spy.set_xlim(-0.5, dim - 0.5)
        spy.set_ylim(dim - 0.5, -0.5)
        density = coo.nnz / max(dim * dim, 1)
        self._spy_title.set_text(f"Ω  {dim}×{dim}\nnnz {coo.nnz} ({100 * density:.0f}%)")
        return True

    def _draw_text(
        self, env: SeifExploreEnv, filt: SlamFilter, true_pose: NDArray[np.float64], est_pose: NDArray[np.float64]
    ) -> None:
        name = type(filt).__name__
        max_active = filt.max_active if isinstance(filt, SparseInformationForm) else None
        if name == "SEIF":
            name += f" (k={max_active})" if max_active is not None else " (k=∞)"
        spec = getattr(env, "spec", None)
        self._header.set_text(f"{getattr(spec, 'id', None) or 'SeifExplore'} · {name}")
        steps = max(len(env.trajectory) - 1, 0)
        assert env.world is not None  # draw() checked it
        total = int(env.world.config.num_landmarks)
        lines = [f"step   {steps}", f"mapped {filt.num_landmarks}/{total}"]
        map_error = getattr(env, "_map_error", None)
        if map_error is not None:
            lines.append(f"map err {map_error:.2f} m")
        lines.append(f"pose err {math.hypot(*(true_pose[:2] - est_pose[:2])):.2f} m")
        if isinstance(filt, SparseInformationForm):
            lines.append(f"active {len(filt.active_landmarks)}")
        self._stats.set_text("\n".join(lines))

    # -- human mode ------------------------------------------------------------------
    def _show(self, frame: NDArray[np.uint8]) -> None:
        import matplotlib.pyplot as plt

        if self._window is None or not plt.fignum_exists(self._window.number):
            plt.ion()
            height, width, _ = FRAME_SHAPE
            self._window = plt.figure("SeifExplore", figsize=(width / _DPI, height / _DPI), dpi=_DPI)
            ax = self._window.add_axes((0, 0, 1, 1))
            ax.set_axis_off()
            self._window_image = ax.imshow(frame, interpolation="nearest")
        else:
            self._window_image.set_data(frame)
        plt.pause(1e-3)

    def close(self) -> None:
        """Close the window (human mode) and drop the figure."""
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window)
            self._window = None
            self._window_image = None
        self._backgrounds.clear()
