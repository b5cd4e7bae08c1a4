"""Temporal filters per joint, batched over all B*J joints (Lee et al. 2022, section 2.2.3, and beyond).

Every filter keeps, per joint, a state ``x`` (N, 2, 3): position (mm) and velocity (mm/s) per axis, a
covariance ``P`` (N, 3): the upper triangle (p_pos, p_pos_vel, p_vel) of the per-axis 2x2 covariance,
shared by the three axes because the models and noises are isotropic, and a counter ``coast`` (N,):
-1 = no track, 0 = measured this frame, k > 0 = k frames in a row without a measurement. ``x`` and ``P``
of a row with ``coast == -1`` are meaningless.

One step per frame, for every joint:

* no track, measurement z: the track starts, ``x = (z, 0)``, ``P = P0``; the output is z itself (there is
  no earlier estimate to predict from).
* track, measurement: predict, then update with z.
* track, no measurement (the merge gave NaN): predict only ("coasting"); after more than
  ``max_coast_frames`` such frames in a row the output is NaN and the track is dropped, so the joint
  restarts from its next measurement instead of drifting on a stale velocity.
* no track, no measurement: NaN.

Kinds:

``paper_kalman`` (paper eq. 7-13): A = I, H = I, Q = q I, R = r I (paper q = 0.01, r = 1.0, mm^2). The
    output is the *predicted* state (eq. 9, ``x~_t = A x^_{t-1}``), i.e. the posterior of the previous
    frame: one frame of delay on top of an exponential smoother whose steady-state gain is
    ``K = P~ / (P~ + r)`` with ``P~ = (q + sqrt(q^2 + 4 q r)) / 2``, about 0.095 for the paper's q and r:
    a time constant of about 10 frames, so on fast motion it lags by several frames (lag, not noise, then
    dominates its error). Since Q and R are per axis and isotropic, P stays a multiple of I.
``cv_kalman`` (beyond the paper): constant velocity per axis, F = [[1, dt], [0, 1]], H = [1, 0], discrete
    white-noise acceleration Q = sigma_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]], R = sigma_m^2, optionally
    divided by the number of agreeing sensors. Output = posterior (no added delay).
``alpha_beta`` (Carraro et al., Algorithm 1): ``X = Xp + V dt; R = Xm - X; X += alpha R;
    V += beta R / dt``. Output = X.

All functions are pure: they return new arrays. The step runs in a compiled kernel
(:mod:`skelfuse.fusion.kernels.filters`, one loop over the joints); its numpy form is the test reference
(:mod:`skelfuse.fusion.reference.filters`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.fusion.presets import FusionParams


def init_filter_state(n_joints: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empty filter state for ``n_joints`` joints: x (N, 2, 3) zeros, P (N, 3) zeros, coast (N,) all -1."""
    return np.zeros((n_joints, 2, 3)), np.zeros((n_joints, 3)), np.full(n_joints, -1, dtype=np.int32)


