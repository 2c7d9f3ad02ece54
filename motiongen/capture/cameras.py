"""Calibrated cameras (OpenCV conventions): load, validate, project, undistort.

A camera maps a world point X (metres, our y-up world) to pixels as OpenCV does:

    x_c = R X + t                        camera frame: x right, y down, z forward (optical axis)
    (x, y) = (x_c / z_c, y_c / z_c)      normalised image coordinates
    radial = 1 + k1 r² + k2 r⁴ + k3 r⁶,  r² = x² + y²
    x' = x·radial + 2 p1 x y + p2 (r² + 2x²),   y' = y·radial + p1 (r² + 2y²) + 2 p2 x y
    (u, v) = (fx x' + s y' + cx, fy y' + cy)    pixels, origin at the top-left pixel's centre

Files (`load_cameras`): JSON
    {"up": "+y", "units": "m",
     "cameras": [{"name": "cam0", "K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]],
                  "R": [[...], [...], [...]]  or  "rvec": [rx, ry, rz],
                  "t": [tx, ty, tz], "dist": [k1, k2, p1, p2, k3], "image_size": [w, h]}]}
or npz with `K` (C,3,3), `R` (C,3,3) or `rvec` (C,3), `t` (C,3), optional `dist` (C,0|4|5),
`names` (C,), `image_size` (C,2), `up`, `units`. `dist` and `image_size` are optional; `up`
(the calibration world's up axis, default "+y") is turned onto our +y by
`motiongen.geometry.up_rotation`, and `units` ("m", "cm" or "mm", default "m") scales `t`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from motiongen.errors import DataError
from motiongen.geometry import up_rotation

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
UPS = tuple(s + a for a in "xyz" for s in "+-")
UNDISTORT_ITERS = 20          # fixed-point iterations (OpenCV's undistortPoints uses 5 by default)


@dataclass
class Cameras:
    """C calibrated cameras in our world (y-up, metres)."""

    names: list[str]
    K: np.ndarray                 # (C, 3, 3) intrinsics
    R: np.ndarray                 # (C, 3, 3) world -> camera rotation
    t: np.ndarray                 # (C, 3) metres
    dist: np.ndarray              # (C, 5) k1, k2, p1, p2, k3 (zeros: no distortion)
    image_size: np.ndarray | None = None   # (C, 2) width, height in pixels
    world_from_file: np.ndarray | None = None   # (3, 3): the file's world axes -> ours
    unit: float = 1.0             # metres per file unit (for 3D points given in the file's world)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def centers(self) -> np.ndarray:
        """(C, 3) camera centres in the world: −Rᵀ t."""
        return -np.einsum("cji,cj->ci", self.R, self.t)

    def file_points_to_world(self, X: np.ndarray) -> np.ndarray:
        """3D points (..., 3) in the calibration file's world and units -> our world, metres."""
        U = np.eye(3) if self.world_from_file is None else self.world_from_file
        return (np.asarray(X, np.float64) * self.unit) @ U.T

    def tensors(self, dtype=torch.float32, device="cpu") -> dict[str, torch.Tensor]:
        return {k: torch.as_tensor(getattr(self, k), dtype=dtype, device=device) for k in ("K", "R", "t", "dist")}

    def project(self, X: torch.Tensor, cam: dict[str, torch.Tensor] | None = None):
        """World points X (..., 3) -> pixels (..., C, 2) and depths z_c (..., C) (differentiable).
        Points at z_c <= 0 are behind the camera: their pixels are meaningless, mask them by depth."""
        c = cam if cam is not None else self.tensors(X.dtype, X.device)
        xc = torch.einsum("cij,...j->...ci", c["R"], X) + c["t"]            # (..., C, 3)
        z = xc[..., 2]
        zs = torch.where(z > 1e-6, z, torch.full_like(z, 1e-6))
        x, y = xc[..., 0] / zs, xc[..., 1] / zs
        xd, yd = _distort(x, y, c["dist"])
        K = c["K"]
        u = K[:, 0, 0] * xd + K[:, 0, 1] * yd + K[:, 0, 2]
        v = K[:, 1, 1] * yd + K[:, 1, 2]
        return torch.stack([u, v], -1), z

    def project_np(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Numpy version of `project` (float64): (..., 3) -> (..., C, 2), (..., C)."""
        with torch.no_grad():
            uv, z = self.project(torch.as_tensor(np.asarray(X), dtype=torch.float64), self.tensors(torch.float64))
        return uv.numpy(), z.numpy()

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (C, ..., 2) -> undistorted normalised coordinates (C, ..., 2) (the inverse of
        the distortion by fixed-point iteration, as OpenCV's undistortPoints)."""
        uv = np.asarray(uv, np.float64)
        shape = uv.shape
        C = shape[0]
        p = uv.reshape(C, -1, 2)
        K = self.K
        yd = (p[..., 1] - K[:, None, 1, 2]) / K[:, None, 1, 1]
        xd = (p[..., 0] - K[:, None, 0, 2] - K[:, None, 0, 1] * yd) / K[:, None, 0, 0]
        if not np.any(self.dist):
            return np.stack([xd, yd], -1).reshape(shape)
        k1, k2, p1, p2, k3 = (self.dist[:, i, None] for i in range(5))
        x, y = xd.copy(), yd.copy()
        for _ in range(UNDISTORT_ITERS):
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            x = (xd - (2 * p1 * x * y + p2 * (r2 + 2 * x * x))) / radial
            y = (yd - (p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)) / radial
        return np.stack([x, y], -1).reshape(shape)

    def subset(self, idx) -> "Cameras":
        idx = list(idx)
        return Cameras([self.names[i] for i in idx], self.K[idx], self.R[idx], self.t[idx], self.dist[idx],
                       None if self.image_size is None else self.image_size[idx], self.world_from_file, self.unit)


def _distort(x, y, dist):
    """OpenCV radial-tangential distortion of normalised coordinates (..., C)."""
    k1, k2, p1, p2, k3 = dist.unbind(-1)                                    # (C,) each
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


# ---- files -------------------------------------------------------------------------------

def load_cameras(path: str | Path) -> Cameras:
    """Read and validate a camera file (JSON or npz; see the module doc). Raises DataError
    naming the file, the camera and the field."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "camera file does not exist")
    if path.suffix.lower() == ".json":
        entries, up, units = _read_json(path)
    else:
        entries, up, units = _read_npz(path)
    if not entries:
        raise DataError(path, "cameras", "no cameras")
    up = "+" + str(up) if str(up) in ("x", "y", "z") else up
    if str(up) not in UPS:
        raise DataError(path, "up", f"expected one of {', '.join(UPS)}, found {up!r}")
    if str(units) not in UNITS:
        raise DataError(path, "units", f"expected one of {', '.join(UNITS)}, found {units!r}")
    U = up_rotation(str(up))
    scale = UNITS[str(units)]
    names, Ks, Rs, ts, ds, sizes = [], [], [], [], [], []
    for i, e in enumerate(entries):
        name = str(e.get("name", f"cam{i}"))
        where = f"cameras[{i}] ({name})"
        K = _array(path, f"{where}.K", e.get("K"), (3, 3))
        if not (K[0, 0] > 0 and K[1, 1] > 0 and K[1, 0] == 0 and np.allclose(K[2], [0, 0, 1])):
            raise DataError(path, f"{where}.K", "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        if e.get("R") is not None:
            R = _array(path, f"{where}.R", e["R"], (3, 3))
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
                raise DataError(path, f"{where}.R", "not a rotation matrix (orthonormal, det +1)")
        elif e.get("rvec") is not None:
            R = Rotation.from_rotvec(_array(path, f"{where}.rvec", e["rvec"], (3,))).as_matrix()
        else:
            raise DataError(path, f"{where}.R", "missing: give R (3x3) or rvec (Rodrigues, 3)")
        t = _array(path, f"{where}.t", e.get("t"), (3,))
        d = np.zeros(5)
        if e.get("dist") is not None:
            dv = np.asarray(e["dist"], np.float64).reshape(-1)
            if dv.size not in (0, 4, 5) or not np.isfinite(dv).all():
                raise DataError(path, f"{where}.dist", f"expected 0, 4 or 5 finite OpenCV coefficients "
                                                       f"(k1, k2, p1, p2[, k3]), found {dv.size}")
            d[:dv.size] = dv
        size = None if e.get("image_size") is None else _array(path, f"{where}.image_size", e["image_size"], (2,))
        names.append(name)
        Ks.append(K)
        Rs.append(R @ U.T)          # x_c = R X_file + t = (R Uᵀ) X_ours + t
        ts.append(t * scale)
        ds.append(d)
        sizes.append(size)
    if len(set(names)) != len(names):
        raise DataError(path, "name", "camera names must be unique")
    image_size = None if any(s is None for s in sizes) else np.stack(sizes)
    return Cameras(names, np.stack(Ks), np.stack(Rs), np.stack(ts), np.stack(ds), image_size, U, scale)


def save_cameras(path: str | Path, cams: Cameras) -> Path:
    """Write cameras as the JSON layout (our world: up +y, metres)."""
    path = Path(path)
    out = {"up": "+y", "units": "m", "cameras": []}
    for i, n in enumerate(cams.names):
        e = {"name": n, "K": cams.K[i].tolist(), "R": cams.R[i].tolist(), "t": cams.t[i].tolist(),
             "dist": cams.dist[i].tolist()}
        if cams.image_size is not None:
            e["image_size"] = cams.image_size[i].tolist()
        out["cameras"].append(e)
    path.write_text(json.dumps(out, indent=1))
    return path


def _array(path, field, value, shape) -> np.ndarray:
    if value is None:
        raise DataError(path, field, f"missing (expected shape {shape})")
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise DataError(path, field, f"expected numbers of shape {shape}") from None
    if a.shape != shape and a.size == int(np.prod(shape)):
        a = a.reshape(shape)                      # t as (3, 1), as cv2 writes it
    if a.shape != shape:
        raise DataError(path, field, f"expected shape {shape}, found {a.shape}")
    if not np.isfinite(a).all():
        raise DataError(path, field, "non-finite value (NaN or inf)")
    return a


def _read_json(path: Path):
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(path, None, f"not readable JSON ({type(e).__name__}: {e})") from None
    if isinstance(doc, list):
        doc = {"cameras": doc}
    if not isinstance(doc, dict) or not isinstance(doc.get("cameras"), list):
        raise DataError(path, "cameras", "expected an object with a list 'cameras'")
    if not all(isinstance(e, dict) for e in doc["cameras"]):
        raise DataError(path, "cameras", "every camera must be an object")
    return doc["cameras"], doc.get("up", "+y"), doc.get("units", "m")


def _read_npz(path: Path):
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as e:       # zipfile / format errors of all kinds
        raise DataError(path, None, f"not a readable .npz or .json camera file ({type(e).__name__}: {e})") from None
    with z:
        d = {k: z[k] for k in z.files}
    if "K" not in d:
        raise DataError(path, "K", f"required array is missing (found: {', '.join(sorted(d))})")
    C = len(d["K"]) if d["K"].ndim == 3 else 0
    if C == 0:
        raise DataError(path, "K", f"expected (C, 3, 3), found {d['K'].shape}")
    for k in ("R", "rvec", "t", "dist", "names", "image_size"):
        if k in d and len(d[k]) != C:
            raise DataError(path, k, f"expected {C} entries (one per camera, like K), found {len(d[k])}")
    entries = [{k: (d[k][i].tolist() if k != "names" else str(d[k][i])) for k in
                ("K", "R", "rvec", "t", "dist", "names", "image_size") if k in d} for i in range(C)]
    for e in entries:
        if "names" in e:
            e["name"] = e.pop("names")
    up = str(d["up"]) if "up" in d else "+y"
    units = str(d["units"]) if "units" in d else "m"
    return entries, up, units
