"""Triangulate 3D keypoints from calibrated views: confidence-weighted DLT with outlier views
found by consensus, and a temporal check.

For one point seen by cameras c with undistorted normalised coordinates (x_c, y_c) and
camera matrices P_c = [R_c | t_c] (rows p1, p2, p3), the DLT stacks two rows per view,

    w_c (x_c p3 − p1) X = 0,   w_c (y_c p3 − p2) X = 0,      X homogeneous (4,),

and takes the right singular vector of the smallest singular value. w_c is the detection's
confidence (0 removes the view). Normalised coordinates instead of pixels keep the system
well conditioned (Hartley's normalisation, done by K⁻¹).

Least squares follows outliers: one wrong detection among four views moves the point by
decimetres, and then the wrong view is not always the one reprojecting worst. So with
`reject_px` set, every pair of views proposes a point (RANSAC over the C(C−1)/2 pairs,
exhaustively); the views reprojecting within `reject_px` of the best proposal (most
confidence in agreement) are its inliers, and the point is solved again from them alone. A
point whose views do not agree (fewer than `min_views` inliers) gets confidence 0. Two views
cannot expose an outlier that lies along the epipolar line (and with three views, one of
them such an outlier, two pairs agree equally well); `max_jump` catches most of those
afterwards: a point further than that from every prediction its nearest valid frames make
(`temporal_outliers`) is dropped.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from motiongen.capture.cameras import Cameras


@dataclass
class Triangulation:
    points: np.ndarray        # (T, J, 3) metres (0 where not triangulated)
    conf: np.ndarray          # (T, J) mean confidence of the views used; 0 = not triangulated
    views: np.ndarray         # (C, T, J) bool: views used
    error_px: np.ndarray      # (T, J) largest reprojection error over the views used (NaN if none)


def dlt(cams: Cameras, xy: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted DLT. xy (C, N, 2) undistorted normalised coordinates, w (C, N) weights ->
    points (N, 3) (NaN where fewer than two views have weight)."""
    P = np.concatenate([cams.R, cams.t[:, :, None]], -1)                       # (C, 3, 4)
    rows_x = xy[..., 0:1] * P[:, None, 2] - P[:, None, 0]                     # (C, N, 4)
    rows_y = xy[..., 1:2] * P[:, None, 2] - P[:, None, 1]

    def unit(r):    # unit rows first, so that the confidence is the only weighting
        return r / np.maximum(np.linalg.norm(r, axis=-1, keepdims=True), 1e-12) * w[..., None]

    A = np.concatenate([unit(rows_x), unit(rows_y)], 0).transpose(1, 0, 2)    # (N, 2C, 4)
    _, _, Vh = np.linalg.svd(A)
    Xh = Vh[:, -1]                                                             # (N, 4)
    ok = ((w > 0).sum(0) >= 2) & (np.abs(Xh[:, 3]) > 1e-12)
    out = np.full((len(Xh), 3), np.nan)
    out[ok] = Xh[ok, :3] / Xh[ok, 3:]
    return out


