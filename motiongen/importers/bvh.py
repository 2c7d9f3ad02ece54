"""Convert BVH files into a motiongen dataset (one sequence per file).

    motiongen import-bvh inputs=[a.bvh,b.bvh] out=DIR [mapping=FILE]
        [scene=GRID_STEM] [scene_id=0] [split=train] [unit=cm] [up=z] [fps=30] [action=walk] [overwrite=true]

Joints are mapped onto the 22 SMPL-X body joints (built-in CMU / Biovision / Mixamo / SMPL-X
layouts, or mapping=FILE: JSON {our_joint_name: bvh_joint_name}), converted to metres and
y-up (unit and up axis detected from the motion unless unit= / up= are given), resampled to
`fps`, and the lowest joint of each clip put on y = 0. A clip that does not look like a
standing human afterwards is refused (one line naming the file, exit 2, nothing written).
Without scene=, the clips share scene `scene_id` with an empty grid covering them (the floor
is the grid's bottom face: below it counts as occupied in scene queries). All clips go to
`split`.
Contact labels: a foot joint touches the floor when it is low (toes < 5 cm, ankles < 12 cm)
and slow (< 0.3 m/s). Actions: none, or action=NAME labels every frame with NAME.
User mistakes print one line and exit with status 2.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motiongen.checks import require_fps
from motiongen.cli import parse_key_values, tool_main
from motiongen.bvh.detect import UNITS
from motiongen.bvh.retarget import import_bvh, load_mapping
from motiongen.bvh.detect import parse_up
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.errors import ConfigError, MotiongenError
from motiongen.output_lock import refuse_output_over_input
from motiongen.rates import DATA_FPS
from motiongen.skeleton import BODY, LEFT_FOOT_JOINTS, RIGHT_FOOT_JOINTS

# (joint, height threshold m): toes touch lower than ankles.
CONTACT_HEIGHT = {LEFT_FOOT_JOINTS[0]: 0.12, RIGHT_FOOT_JOINTS[0]: 0.12,
                  LEFT_FOOT_JOINTS[1]: 0.05, RIGHT_FOOT_JOINTS[1]: 0.05}
CONTACT_SPEED = 0.3   # m/s
EMPTY_GRID_VOXEL = 0.05
EMPTY_GRID_HEIGHT = 2.0


SPEC = {"inputs": (list, []), "out": (str, None), "mapping": (str, None), "scene": (str, None), "scene_id": (int, 0),
        "split": (str, "train"), "unit": (str, None), "up": (str, None), "fps": (float, DATA_FPS), "action": (str, None),
        "overwrite": (bool, False)}
USAGE = "inputs=[a.bvh,b.bvh] out=DIR [mapping=FILE]"


def parse_args(argv: list[str]) -> dict:
    return parse_key_values(argv, SPEC, required=("inputs", "out"), usage=USAGE, doc=__doc__)


def foot_contact(joints: np.ndarray, fps: float) -> np.ndarray:
    """(T, 22) bool floor contact of the foot joints from height and speed (see module doc)."""
    T = len(joints)
    contact = np.zeros((T, joints.shape[1]), bool)
    vel = np.gradient(joints, axis=0) * fps if T > 1 else np.zeros_like(joints)   # (T, J, 3)
    speed = np.linalg.norm(vel, axis=-1)
    for j, h in CONTACT_HEIGHT.items():
        contact[:, j] = (joints[:, j, 1] < h) & (speed[:, j] < CONTACT_SPEED)
    return contact


def empty_grid(motions: list[np.ndarray], margin: float = 1.0) -> OccupancyGrid:
    """An all-free grid over the clips' ground extent (+ margin), from the floor up 2 m."""
    pts = np.concatenate([m.reshape(-1, 3) for m in motions])
    lo = np.array([pts[:, 0].min() - margin, 0.0, pts[:, 2].min() - margin])
    hi = np.array([pts[:, 0].max() + margin, EMPTY_GRID_HEIGHT, pts[:, 2].max() + margin])
    shape = np.ceil((hi - lo) / EMPTY_GRID_VOXEL).astype(int)
    return OccupancyGrid.from_dense(np.zeros(shape, bool), lo, EMPTY_GRID_VOXEL)


