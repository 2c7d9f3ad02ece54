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
cannot expose an outlier that lies along the epipolar line; `max_jump` catches most of those
afterwards: a point further than that from every prediction of its ±2 neighbouring frames
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


def temporal_outliers(points: np.ndarray, conf: np.ndarray, max_jump: float) -> np.ndarray:
    """(T, J) bool: triangulated points further than max_jump (m) from every prediction their
    neighbours make: the midpoints (X_{t−k} + X_{t+k}) / 2 for k = 1, 2 and the linear
    extrapolations 2X_{t±1} − X_{t±2}. Smooth motion is within a·Δt² (~1 cm) of all of them;
    an outlier at t is far from all; an outlier among the neighbours spoils only some."""
    P = np.where(conf[..., None] > 0, points, np.nan)                             # (T, J, 3)
    pad = np.pad(P, ((2, 2), (0, 0), (0, 0)), constant_values=np.nan)
    T = len(P)

    def at(k):                                                                     # X_{t+k}, (T, J, 3)
        return pad[2 + k:2 + k + T]

    cands = np.stack([(at(-1) + at(1)) / 2, (at(-2) + at(2)) / 2, 2 * at(1) - at(2), 2 * at(-1) - at(-2)])
    dist = np.linalg.norm(P[None] - cands, axis=-1)                                # (4, T, J)
    near = np.where(np.isfinite(dist), dist, np.inf).min(0)
    return (conf > 0) & np.isfinite(near) & (near > max_jump)


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
