"""An extended Kalman filter on the rover's (x, y, heading): odometry predicts, skyline fixes
update, and an innovation gate keeps a confident-looking outlier out.

Written here rather than taken from a library (filterpy, for one, is unmaintained since 2018):
the state has three components, the motion model is exact rigid-body composition, and the one
subtlety, the heading's wrap at 360 deg in the innovation, is easier to see in 100 lines than
to configure around.

State: x, y [m] in the work CRS, heading [deg] clockwise from grid north (as every azimuth inside
skyfix; outputs convert to true north). Covariance in m^2, m deg and deg^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..north import heading_360, wrap_deg

#: chi-square quantiles at 99.9 %, by degrees of freedom: the innovation gate
GATE_CHI2 = {1: 10.83, 3: 16.27}
#: ... and at 95 %: the region where the track corroborates a measurement of middling confidence
CORROBORATION_CHI2 = {1: 3.84, 3: 7.81}
RAD = math.pi / 180.0


@dataclass(frozen=True)
class Odometry:
    """The motion from one stop to the next, in the first stop's body frame: ``forward_m`` along
    its heading, ``left_m`` to its left [m], ``dheading_deg`` the heading change [deg, clockwise
    positive, as headings], and the 3 x 3 covariance of (forward, left, dheading) [m^2, m deg,
    deg^2]."""

    forward_m: float
    left_m: float
    dheading_deg: float
    cov: np.ndarray

    @classmethod
    def from_sigmas(cls, forward_m, left_m, dheading_deg, sigma_forward_m, sigma_left_m,
                    sigma_heading_deg) -> "Odometry":
        return cls(float(forward_m), float(left_m), float(dheading_deg),
                   np.diag([sigma_forward_m ** 2, sigma_left_m ** 2, sigma_heading_deg ** 2]))

    @property
    def distance_m(self) -> float:
        return math.hypot(self.forward_m, self.left_m)


@dataclass(frozen=True)
class Update:
    """What an update did: ``accepted``, the normalised innovation squared ``nis`` (chi-square with
    ``dof`` degrees of freedom when the filter and the measurement are both right), and the
    innovation itself [m, m, deg or deg]."""

    accepted: bool
    nis: float
    dof: int
    innovation: tuple


def fix_covariance(position_sigma_m, heading_sigma_deg) -> np.ndarray:
    """The 3 x 3 covariance [m^2, deg^2] of a fix or a start given by its 1-sigmas: the position's
    radial, as every position sigma skyfix reads or writes (the root of the trace: half its
    square on each axis), the heading's [deg]."""
    axis = float(position_sigma_m) ** 2 / 2.0
    return np.diag([axis, axis, float(heading_sigma_deg) ** 2])


class PoseFilter:
    """EKF on (x [m], y [m], heading [deg from grid north])."""

    def __init__(self, x, y, heading_deg, cov):
        self.state = np.array([float(x), float(y), heading_360(float(heading_deg))])
        self.cov = np.array(cov, float).reshape(3, 3)
        if not np.all(np.isfinite(self.state)) or not np.all(np.isfinite(self.cov)):
            raise ValueError("the filter's start must be finite")

    @property
    def position_sigma_m(self) -> float:
        """Radial 1-sigma [m]: the root of the position covariance's trace, as a fix's
        ``position_sigma_m`` (about 63 % of errors within it when both axes are alike)."""
        return float(math.sqrt(max(self.cov[0, 0] + self.cov[1, 1], 0.0)))

    @property
    def position_axis_sigma_m(self) -> float:
        """1-sigma [m] along the worst axis: the root of the larger eigenvalue of the position
        covariance (how far the position may be off in any one direction)."""
        return float(math.sqrt(max(np.linalg.eigvalsh(self.cov[:2, :2]).max(), 0.0)))

    @property
    def heading_sigma_deg(self) -> float:
        return float(math.sqrt(max(self.cov[2, 2], 0.0)))

    def predict(self, odo: Odometry) -> None:
        """Compose the odometry onto the state (exact), and propagate the covariance through its
        Jacobians: F on the state, G on the odometry's (forward, left, dheading)."""
        x, y, h = self.state
        s, c = math.sin(h * RAD), math.cos(h * RAD)
        f, l_ = odo.forward_m, odo.left_m
        # forward is (sin h, cos h) in (east, north); left is forward turned 90 deg anticlockwise
        self.state = np.array([x + f * s - l_ * c, y + f * c + l_ * s,
                               heading_360(h + odo.dheading_deg)])
        big_f = np.array([[1.0, 0.0, (f * c + l_ * s) * RAD],
                          [0.0, 1.0, (-f * s + l_ * c) * RAD],
                          [0.0, 0.0, 1.0]])
        big_g = np.array([[s, -c, 0.0], [c, s, 0.0], [0.0, 0.0, 1.0]])
        self.cov = big_f @ self.cov @ big_f.T + big_g @ odo.cov @ big_g.T

    def _update(self, h_mat, innov, r_mat, gate: bool, chi2=None) -> Update:
        s_mat = h_mat @ self.cov @ h_mat.T + r_mat
        s_inv = np.linalg.inv(s_mat)
        nis = float(innov @ s_inv @ innov)
        dof = innov.size
        ok = (not gate) or nis <= (chi2 or GATE_CHI2)[dof]
        if ok:
            k = self.cov @ h_mat.T @ s_inv
            self.state = self.state + k @ innov
            self.state[2] = heading_360(self.state[2])
            # Joseph form: stays symmetric and positive under rounding
            a = np.eye(3) - k @ h_mat
            self.cov = a @ self.cov @ a.T + k @ r_mat @ k.T
        return Update(ok, nis, dof, tuple(float(v) for v in innov))

    def update_heading(self, heading_deg, sigma_deg, *, gate=True, chi2=None) -> Update:
        """A heading measurement [deg from grid north] with its 1-sigma [deg]; ``chi2`` (by
        degrees of freedom) replaces the 99.9 % gate."""
        innov = np.array([float(wrap_deg(heading_deg - self.state[2]))])
        return self._update(np.array([[0.0, 0.0, 1.0]]), innov,
                            np.array([[float(sigma_deg) ** 2]]), gate, chi2)

    def update_pose(self, x, y, heading_deg, position_sigma_m, heading_sigma_deg, *,
                    gate=True, chi2=None) -> Update:
        """A position and heading fix [m, m, deg from grid north] with 1-sigmas [m, deg]
        (the position sigma radial, as a fix reports it: the root of its covariance's trace,
        half of it on each axis); ``chi2`` as for a heading."""
        innov = np.array([float(x) - self.state[0], float(y) - self.state[1],
                          float(wrap_deg(heading_deg - self.state[2]))])
        return self._update(np.eye(3), innov, fix_covariance(position_sigma_m, heading_sigma_deg),
                            gate, chi2)