def run(args: dict[str, str]) -> Path:
    inputs = args["inputs"]
    if not inputs:
        raise ConfigError("inputs=[]: give at least one BVH file")
    refuse_over_sources(args)
    mapping = load_mapping(args["mapping"]) if args.get("mapping") else None
    fps = require_fps("fps", args["fps"])        # the output rate: 1e9 asked for billions of frames
    unit = args.get("unit") or None
    if unit is not None and unit not in UNITS:
        raise ConfigError(f"unit={unit!r}: expected one of {list(UNITS)}")
    up = args.get("up") or None
    if up is not None:
        try:
            up = parse_up(up)
        except MotiongenError:
            raise ConfigError(f"up={up!r}: expected x, y or z with an optional sign (e.g. z, -y)") from None

    motions = load_clips(inputs, lambda path: import_bvh(path, mapping, fps=fps, unit=unit, up=up))
    info = [{"name": name, "file": str(path), "layout": m.layout, "unit": m.unit, "unit_from": m.unit_from,
             "up_axis": m.up_axis, "up_from": m.up_from, "height_m": round(m.height, 4), "source_fps": m.source_fps}
            for (name, m), path in zip(motions, inputs)]
    return write_clips(args, motions, fps, source="bvh", extra={"bvh_import": info})


def refuse_over_sources(args: dict) -> None:
    """The dataset written at out= (replacing what is there with overwrite=true) may not be,
    hold or lie inside any file the import reads."""
    refuse_output_over_input(args["out"], [*args["inputs"], args.get("mapping"), args.get("scene"),
                                           args.get("body_model")], "out")


def load_clips(inputs: list, load) -> list[tuple[str, object]]:
    """(name, load(path)) per input file, named by the file's stem (made unique with _1, _2, ...)."""
    clips, names = [], set()
    for path in inputs:
        m = load(path)
        name, k = Path(path).stem, 1
        while name in names:
            name, k = f"{Path(path).stem}_{k}", k + 1
        names.add(name)
        clips.append((name, m))
    return clips


def write_clips(args: dict, clips: list[tuple[str, object]], fps: float, source: str, extra: dict,
                smplx: bool = False) -> Path:
    """Write imported clips (each with `.joints` (T, 22, 3), and `.params` SMPL-X fields when
    `smplx`) as one scene of a dataset: the scene= grid or an empty one over the clips, every
    frame labelled with action= if given, floor contact from the joints, all in split=.
    Nothing is left behind on failure (the writer aborts)."""
    scene_id = args["scene_id"]
    grid = OccupancyGrid.load(args["scene"]) if args.get("scene") else empty_grid([m.joints for _, m in clips])
    vocab = [args["action"]] if args.get("action") else []
    w = DatasetWriter(args["out"], joint_set=BODY, actions=vocab, fps=fps, has_smplx=smplx,
                      overwrite=args["overwrite"])
    try:
        w.add_scene(scene_id, grid=grid, name=Path(args["scene"]).name if args.get("scene") else "empty_floor")
        for name, m in clips:
            T = len(m.joints)
            w.add_sequence(name, scene=scene_id, joints=m.joints.astype(np.float32),
                           actions=np.ones((T, len(vocab)), bool), contact=foot_contact(m.joints, fps),
                           smplx=m.params if smplx else None)
        splits = {s: [] for s in ("train", "val", "test")}
        splits[args["split"]] = [scene_id]
        return w.finish(splits=splits, source=source, extra=extra)
    except BaseException:
        w.abort()
        raise


main = tool_main(lambda argv: run(parse_args(argv)), lambda root: print(f"wrote {root}"))


if __name__ == "__main__":
    main()
