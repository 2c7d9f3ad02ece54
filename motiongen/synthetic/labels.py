"""Action vocabulary and contact labels computed from geometry.

A joint is in contact when its distance to the floor, a furniture box or a movable object,
minus the depth of the joint under the skin (body.tissue: the sole for ankles and toes), is
below a threshold. Nothing is hand-set: a seated pelvis is in contact because it is on the seat.
"""

from __future__ import annotations

import numpy as np

ACTIONS = ["walk", "stand", "sit", "lie down", "pick up", "carry"]
CONTACT_THRESHOLD = 0.05  # m beyond the skin


def action_rows(n: int, *names: str) -> np.ndarray:
    """(n, A) bool with the named actions set."""
    out = np.zeros((n, len(ACTIONS)), bool)
    for name in names:
        out[:, ACTIONS.index(name)] = True
    return out


def box_distance(p: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Distance (..., B) from points p (..., 3) to axis-aligned boxes (B, 2, 3); 0 inside."""
    d = np.maximum(np.maximum(boxes[:, 0] - p[..., None, :], p[..., None, :] - boxes[:, 1]), 0.0)
    return np.linalg.norm(d, axis=-1)


def contacts(joints: np.ndarray, tissue: np.ndarray, boxes: np.ndarray,
             obj_centres: np.ndarray, obj_radius: np.ndarray) -> np.ndarray:
    """(T, J) bool. joints (T, J, 3); tissue (J,); boxes (B, 2, 3); obj_centres (T, K, 3);
    obj_radius (K,) (objects as bounding spheres; K may be 0)."""
    dist = joints[..., 1].copy()                                               # floor, (T, J)
    T = len(joints)
    for s in range(0, T, 256):  # chunks bound the (t, J, B, 3) temporary
        dist[s:s + 256] = np.minimum(dist[s:s + 256], box_distance(joints[s:s + 256], boxes).min(-1))
    if obj_centres.shape[1]:
        d_obj = np.linalg.norm(joints[:, :, None] - obj_centres[:, None], axis=-1) - obj_radius  # (T, J, K)
        dist = np.minimum(dist, np.maximum(d_obj, 0.0).min(-1))
    return dist - tissue < CONTACT_THRESHOLD
