"""Check a `motiongen sample gltf=true` export in Blender: import motion.glb with Blender's own
glTF importer, step its animations, and measure how far the armatures' joints are from the
joints in motion.npz.

    python scripts/check_gltf_blender.py OUT/motion.glb OUT/motion.npz [frames...]
    blender -b -P scripts/check_gltf_blender.py -- OUT/motion.glb OUT/motion.npz

Needs Blender's Python module (`pip install bpy`: Blender as a module, for the Python version
its release names) or Blender itself, and numpy; not motiongen. Prints the largest distance
per sample and overall, in cm; exits 1 when it exceeds 1 cm.
"""

from __future__ import annotations

import sys

import bpy
import numpy as np
from mathutils import Vector

TOLERANCE_CM = 1.0


def import_motion(glb: str, fps: float) -> None:
    """An empty scene with the motion's frame rate, then the file: the importer keys each glTF
    time t at frame t * fps, so frame f is the npz's frame f."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = round(fps), round(fps) / fps
    bpy.ops.import_scene.gltf(filepath=glb)


def sample_armatures() -> dict[int, object]:
    """Sample index -> its armature object (glTF node `sample_<s>`), each playing its own
    animation: the importer makes only the first one active and stashes the others as NLA
    tracks, so each armature gets the action of its track."""
    out = {}
    for obj in bpy.data.objects:
        if obj.type != "ARMATURE" or not obj.name.startswith("sample_"):
            continue
        ad = obj.animation_data
        action = ad.action or next(s.action for t in ad.nla_tracks for s in t.strips)
        for track in ad.nla_tracks:
            track.mute = True                           # only the assigned action plays
        ad.action = action
        if hasattr(ad, "action_slot") and len(getattr(action, "slots", ())):
            ad.action_slot = action.slots[0]             # Blender >= 4.4: slotted actions
        out[int(obj.name.split("_")[1].split(".")[0])] = obj
    return out


def joints_at(arm, names: list[str]) -> np.ndarray:
    """(J, 3) the pose bones' heads in world space, Blender z-up -> the export's y-up."""
    heads = [arm.matrix_world @ Vector(arm.pose.bones[n].head) for n in names]
    return np.array([(h.x, h.z, -h.y) for h in heads])


def main(argv: list[str]) -> int:
    glb, npz = argv[0], argv[1]
    with np.load(npz) as z:
        joints, fps, names = z["joints"], float(z["fps"]), [str(n) for n in z["joint_names"]]
    T = joints.shape[1]
    frames = [int(f) for f in argv[2:]] or sorted({0, 1, T // 3, T // 2, (2 * T) // 3, T - 1})
    import_motion(glb, fps)
    arms = sample_armatures()
    worst = 0.0
    for s, arm in sorted(arms.items()):
        errs = []
        for f in frames:
            bpy.context.scene.frame_set(f)
            errs.append(np.linalg.norm(joints_at(arm, names) - joints[s, f], axis=-1).max())
        print(f"sample {s}: max joint distance {100 * max(errs):.4f} cm over frames {frames}")
        worst = max(worst, max(errs))
    print(f"{len(arms)} of {joints.shape[0]} samples, max joint distance {100 * worst:.4f} cm "
          f"(Blender {bpy.app.version_string})")
    return 0 if len(arms) == joints.shape[0] and 100 * worst <= TOLERANCE_CM else 1


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    sys.exit(main(args))
