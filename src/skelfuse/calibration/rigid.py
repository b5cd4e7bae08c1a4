"""Least-squares rigid fits between corresponding 3D points, plain and robust (pure numpy).

Cycle: corresponding points ``source`` (N, 3) and ``target`` (N, 3), mm, in two frames →
:func:`fit_rigid` (closed form, Arun / Kabsch / Umeyama without scale) → ``target ≈ R @ source + t``;
:func:`fit_rigid_ransac` wraps it for data with outliers: RANSAC on minimal 3-point samples, then a
trimmed refinement on the points within a final threshold.

Both fixes of the paper's errata are applied:

* the translation is ``t = mean_target - R @ mean_source`` (the paper's text drops ``R``);
* the SVD rotation is forced to a proper rotation (det +1): ``R = U diag(1, 1, det(U V')) V'``. Without it,
  coplanar or very noisy points can give a reflection, which would mirror every skeleton (Arun et al. 1987,
  Umeyama 1991).

References
----------
K. S. Arun, T. S. Huang, S. D. Blostein, "Least-Squares Fitting of Two 3-D Point Sets", IEEE PAMI 9(5), 1987.
S. Umeyama, "Least-Squares Estimation of Transformation Parameters Between Two Point Patterns", IEEE PAMI
13(4), 1991.
M. A. Fischler, R. C. Bolles, "Random Sample Consensus", CACM 24(6), 1981.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.transform import make_transform
from skelfuse.schema.errors import CalibrationError

_DEGENERATE_SPREAD_MM = 1e-6
"""A 3-point RANSAC sample whose second singular value (centred) is below this is collinear: skipped."""


@dataclass(frozen=True)
class RigidFit:
    """A rigid transform ``target ≈ R @ source + t`` and how well it fits.

    Attributes
    ----------
    R : (3, 3) float64, proper rotation (det +1).
    t : (3,) float64, translation, mm.
    rms_mm : float
        Root-mean-square distance ``|R @ source + t - target|`` over the points used in the fit (weighted
        by the weights where given), mm.
    n : int
        Number of points the fit used (inliers, for the robust fit).
    inliers : (N,) bool or None
        For :func:`fit_rigid_ransac`: which of the N input points the final fit used. None for
        :func:`fit_rigid`, which uses every point.
    """

    R: np.ndarray
    t: np.ndarray
    rms_mm: float
    n: int
    inliers: np.ndarray | None = None

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous ``target_from_source``."""
        return make_transform(self.R, self.t)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) source points → target frame, mm."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t


