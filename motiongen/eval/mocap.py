"""The real-mocap row of the evaluation: BVH clips measured the way generated motion is."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motiongen.data.bvh import import_bvh
from motiongen.errors import ConfigError
from motiongen.eval import metrics as M
from motiongen.skeleton import BODY


def _finite(xs) -> np.ndarray:
    return np.asarray([x for x in xs if x is not None and np.isfinite(x)], np.float64)


def mocap_body_metrics(paths, fps: float = 30.0) -> dict:
    """The Body table's row for real mocap measured the same way: BVH clips through our
    importer (`motiongen.data.bvh.import_bvh`, 22 joints, y-up, 30 fps, lowest joint on the
    floor), per-clip metrics averaged (grounded slide: median over clips). paths: BVH files or
    folders of them. Scene metrics are n/a (no scene)."""
    files = []
    for p in paths:
        p = Path(p)
        files += sorted(p.glob("*.bvh")) if p.is_dir() else [p]
    if not files:
        raise ConfigError(f"mocap: no .bvh files in {[str(p) for p in paths]}")
    rows = []
    for f in files:
        j = import_bvh(f, fps=fps).joints
        b = M.bone_consistency(j, BODY.parents)
        rows.append({"bone_cv": b.cv_median, "bone_max_dev": b.max_deviation, "slide_mps": M.grounded_slide(j, fps),
                     "foot_skating": M.foot_skating_ratio(j, fps), "jerk": M.mean_jerk(j, fps),
                     "floor_penetration_frames": M.floor_penetration(j)["frame_ratio"]})
    out = {k: float(_finite(r[k] for r in rows).mean()) for k in rows[0]}
    out["slide_mps"] = float(np.median(_finite(r["slide_mps"] for r in rows)))
    out["n_sequences"], out["files"] = len(files), [f.name for f in files]
    return out
