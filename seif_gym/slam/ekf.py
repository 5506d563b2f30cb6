"""EKF SLAM: the exact dense-covariance baseline.

The extended Kalman filter keeps the mean ``mu`` and the full covariance
``Sigma`` of the robot pose and all landmarks. A motion step costs O(n) (only
the robot rows and columns of ``Sigma`` change), a measurement step O(n^2)
(every entry of ``Sigma`` changes). It is the reference the information
filters are checked against: with the update order used here, the EKF equals
the exact extended information filter (:class:`~seif_gym.slam.eif.EIF`) to
round-off after any number of steps.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from seif_gym.slam.base import INITIAL_LANDMARK_CAPACITY, SlamFilter, swap_remove_dense, symmetrized
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray

__all__ = ["EKF"]


class EKF(SlamFilter):
    r"""EKF SLAM with known correspondences and a dense covariance.

    Parameters
    ----------
    motion, sensor, initial_pose, initial_pose_cov
        See :class:`~seif_gym.slam.base.SlamFilter`. The EKF has no options.

    Notes
    -----
    State ``y = (x, y, theta, m_1x, m_1y, ...)`` with mean ``mu`` and
    covariance ``Sigma``, stored in arrays whose landmark capacity doubles when
    full, so adding a landmark costs amortized O(n^2) (one copy of ``Sigma`` per
    doubling) rather than a copy per landmark.

    *Motion update* (Thrun, Burgard & Fox, *Probabilistic Robotics*, Table
    10.1 "EKF SLAM with known correspondences", lines 2-5; the velocity
    motion model of :class:`~seif_gym.slam.models.VelocityMotionModel`): with
    ``(delta, G, R) = motion.linearize(mu_x, u, dt)``,

    .. math:: \mu_x \leftarrow \mu_x + \delta, \quad
              \Sigma_{xx} \leftarrow G \Sigma_{xx} G^T + R, \quad
              \Sigma_{xm} \leftarrow G \Sigma_{xm},

    the heading wrapped afterwards. Only the robot rows and columns change.

    *Measurement update* (Thrun Table 10.1, the rest of it, with two changes:
    a new landmark's covariance is initialized from the inverse sensor model
    instead of a huge prior, and the known landmarks are applied as one batch;
    the sensor model of :class:`~seif_gym.slam.models.RangeBearingSensor`):

    1. Each landmark seen for the first time is added from its own measurement
       with the inverse sensor model ``m = h^-1(x, z)`` and its Jacobians
       ``G_x = dm/dx``, ``G_z = dm/dz``:
       ``Sigma_mm = G_x Sigma_xx G_x^T + G_z Q G_z^T``,
       ``Sigma_m. = G_x Sigma_x.``. That measurement is consumed: it carries no
       further information about the rest of the state.
    2. All measurements of landmarks already in the map are applied at once,
       linearized at the current mean: ``H`` stacks the ``(2, 5)`` Jacobians
       (non-zero only in the robot and landmark columns, which is exploited:
       ``Sigma H^T`` is gathered from those columns),
       ``S = H Sigma H^T + diag(Q, ..., Q)``, ``K = Sigma H^T S^-1`` by a
       Cholesky solve, ``mu += K nu`` with the bearing innovations wrapped,
       ``Sigma -= K S K^T`` (formed as ``K (Sigma H^T)^T``) and symmetrized.

    Step 1 is exactly the information-form update with zero prior information
    on the new landmark (the information filters initialise it with zero
    information of its own; the measurement supplies it), and step 2 adds all other
    measurement information at the same linearization point, so the EKF and
    the EIF are the same linear-Gaussian update and agree to round-off.

    A measurement update either completes or, if anything in it raises,
    leaves the filter untouched (all results are computed before any state
    is written).
    """

    OPTIONS = {}

    # -- storage -------------------------------------------------------------
    def _initialize(self, pose: FloatArray, pose_cov: FloatArray) -> None:
        size = 3 + 2 * INITIAL_LANDMARK_CAPACITY
        self._state_mean: FloatArray = np.zeros(size)
        self._state_cov: FloatArray = np.zeros((size, size))
        self._state_mean[:3] = pose
        self._state_cov[:3, :3] = pose_cov
        self._dim = 3

    def _reserve(self, dim: int) -> None:
        """Make room for a state of length ``dim``, doubling the landmark capacity."""
        size = len(self._state_mean)
        if dim <= size:
            return
        capacity = (size - 3) // 2
        while 3 + 2 * capacity < dim:
            capacity *= 2
        new_size = 3 + 2 * capacity
        mean = np.zeros(new_size)
        cov = np.zeros((new_size, new_size))
        mean[: self._dim] = self._state_mean[: self._dim]
        cov[: self._dim, : self._dim] = self._state_cov[: self._dim, : self._dim]
        self._state_mean, self._state_cov = mean, cov

    def _merge(self, keep: int, remove: int) -> None:
        """Condition on ``m_remove - m_keep = 0`` (a noise-free measurement), then drop ``m_remove``; O(n^2).

        With ``H`` picking ``m_remove - m_keep``: ``K = Sigma H^T (H Sigma H^T)^-1``,
        ``mu -= K H mu``, ``Sigma -= K H Sigma`` (``SlamFilter.merge_landmarks``).
        """
        dim = self._dim
        mean, cov = self._state_mean[:dim], self._state_cov[:dim, :dim]
        a, b = 3 + 2 * keep, 3 + 2 * remove
        cross = cov[:, b : b + 2] - cov[:, a : a + 2]  # Sigma H^T
        innovation_cov = symmetrized(cross[b : b + 2] - cross[a : a + 2])  # H Sigma H^T
        gain = scipy.linalg.solve(innovation_cov, cross.T, assume_a="pos", check_finite=False).T
        new_mean = mean - gain @ (mean[b : b + 2] - mean[a : a + 2])
        new_cov = symmetrized(cov - gain @ cross.T)
        if not (np.all(np.isfinite(new_mean)) and np.all(np.isfinite(new_cov))):
            raise np.linalg.LinAlgError("merge_landmarks: the conditioned belief is not finite")
        new_mean[2] = wrap_angle(float(new_mean[2]))
        # commit
        mean[:] = new_mean
        cov[:] = new_cov
        swap_remove_dense(self._state_cov, (self._state_mean,), dim, remove)
        self._dim = dim - 2

    # -- filter steps ----------------------------------------------------------
    def _predict(self, control: FloatArray, dt: float, verify: bool = False) -> None:
        """EKF motion update (class Notes); O(n). ``verify``: the new pose rows finite, the pose block PD."""
        dim = self._dim
        mean, cov = self._state_mean, self._state_cov
        delta, jacobian, motion_noise = self._linearize(mean[:3].copy(), control, dt)
        if verify:
            self._check_motion(control, dt, delta, jacobian, motion_noise)
        robot_block = symmetrized(jacobian @ cov[:3, :3] @ jacobian.T + motion_noise)
        robot_map_block = jacobian @ cov[:3, 3:dim]
        if verify:
            self._check_pose_covariance(control, dt, robot_block, robot_map_block)
        mean[:3] += delta
        mean[2] = wrap_angle(float(mean[2]))
        cov[:3, :3] = robot_block
        cov[:3, 3:dim] = robot_map_block
        cov[3:dim, :3] = robot_map_block.T

    def _check_pose_covariance(self, control: FloatArray, dt: float, robot_block: FloatArray,
                               robot_map_block: FloatArray) -> None:  # fmt: skip
        """Refuse a predicted pose covariance that is not finite or not positive definite (before any write)."""
        if not (np.isfinite(robot_block).all() and np.isfinite(robot_map_block).all()):
            self._refuse_motion(control, dt, "the predicted pose covariance overflows float64")
        try:
            np.linalg.cholesky(robot_block)
        except np.linalg.LinAlgError:
            self._refuse_motion(control, dt, "the predicted pose covariance is not positive definite in float64")

    def _update(
        self,
        ranges: FloatArray,
        bearings: FloatArray,
        indices: NDArray[np.int64],
        is_new: NDArray[np.bool_],
    ) -> None:
        """EKF measurement update: add new landmarks, then one batch update (class Notes)."""
        old_dim = self._dim
        mean = self._state_mean[:old_dim]
        cov = self._state_cov[:old_dim, :old_dim]
        pose = mean[:3].copy()
        measurement_cov = self._measurement_cov
        # per-measurement Q_i of a range-dependent sensor (None: every measurement has Q)
        noise_covs = self._noise_covariances(ranges) if self._range_noise else None
        new_count = int(np.count_nonzero(is_new))
        new_dim = old_dim + 2 * new_count

        # 1. augmentation blocks of the new landmarks (nothing written yet)
        if new_count:
            new_ranges, new_bearings = ranges[is_new], bearings[is_new]
            new_means = self.sensor.inverse(pose, new_ranges, new_bearings).ravel()
            wrt_pose, wrt_measurement = self.sensor.inverse_jacobians(pose, new_ranges, new_bearings)
            wrt_pose_stacked = wrt_pose.reshape(2 * new_count, 3)
            new_cross = wrt_pose_stacked @ cov[:3, :]  # Sigma_{new, old} = G_x Sigma_{x, old}
            new_block = wrt_pose_stacked @ new_cross[:, :3].T  # G_x Sigma_xx G_x^T (all pairs)
            own_cov = measurement_cov if noise_covs is None else noise_covs[is_new]
            own_noise = wrt_measurement @ own_cov @ wrt_measurement.transpose(0, 2, 1)
            for k in range(new_count):
                new_block[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] += own_noise[k]
            new_block = symmetrized(new_block)
        else:
            new_means = np.empty(0)
            new_cross = np.empty((0, old_dim))
            new_block = np.empty((0, 0))

        # 2. batch update with the landmarks already in the map
        old = ~is_new
        old_count = int(np.count_nonzero(old))
        if old_count:
            columns = 3 + 2 * indices[old][:, None] + np.arange(2)  # (m, 2) state columns
            landmark_means = mean[columns]
            predicted = self.sensor.predict(pose, landmark_means)
            jacobians = self.sensor.jacobian(pose, landmark_means)  # (m, 2, 5)
            innovation = np.column_stack([ranges[old], bearings[old]]) - predicted
            innovation[:, 1] = wrap_angle(innovation[:, 1])
            pose_jacobian = jacobians[:, :, :3].reshape(2 * old_count, 3)
            landmark_jacobians = jacobians[:, :, 3:]

            def times_jacobian_transpose(rows: FloatArray) -> FloatArray:
                """``rows @ H^T`` for rows over the old state, using H's sparsity."""
                product = rows[:, :3] @ pose_jacobian.T
                landmark_part = np.einsum("rmc,mjc->rmj", rows[:, columns], landmark_jacobians)
                product += landmark_part.reshape(len(rows), 2 * old_count)
                return product

            cov_jt_old = times_jacobian_transpose(cov)  # (old_dim, 2m)
            cov_jt_new = times_jacobian_transpose(new_cross)  # (2 new, 2m)
            innovation_cov = times_jacobian_transpose(cov_jt_old.T)  # H Sigma H^T, (2m, 2m)
            old_covs = None if noise_covs is None else noise_covs[old]
            for k in range(old_count):
                innovation_cov[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] += (
                    measurement_cov if old_covs is None else old_covs[k]
                )
            factor = scipy.linalg.cho_factor(symmetrized(innovation_cov), lower=True, check_finite=False)
            cov_jt = np.vstack([cov_jt_old, cov_jt_new])  # Sigma H^T over the augmented state
            gain_transpose = scipy.linalg.cho_solve(factor, cov_jt.T, check_finite=False)  # K^T = S^-1 H Sigma

        # commit: nothing below can fail on valid numbers
        self._reserve(new_dim)
        state_mean, state_cov = self._state_mean, self._state_cov
        if new_count:
            state_mean[old_dim:new_dim] = new_means
            state_cov[old_dim:new_dim, :old_dim] = new_cross
            state_cov[:old_dim, old_dim:new_dim] = new_cross.T
            state_cov[old_dim:new_dim, old_dim:new_dim] = new_block
        self._dim = new_dim
        if old_count:
            state_mean[:new_dim] += gain_transpose.T @ innovation.ravel()
            updated = state_cov[:new_dim, :new_dim] - cov_jt @ gain_transpose  # Sigma - K S K^T
            state_cov[:new_dim, :new_dim] = symmetrized(updated)
            state_mean[2] = wrap_angle(float(state_mean[2]))

    # -- belief ----------------------------------------------------------------
    def _mean_vector(self) -> FloatArray:
        return self._state_mean[: self._dim]

    def _marginal_covariance(self, state_indices: NDArray[np.int64]) -> FloatArray:
        return self._state_cov[np.ix_(state_indices, state_indices)].copy()

    def _marginal_variances(self) -> FloatArray:
        return np.diag(self._state_cov)[: self._dim].copy()

    def _full_covariance(self) -> FloatArray:
        return self._state_cov[: self._dim, : self._dim].copy()

    def _state_nbytes(self) -> int:
        return self._state_mean.nbytes + self._state_cov.nbytes