def reprojection_errors(cams: Cameras, X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Pixel distance (C, N) of points X (N, 3) from detections uv (C, N, 2); inf where a
    point is behind the camera or not finite."""
    proj, depth = cams.project_np(np.nan_to_num(X))                            # (N, C, 2), (N, C)
    err = np.linalg.norm(proj.transpose(1, 0, 2) - uv, axis=-1)
    return np.where((depth.T > 0) & np.isfinite(X).all(-1), err, np.inf)


def _consensus(cams: Cameras, xy, uv, w, reject_px: float) -> np.ndarray:
    """Inlier weights (C, N): the views agreeing with the best two-view proposal."""
    C, N = w.shape
    best_score = np.full(N, -1.0)
    best_err = np.full(N, np.inf)
    inliers = np.zeros((C, N), bool)
    for a, b in itertools.combinations(range(C), 2):
        pair = np.zeros_like(w)
        pair[[a, b]] = w[[a, b]]
        X = dlt(cams, xy, pair)
        err = reprojection_errors(cams, X, uv)                                 # (C, N)
        agree = (err <= reject_px) & (w > 0)
        score = (w * agree).sum(0)
        mean_err = np.where(agree, err, 0).sum(0) / np.maximum(agree.sum(0), 1)
        better = (score > best_score + 1e-9) | ((np.abs(score - best_score) <= 1e-9) & (mean_err < best_err))
        better &= agree[a] & agree[b]
        best_score = np.where(better, score, best_score)
        best_err = np.where(better, mean_err, best_err)
        inliers[:, better] = agree[:, better]
    return np.where(inliers, w, 0.0)


def _nearest_valid(valid: np.ndarray) -> tuple[np.ndarray, ...]:
    """For each (t, j): the two nearest valid frames before t and after t (−1 / T: none)."""
    T = len(valid)
    idx = np.where(valid, np.arange(T)[:, None], -1)
    before1 = np.maximum.accumulate(np.vstack([np.full((1, idx.shape[1]), -1), idx[:-1]]), 0)   # last valid < t
    ridx = np.where(valid, np.arange(T)[:, None], T)[::-1]
    after1 = np.minimum.accumulate(np.vstack([np.full((1, idx.shape[1]), T), ridx[:-1]]), 0)[::-1]   # first valid > t
    cols = np.arange(idx.shape[1])
    before2 = np.where(before1 >= 0, before1[np.clip(before1, 0, T - 1), cols], -1)
    after2 = np.where(after1 < T, after1[np.clip(after1, 0, T - 1), cols], T)
    return before1, before2, after1, after2


def temporal_outliers(points: np.ndarray, conf: np.ndarray, max_jump: float, max_gap: int = 5) -> np.ndarray:
    """(T, J) bool: triangulated points further than max_jump (m) from most predictions the
    nearest valid frames make: linear interpolation between a frame before and one after
    (the nearest two on each side, paired every way) and linear extrapolation from two frames
    on one side, all within max_gap frames. Smooth motion is within ~a·gap²/8 (centimetres)
    of them. An outlier among the neighbours spoils at most half of the predictions of a good
    point; a bad point agrees with at most a few (a majority vote, not the nearest: the wrong
    two-view points of one joint in consecutive frames often lie on one camera ray, so a
    prediction through a wrong neighbour can land on a wrong point)."""
    T = len(points)
    valid = conf > 0
    b1, b2, a1, a2 = _nearest_valid(valid)
    cols = np.arange(points.shape[1])[None]
    t = np.arange(T)[:, None].astype(float)

    def line(i, k, ok):
        """Points on the line through frames i and k (T, J) evaluated at t; NaN where not ok."""
        ii, kk = np.clip(i, 0, T - 1), np.clip(k, 0, T - 1)
        Pi, Pk = points[ii, cols], points[kk, cols]                               # (T, J, 3)
        s = ((t - ii) / np.where(kk != ii, kk - ii, 1))[..., None]
        return np.where(ok[..., None], Pi + s * (Pk - Pi), np.nan)

    def near(i):
        return (i >= 0) & (i < T) & (np.abs(i - t) <= max_gap)

    cands = [line(i, k, near(i) & near(k)) for i in (b1, b2) for k in (a1, a2)]     # interpolations
    cands += [line(b1, b2, near(b1) & near(b2)), line(a1, a2, near(a1) & near(a2))]  # extrapolations
    dist = np.linalg.norm(points[None] - np.stack(cands), axis=-1)                # (6, T, J)
    available = np.isfinite(dist).sum(0)
    agree = (dist <= max_jump).sum(0)                                             # NaN compares False
    return valid & (available > 0) & (2 * agree < available)


def triangulate(cams: Cameras, uv: np.ndarray, conf: np.ndarray, min_views: int = 2,
                reject_px: float | None = 30.0, max_jump: float | None = 0.1) -> Triangulation:
    """uv (C, T, J, 2) pixels, conf (C, T, J) -> `Triangulation` (see the module doc).
    reject_px None keeps every view (plain weighted DLT); max_jump None skips the temporal check."""
    C, T, J = conf.shape
    flat_uv = uv.reshape(C, T * J, 2)
    xy = cams.undistort(uv).reshape(C, T * J, 2)
    w = conf.reshape(C, T * J).astype(np.float64)
    min_views = max(2, int(min_views))
    if reject_px is not None and C > 2:
        w = _consensus(cams, xy, flat_uv, w, reject_px)
    X = dlt(cams, xy, w)
    err = np.where(w > 0, reprojection_errors(cams, X, flat_uv), -1.0)
    worst = err.max(0)
    used = w > 0
    n_used = used.sum(0)
    ok = np.isfinite(X).all(-1) & (n_used >= min_views)
    if reject_px is not None:
        ok &= worst <= reject_px
    c = np.where(ok, w.sum(0) / np.maximum(n_used, 1), 0.0).reshape(T, J)
    pts = np.where(ok[:, None], np.nan_to_num(X), 0.0).reshape(T, J, 3)
    if max_jump is not None:
        c = np.where(temporal_outliers(pts, c, max_jump), 0.0, c)
    e = np.where(n_used > 0, np.where(np.isfinite(worst), worst, np.nan), np.nan)
    return Triangulation(pts, c, used.reshape(C, T, J), e.reshape(T, J))