def filter_step(
    x: np.ndarray,
    P: np.ndarray,
    coast: np.ndarray,
    z: np.ndarray,
    n_agree: np.ndarray,
    params: FusionParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One filter step for N joints, of the kind ``params.filter``.

    Parameters
    ----------
    x : (N, 2, 3) float64, position (mm) and velocity (mm/s).
    P : (N, 3) float64, (p_pos mm^2, p_pos_vel mm^2/s, p_vel mm^2/s^2).
    coast : (N,) int, -1 = no track, else frames since the last measurement.
    z : (N, 3) float64, mm, the merged positions; NaN = no measurement.
    n_agree : (N,) int, sensors behind each measurement (cv_kalman may scale R by it).
    params : FusionParams
    dt_s : float, seconds since the previous frame.

    Returns
    -------
    out : (N, 3) float64, mm, the filtered positions (NaN = no estimate).
    x, P, coast : the new state (new arrays).
    """
    kind = params.filter
    if kind is None:
        return z.copy(), x, P, coast
    code, model, r, gains = _kernel_model(
        kind,
        float(dt_s),
        (params.kalman_q_mm2, params.kalman_r_mm2, params.kalman_p0_mm2),
        (params.cv_accel_sigma_mm_s2, params.cv_meas_sigma_mm, params.cv_velocity0_sigma_mm_s),
        (params.alpha, params.beta),
    )
    N = len(coast)
    x = np.ascontiguousarray(x, dtype=np.float64)
    P = np.ascontiguousarray(P, dtype=np.float64)
    z = np.ascontiguousarray(z, dtype=np.float64)
    n_agree = np.ascontiguousarray(n_agree, dtype=np.int64)
    if x.shape != (N, 2, 3) or P.shape != (N, 3) or z.shape != (N, 3) or n_agree.shape != (N,):
        raise ValueError(
            f"filter_step needs x (N, 2, 3), P (N, 3), z (N, 3), n_agree (N,) for the N = {N} joints of coast, got "
            f"{x.shape}, {P.shape}, {z.shape}, {n_agree.shape}"
        )
    return kernels.load().filters.filter_step(
        code,
        x,
        P,
        np.ascontiguousarray(coast, dtype=np.int32),
        z,
        n_agree,
        model,
        r,
        gains,
        int(params.max_coast_frames),
        kind == "cv_kalman" and bool(params.cv_scale_r_by_agree),
        params.kalman_output == "posterior",
    )


_KIND_CODES = {"paper_kalman": 0, "cv_kalman": 1, "alpha_beta": 2}  # the kernel's PAPER_KALMAN, CV_KALMAN, ALPHA_BETA
_IDENTITY2 = np.eye(2)
_IDENTITY3 = np.eye(3)
_ZEROS3 = np.zeros(3)


@lru_cache(maxsize=16)
def _kernel_model(
    kind: str,
    dt: float,
    paper: tuple[float, float, float],
    cv: tuple[float, float, float],
    alpha_beta: tuple[float, float],
) -> tuple[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], float, np.ndarray]:
    """The kernel's arguments for filter ``kind`` at one dt (cached: dt is the same frame after frame).

    ``paper`` = (q, r, p0) mm^2, ``cv`` = (acceleration sigma mm/s^2, measurement sigma mm, initial velocity sigma
    mm/s), ``alpha_beta`` = (alpha, beta): FusionParams' values. Returns the kind's code, its linear model (F on
    the state rows, the covariance map and Q on the triangle, a new track's covariance), the measurement variance
    R and the alpha-beta gains (alpha, beta / dt).
    """
    if kind not in _KIND_CODES:
        raise ValueError(f"filter must be 'paper_kalman', 'cv_kalman', 'alpha_beta' or None, got {kind!r}")
    gains = np.zeros(2)
    if kind == "paper_kalman":  # A = I, Q = q I, R = r I; velocity and off-diagonal terms stay 0
        q, r, p0 = paper
        model = (_IDENTITY2, _IDENTITY3, np.array([q, 0.0, 0.0]), np.array([p0, 0.0, 0.0]))
    elif kind == "cv_kalman":
        accel_sigma, meas_sigma, velocity_sigma = cv
        cov_map, q_vec, state_map = _cv_model(dt, accel_sigma)
        model = (state_map, cov_map, q_vec, np.array([meas_sigma**2, 0.0, velocity_sigma**2]))
        r = meas_sigma**2
    else:  # X = Xp + V dt; P is not used
        model = (np.array([[1.0, dt], [0.0, 1.0]]), _IDENTITY3, _ZEROS3, _ZEROS3)
        r = 0.0
        gains = np.array([alpha_beta[0], alpha_beta[1] / dt])
    as_float = (np.array(m, dtype=np.float64) for m in model)  # writable copies: one kernel signature
    return _KIND_CODES[kind], (next(as_float), next(as_float), next(as_float), next(as_float)), float(r), gains


@lru_cache(maxsize=16)
def _cv_model(dt: float, accel_sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant-velocity model for one dt, cached (dt is the same frame after frame).

    Returns
    -------
    cov_map : (3, 3), ``P~ = P @ cov_map + q_vec`` on the triangle (p00, p01, p11) of F P F'.
    q_vec : (3,), the discrete white-noise acceleration Q = s^2 [dt^4/4, dt^3/2, dt^2].
    state_map : (2, 2), F = [[1, dt], [0, 1]] acting on the (position, velocity) rows of x.
    """
    cov_map = np.array([[1.0, 0.0, 0.0], [2.0 * dt, 1.0, 0.0], [dt * dt, dt, 1.0]])
    q = accel_sigma**2
    q_vec = np.array([q * dt**4 / 4.0, q * dt**3 / 2.0, q * dt * dt])
    state_map = np.array([[1.0, dt], [0.0, 1.0]])
    for array in (cov_map, q_vec, state_map):
        array.setflags(write=False)
    return cov_map, q_vec, state_map