def _check_pairs(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or dst.shape != src.shape:
        raise ValueError(f"source and target must both have shape (N, 3), got {src.shape} and {dst.shape}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("source and target must be finite; drop missing (NaN) points before fitting")
    return src, dst


def _kabsch(src: np.ndarray, dst: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched weighted Kabsch. src, dst (..., N, 3), w (..., N) summing to > 0 → R (..., 3, 3), t (..., 3)."""
    wsum = w.sum(axis=-1, keepdims=True)
    mean_src = (w[..., None] * src).sum(axis=-2) / wsum
    mean_dst = (w[..., None] * dst).sum(axis=-2) / wsum
    # Cov = sum_i w_i (dst_i - mean_dst)(src_i - mean_src)'  so that R = argmax tr(R' Cov)
    cov = np.einsum("...n,...ni,...nj->...ij", w, dst - mean_dst[..., None, :], src - mean_src[..., None, :])
    U, _, Vt = np.linalg.svd(cov)
    # Reflection fix (the paper's erratum): flip the axis of the smallest singular value when det(U V') = -1.
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    D = np.zeros(cov.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = U @ D @ Vt
    # t = mean_target - R mean_source (the paper's text drops R: erratum).
    t = mean_dst - np.einsum("...ij,...j->...i", R, mean_src)
    return R, t


def fit_rigid(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> RigidFit:
    """Least-squares rigid transform with ``target ≈ R @ source + t`` (no scale).

    Minimizes ``sum_i w_i |R source_i + t - target_i|^2`` in closed form (SVD of the weighted
    cross-covariance), with the reflection fix and ``t = mean_target - R mean_source``.

    Parameters
    ----------
    source : (N, 3) array, mm
        Points in the source frame (e.g. a subordinate sensor).
    target : (N, 3) array, mm
        The same physical points in the target frame (e.g. the master sensor), row for row.
    weights : (N,) array or None
        Non-negative weight per pair; None weighs all equally.

    Returns
    -------
    RigidFit with ``inliers=None``.

    Raises
    ------
    ValueError
        Wrong shapes, non-finite values, negative weights.
    CalibrationError
        Fewer than 3 points with positive weight, or all of them on one line (rotation about that line is
        undetermined): collect points that spread in at least two directions.
    """
    src, dst = _check_pairs(source, target)
    if weights is None:
        w = np.ones(len(src))
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (len(src),):
            raise ValueError(f"weights must have shape ({len(src)},), got {w.shape}")
        if not np.isfinite(w).all() or (w < 0).any():
            raise ValueError("weights must be finite and non-negative")
    used = w > 0
    if used.sum() < 3:
        raise CalibrationError(
            f"a rigid fit needs at least 3 corresponding points with positive weight, got {int(used.sum())}"
        )
    centred = src[used] - np.average(src[used], axis=0, weights=w[used])
    spread = np.linalg.svd(centred * np.sqrt(w[used])[:, None] / np.sqrt(w[used].sum()), compute_uv=False)
    if spread[1] <= _DEGENERATE_SPREAD_MM * max(spread[0], 1.0):
        raise CalibrationError(
            f"the {int(used.sum())} source points lie on one line (spread {spread[0]:.1f} mm along it, "
            f"{spread[1]:.2g} mm across): the rotation about that line is undetermined; collect points that "
            "spread in at least two directions"
        )
    R, t = _kabsch(src, dst, w)
    resid = np.linalg.norm(src @ R.T + t - dst, axis=1)
    rms = float(np.sqrt(np.sum(w * resid**2) / w.sum()))
    return RigidFit(R=R, t=t, rms_mm=rms, n=int(used.sum()))


def fit_rigid_ransac(
    source: np.ndarray,
    target: np.ndarray,
    *,
    threshold_mm: float,
    iterations: int = 500,
    min_inliers: int = 3,
    rng: np.random.Generator,
    trim_fraction: float = 0.1,
    refine_iterations: int = 5,
    weights: np.ndarray | None = None,
) -> RigidFit:
    """Robust rigid fit ``target ≈ R @ source + t``: RANSAC, then a trimmed least-squares refinement.

    1. ``iterations`` minimal samples of 3 points (collinear samples skipped), each fitted in closed form
       (vectorized over samples); a hypothesis scores the number of points within ``threshold_mm``, ties
       broken by the smaller sum of truncated residuals (MSAC).
    2. Refinement, ``refine_iterations`` times: the inliers of the current fit (residual <
       ``threshold_mm``) minus the worst ``trim_fraction`` of them are refitted with :func:`fit_rigid`.
       Trimming guards against outliers that happen to fall just inside the threshold; refitting lets the
       inlier set follow the improving fit. Stops early when the set no longer changes.

    Parameters
    ----------
    source, target : (N, 3) arrays, mm, corresponding row for row.
    threshold_mm : float
        Inlier distance ``|R source + t - target|``, mm. Pick about 3x the expected residual of a good point.
    iterations : int
        RANSAC samples. With an inlier share w, the chance of never drawing an all-inlier sample is
        (1 - w^3)^iterations: 500 samples leave 1e-12 at w = 0.6 and 1.7e-4 at w = 0.3.
    min_inliers : int
        Fewest inliers an acceptable fit may have (at least 3).
    rng : numpy Generator, for the samples (seeded by the caller: results are reproducible).
    trim_fraction : float in [0, 0.5)
        Share of the worst inliers dropped at each refinement step.
    refine_iterations : int
        Refinement steps (0: return the refit of the best hypothesis' inliers).
    weights : (N,) array or None
        Per-point weights for the refinement fits (RANSAC scoring ignores them).

    Returns
    -------
    RigidFit whose ``inliers`` is the (N,) mask of points the final fit used; ``rms_mm`` is over those.

    Raises
    ------
    ValueError
        Bad shapes or parameters.
    CalibrationError
        Fewer than 3 points, every sample degenerate, or fewer than ``min_inliers`` inliers: the two point
        sets do not match under any rigid motion within ``threshold_mm`` (check that the frames correspond
        and that the threshold suits the noise).
    """
    src, dst = _check_pairs(source, target)
    if not threshold_mm > 0:
        raise ValueError(f"threshold_mm must be positive, got {threshold_mm}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if not 0 <= trim_fraction < 0.5:
        raise ValueError(f"trim_fraction must be in [0, 0.5), got {trim_fraction}")
    min_inliers = max(int(min_inliers), 3)
    n = len(src)
    if n < 3:
        raise CalibrationError(f"a rigid fit needs at least 3 corresponding points, got {n}")
    w = None if weights is None else np.asarray(weights, dtype=np.float64)

    best_key: tuple[int, float] = (-1, np.inf)
    best_R, best_t = np.eye(3), np.zeros(3)
    chunk = max(1, min(iterations, 4_000_000 // max(n, 1)))  # bound the (chunk, N) residual matrix
    done = 0
    while done < iterations:
        m = min(chunk, iterations - done)
        done += m
        idx = np.stack([rng.choice(n, size=3, replace=False) for _ in range(m)])
        s, d = src[idx], dst[idx]
        spread = np.linalg.svd(s - s.mean(axis=1, keepdims=True), compute_uv=False)[:, 1]
        ok = spread > max(_DEGENERATE_SPREAD_MM, 1e-3 * threshold_mm)
        if not ok.any():
            continue
        R, t = _kabsch(s[ok], d[ok], np.ones(s[ok].shape[:2]))
        # (K, N) residuals; matmul and a two-operand einsum, not one three-index einsum (4x faster: BLAS).
        offset = src @ R.transpose(0, 2, 1) + (t[:, None, :] - dst[None])
        resid = np.sqrt(np.einsum("kni,kni->kn", offset, offset))
        inlier = resid < threshold_mm
        count = inlier.sum(axis=1)
        cost = np.minimum(resid, threshold_mm).sum(axis=1)
        k = int(np.lexsort((cost, -count))[0])
        key = (int(count[k]), float(cost[k]))
        if key[0] > best_key[0] or (key[0] == best_key[0] and key[1] < best_key[1]):
            best_key, best_R, best_t = key, R[k], t[k]
    if best_key[0] < 0:
        raise CalibrationError(
            f"every RANSAC sample of the {n} source points was collinear: the points lie on one line; "
            "collect points that spread in at least two directions"
        )

    mask = np.linalg.norm(src @ best_R.T + best_t - dst, axis=1) < threshold_mm
    if mask.sum() < min_inliers:
        raise CalibrationError(
            f"robust rigid fit: best hypothesis has {int(mask.sum())} of {n} points within {threshold_mm:g} mm, "
            f"fewer than the {min_inliers} required; check that the two point sets correspond (same frames, "
            "same joints) and that threshold_mm suits the noise"
        )
    return refine_rigid_trimmed(
        src,
        dst,
        best_R,
        best_t,
        threshold_mm=threshold_mm,
        trim_fraction=trim_fraction,
        iterations=refine_iterations,
        min_inliers=min_inliers,
        weights=w,
    )


def refine_rigid_trimmed(
    source: np.ndarray,
    target: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    *,
    threshold_mm: float,
    trim_fraction: float = 0.1,
    iterations: int = 5,
    min_inliers: int = 3,
    weights: np.ndarray | None = None,
) -> RigidFit:
    """Trimmed least-squares refinement of a rigid fit from a starting estimate ``(R, t)``.

    Each step keeps the points within ``threshold_mm`` of the current fit, drops the worst ``trim_fraction``
    of them and refits with :func:`fit_rigid`; it stops after ``iterations`` steps or when the kept set no
    longer changes. The first step always refits (``iterations=0`` refits the inliers of ``(R, t)`` once).

    Returns
    -------
    RigidFit with ``inliers`` = the (N,) mask the final fit used.

    Raises
    ------
    CalibrationError
        Fewer than ``max(min_inliers, 3)`` points within ``threshold_mm`` of the starting estimate.
    """
    src, dst = _check_pairs(source, target)
    w = None if weights is None else np.asarray(weights, dtype=np.float64)
    min_inliers = max(int(min_inliers), 3)

    def kept_by(fit_R: np.ndarray, fit_t: np.ndarray, trim: bool) -> np.ndarray:
        resid = np.linalg.norm(src @ fit_R.T + fit_t - dst, axis=1)
        keep = resid < threshold_mm
        n_drop = int(np.floor(trim_fraction * keep.sum())) if trim else 0
        if n_drop and keep.sum() - n_drop >= min_inliers:
            worst = np.flatnonzero(keep)[np.argsort(resid[keep])[-n_drop:]]
            keep[worst] = False
        return keep

    used = kept_by(np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64), trim=False)
    if used.sum() < min_inliers:
        raise CalibrationError(
            f"rigid refinement: {int(used.sum())} of {len(src)} points lie within {threshold_mm:g} mm of the "
            f"starting estimate, fewer than the {min_inliers} required; the estimate is too far off"
        )
    fit = fit_rigid(src[used], dst[used], None if w is None else w[used])
    for _ in range(iterations):
        keep = kept_by(fit.R, fit.t, trim=True)
        if keep.sum() < min_inliers or np.array_equal(keep, used):
            break
        try:
            fit = fit_rigid(src[keep], dst[keep], None if w is None else w[keep])
        except CalibrationError:
            break
        used = keep
    return RigidFit(R=fit.R, t=fit.t, rms_mm=fit.rms_mm, n=int(used.sum()), inliers=used)


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix (or of the difference ``R_a @ R_b.T`` of two), degrees, in [0, 180]."""
    cos = (np.trace(np.asarray(R, dtype=np.float64)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
