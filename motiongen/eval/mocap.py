"""The real-mocap row of the evaluation: BVH clips measured the way generated motion is."""

from __future__ import annotations

from pathlib import Path

from motiongen.bvh.retarget import import_bvh
from motiongen.errors import ConfigError
from motiongen import metrics as M
from motiongen.rates import DATA_FPS
from motiongen.skeleton import BODY


def mocap_body_metrics(paths, fps: float = DATA_FPS) -> dict:
    """The Body table's row for real mocap measured the same way: BVH clips through our
    importer (`motiongen.bvh.retarget.import_bvh`, 22 joints, y-up, 30 fps, lowest joint on the
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
        rows.append({**M.body_metrics(j, fps, BODY.parents), "jerk": M.mean_jerk(j, fps),
                     "floor_penetration_frames": M.floor_penetration(j)["frame_ratio"]})
    out = {k: M.finite_mean(r[k] for r in rows) for k in rows[0]}
    out["slide_mps"] = M.finite_median(r["slide_mps"] for r in rows)
    out["n_sequences"], out["files"] = len(files), [f.name for f in files]
    return out
