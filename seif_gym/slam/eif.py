"""The exact extended information filter (EIF) for SLAM.

The EIF keeps the information matrix ``Omega = Sigma^-1``, the information
vector ``xi = Omega mu`` and the mean ``mu``, with no sparsification and
exact mean recovery. It is the SEIF with an unbounded active set, and equals
EKF SLAM to round-off after any number of steps. Its motion update is derived
here independently of the SEIF's constant-time formulas
(:func:`seif_gym.slam.seif.motion_update`), so that it can cross-check them.

Why ``Omega`` is stored dense
-----------------------------
Without sparsification the information matrix of SLAM fills in completely:
every measurement links a landmark to the robot, and every motion update
(marginalizing the old pose) links all landmarks that were linked to the
robot to one another. After a few steps every landmark ever seen is linked to
the robot and to every other landmark, so a sparse format would store a dense
matrix with index overhead. A dense array (with doubling capacity) is both
smaller and faster here; :attr:`EIF.information_matrix` still hands out a
``scipy.sparse`` copy for code that compares against the SEIF.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
from numpy.typing import NDArray

from seif_gym.slam.base import (
    INITIAL_LANDMARK_CAPACITY,
    InformationForm,
    SlamFilter,
    merge_dense_rows,
    symmetrized,
)
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray

__all__ = ["EIF"]


def _spd_inverse(matrix: FloatArray) -> FloatArray:
    """Inverse of a small symmetric positive definite matrix by Cholesky, symmetrized."""
    factor = scipy.linalg.cho_factor(matrix, lower=True, check_finite=False)
    return symmetrized(scipy.linalg.cho_solve(factor, np.eye(len(matrix)), check_finite=False))


class EIF(SlamFilter, InformationForm):
    r"""Extended information filter SLAM with known correspondences.

    Parameters
    ----------
    motion, sensor, initial_pose, initial_pose_cov
        See :class:`~seif_gym.slam.base.SlamFilter`. The EIF has no options.

    Notes
    -----
    State ``y = (x, y, theta, m_1x, m_1y, ...)``; ``Omega`` (dense, see the
    module docstring), ``xi`` and ``mu`` live in arrays whose landmark capacity
    doubles when full. ``Omega`` is kept exactly symmetric: every block that
    is written is symmetrized or written together with its transpose.

    *Motion update* as state augmentation followed by marginalization (M.
    Walter, SLAM Summer School 2006 supplement: "Adding New
    Features to the Map" and the time-projection figure; the extended
    information filter of Thrun, Burgard & Fox, *Probabilistic Robotics*,
    ch. 3.5, Table 3.6, for the linearization). With ``(delta, G, R) = motion.linearize(mu_x, u, dt)`` the new pose is
    ``x' = mu_x + delta + G (x - mu_x) + w``, ``w ~ N(0, R)``. Adding ``x'``
    gives the factor ``A = [-G, I]`` on ``(x, x')`` with information
    ``A^T R^-1 A``; the joint information over ``(x, m, x')`` is::

        [ Omega_xx + G^T R^-1 G   Omega_xm   -G^T R^-1 ]
        [ Omega_mx                Omega_mm    0        ]
        [ -R^-1 G                 0           R^-1     ]

    and marginalizing the old pose ``x`` (Schur complement, with
    ``P = Omega_xx + G^T R^-1 G`` and ``B = [-R^-1 G; Omega_mx]``) gives

    .. math:: \bar\Omega = \begin{bmatrix} R^{-1} & 0 \\ 0 & \Omega_{mm} \end{bmatrix}
              - B P^{-1} B^T .

    Then ``mu_bar = (mu_x + delta, mu_m)`` with the heading wrapped, and
    ``xi_bar = Omega_bar mu_bar``: exact for a Gaussian, and it keeps ``xi``
    consistent with the wrapped heading (a component of ``xi`` is never
    wrapped). This is the same Gaussian as the EKF's ``G Sigma_xx G^T + R``,
    ``G Sigma_xm``, and is used to cross-check the constant-time formulas of
    :func:`seif_gym.slam.seif.motion_update` (``Psi``, ``lambda``, ``kappa``).
    Cost O(n^2).

    *Measurement update* (Thrun Table 12.3). A new
    landmark gets zero rows and columns of information and the mean
    ``sensor.inverse(mu_x, z)``. Then, with every ``H_i`` linearized at
    ``mu_bar``,

    .. math:: \Omega \mathrel{+}= \sum_i H_i^T Q^{-1} H_i, \qquad
              \xi \mathrel{+}= \sum_i H_i^T Q^{-1}
              (\mathrm{wrap}(z_i - \hat z_i) + H_i \bar\mu).

    *Mean recovery* is exact: ``mu = Omega^-1 xi`` by a Cholesky factorization
    of ``Omega``, computed as the
    correction ``mu = mu_bar + Omega^-1 (xi - Omega mu_bar)`` so that the
    round-off of the solve scales with the (small) correction rather than
    with ``mu``. If wrapping ``mu_theta`` changes it, ``xi = Omega mu`` is
    recomputed. Cost O(n^3) per update; the factor is kept for covariance
    queries until the next motion update.

    Covariances come from Cholesky solves against ``Omega``; ``Omega`` is never
    inverted explicitly in a filter step.

    A step either completes or, if anything in it raises, leaves the filter
    untouched (all results are computed before any state is written).
    """

    OPTIONS = {}

    # -- storage -------------------------------------------------------------
    def _initialize(self, pose: FloatArray, pose_cov: FloatArray) -> None:
        size = 3 + 2 * INITIAL_LANDMARK_CAPACITY
        self._information: FloatArray = np.zeros((size, size))
        self._info_vector: FloatArray = np.zeros(size)
        self._state_mean: FloatArray = np.zeros(size)
        self._information[:3, :3] = _spd_inverse(pose_cov)
        self._state_mean[:3] = pose
        self._info_vector[:3] = self._information[:3, :3] @ pose
        self._dim = 3
        self._cholesky: tuple[FloatArray, bool] | None = None  # factor of Omega, or None if stale

    def _reserve(self, dim: int) -> None:
        """Make room for a state of length ``dim``, doubling the landmark capacity."""
        size = len(self._state_mean)
        if dim <= size:
            return
        capacity = (size - 3) // 2
        while 3 + 2 * capacity < dim:
            capacity *= 2
        new_size = 3 + 2 * capacity
        information = np.zeros((new_size, new_size))
        info_vector = np.zeros(new_size)
        mean = np.zeros(new_size)
        used = self._dim
        information[:used, :used] = self._information[:used, :used]
        info_vector[:used] = self._info_vector[:used]
        mean[:used] = self._state_mean[:used]
        self._information, self._info_vector, self._state_mean = information, info_vector, mean

    def _merge(self, keep: int, remove: int) -> None:
        """``Omega <- P^T Omega P``, ``xi <- P^T xi`` (``SlamFilter.merge_landmarks``), then the exact mean."""
        dim, new_dim = self._dim, self._dim - 2
        information = self._information[:dim, :dim].copy()
        info_vector = self._info_vector[:dim].copy()
        merge_dense_rows(information, (info_vector,), dim, keep, remove)
        information, info_vector = information[:new_dim, :new_dim], info_vector[:new_dim]
        factor = scipy.linalg.cho_factor(information, lower=True, check_finite=False)
        mean = scipy.linalg.cho_solve(factor, info_vector, check_finite=False)
        wrapped_heading = wrap_angle(float(mean[2]))
        if wrapped_heading != mean[2]:
            mean[2] = wrapped_heading
            info_vector = information @ mean
        # commit
        self._information[:dim, :dim] = 0.0
        self._information[:new_dim, :new_dim] = information
        self._info_vector[:dim] = 0.0
        self._info_vector[:new_dim] = info_vector
        self._state_mean[:dim] = 0.0
        self._state_mean[:new_dim] = mean
        self._dim = new_dim
        self._cholesky = factor

    # -- filter steps ----------------------------------------------------------
    def _predict(self, control: FloatArray, dt: float, verify: bool = False) -> None:
        """EIF motion update: add the new pose, marginalize the old one (class Notes).

        ``verify``: the new pose information against its closed form, before any write.
        """
        dim = self._dim
        information = self._information[:dim, :dim]
        mean = self._state_mean[:dim]
        delta, jacobian, motion_noise = self._linearize(mean[:3].copy(), control, dt)
        if verify:
            self._check_motion(control, dt, delta, jacobian, motion_noise)
        noise_information = _spd_inverse(motion_noise)
        noise_info_jacobian = noise_information @ jacobian  # R^-1 G
        old_pose_information = symmetrized(information[:3, :3] + jacobian.T @ noise_info_jacobian)  # P
        links = np.empty((dim, 3))  # B: links of the old pose to (x', m)
        links[:3] = -noise_info_jacobian
        links[3:] = information[3:, :3]
        factor = scipy.linalg.cho_factor(old_pose_information, lower=True, check_finite=False)
        removed = symmetrized(links @ scipy.linalg.cho_solve(factor, links.T, check_finite=False))  # B P^-1 B^T
        if verify:
            if not np.isfinite(removed).all():
                self._refuse_motion(control, dt, "the predicted information matrix overflows float64")
            self._check_pose_information(control, dt, information[:3, :3], noise_information - removed[:3, :3],
                                         jacobian, motion_noise)  # fmt: skip

        # commit
        information[:3, :3] = noise_information - removed[:3, :3]
        information[:3, 3:] = -removed[:3, 3:]
        information[3:, :3] = -removed[3:, :3]
        information[3:, 3:] -= removed[3:, 3:]
        mean[:3] += delta
        mean[2] = wrap_angle(float(mean[2]))
        self._info_vector[:dim] = information @ mean
        self._cholesky = None

    def _update(
        self,
        ranges: FloatArray,
        bearings: FloatArray,
        indices: NDArray[np.int64],
        is_new: NDArray[np.bool_],
    ) -> None:
        """EIF measurement update and exact mean recovery (class Notes)."""
        count = len(indices)
        if count == 0:  # no information: the mean and Omega stay as they are
            return
        old_dim = self._dim
        pose = self._state_mean[:3].copy()
        new_count = int(np.count_nonzero(is_new))
        new_dim = old_dim + 2 * new_count

        # mu_bar over the augmented state: new landmarks from the inverse sensor model
        mean_bar = np.empty(new_dim)
        mean_bar[:old_dim] = self._state_mean[:old_dim]
        if new_count:
            mean_bar[old_dim:] = self.sensor.inverse(pose, ranges[is_new], bearings[is_new]).ravel()
        information = np.zeros((new_dim, new_dim))
        information[:old_dim, :old_dim] = self._information[:old_dim, :old_dim]
        info_vector = np.zeros(new_dim)
        info_vector[:old_dim] = self._info_vector[:old_dim]

        columns = 3 + 2 * indices[:, None] + np.arange(2)  # (m, 2) state columns
        landmark_means = mean_bar[columns]
        predicted = self.sensor.predict(pose, landmark_means)
        jacobians = self.sensor.jacobian(pose, landmark_means)  # (m, 2, 5), columns (x, y, theta, m_x, m_y)
        innovation = np.column_stack([ranges, bearings]) - predicted
        innovation[:, 1] = wrap_angle(innovation[:, 1])
        noise_infos = self._noise_informations(ranges)  # per-measurement Q_i^-1 of a range-dependent sensor
        if noise_infos is None:
            weighted = np.einsum("ab,mbc->mac", self._measurement_info, jacobians)  # Q^-1 H_i
        else:
            weighted = np.einsum("mab,mbc->mac", noise_infos, jacobians)
        blocks = np.einsum("mai,maj->mij", jacobians, weighted)  # H_i^T Q^-1 H_i, (m, 5, 5)
        blocks = 0.5 * (blocks + blocks.transpose(0, 2, 1))
        local_means = np.concatenate([np.broadcast_to(pose, (count, 3)), landmark_means], axis=1)
        pseudo_measurement = innovation + np.einsum("mac,mc->ma", jacobians, local_means)
        vectors = np.einsum("mac,ma->mc", weighted, pseudo_measurement)  # H_i^T Q^-1 (...)

        flat_columns = columns.ravel()
        robot_landmark = blocks[:, :3, 3:].transpose(1, 0, 2).reshape(3, 2 * count)
        information[:3, :3] += blocks[:, :3, :3].sum(axis=0)
        information[:3, flat_columns] += robot_landmark
        information[flat_columns, :3] += robot_landmark.T
        information[columns[:, :, None], columns[:, None, :]] += blocks[:, 3:, 3:]
        info_vector[:3] += vectors[:, :3].sum(axis=0)
        info_vector[columns] += vectors[:, 3:]

        factor = scipy.linalg.cho_factor(information, lower=True, check_finite=False)
        mean = mean_bar + scipy.linalg.cho_solve(factor, info_vector - information @ mean_bar, check_finite=False)
        wrapped_heading = wrap_angle(float(mean[2]))
        if wrapped_heading != mean[2]:
            mean[2] = wrapped_heading
            info_vector = information @ mean

        # commit
        self._reserve(new_dim)
        self._information[:new_dim, :new_dim] = information
        self._info_vector[:new_dim] = info_vector
        self._state_mean[:new_dim] = mean
        self._dim = new_dim
        self._cholesky = factor

    # -- information form --------------------------------------------------------
    @property
    def information_matrix(self) -> scipy.sparse.csr_array:
        """A copy of ``Omega``, (3 + 2n, 3 + 2n), with the exactly-zero entries dropped."""
        return scipy.sparse.csr_array(self._information[: self._dim, : self._dim])

    @property
    def information_vector(self) -> FloatArray:
        """A read-only copy of ``xi``, shape (3 + 2n,)."""
        vector = self._info_vector[: self._dim].copy()
        vector.setflags(write=False)
        return vector

    # -- belief ----------------------------------------------------------------
    def _factor(self) -> tuple[FloatArray, bool]:
        """Cholesky factor of ``Omega``, computed once per state."""
        if self._cholesky is None:
            self._cholesky = scipy.linalg.cho_factor(
                self._information[: self._dim, : self._dim], lower=True, check_finite=False
            )
        return self._cholesky

    def _mean_vector(self) -> FloatArray:
        return self._state_mean[: self._dim]

    def _marginal_covariance(self, state_indices: NDArray[np.int64]) -> FloatArray:
        unit_columns = np.zeros((self._dim, len(state_indices)))
        unit_columns[state_indices, np.arange(len(state_indices))] = 1.0
        columns = scipy.linalg.cho_solve(self._factor(), unit_columns, check_finite=False)
        return symmetrized(columns[state_indices])

    def _marginal_variances(self) -> FloatArray:
        # diag(Omega^-1) = squared column norms of L^-1 (Omega = L L^T): one triangular solve
        factor, lower = self._factor()
        inverse_factor = scipy.linalg.solve_triangular(factor, np.eye(self._dim), lower=lower, check_finite=False)
        if not lower:  # cho_factor(..., lower=True) above: never taken, kept for safety
            inverse_factor = inverse_factor.T
        return np.einsum("ij,ij->j", inverse_factor, inverse_factor)

    def _full_covariance(self) -> FloatArray:
        return symmetrized(scipy.linalg.cho_solve(self._factor(), np.eye(self._dim), check_finite=False))

    def _state_nbytes(self) -> int:
        return self._information.nbytes + self._info_vector.nbytes + self._state_mean.nbytes
