"""The evaluation protocol: the TRUMANS supplement's static and dynamic settings (A.1).

* Static: per test scene, `pairs` start/end pairs on free floor; some end at a real sit spot
  (taken from the scene's own motion data: pelvis of the middle frame of each "sit" segment)
  with the sit action. Midpoints come from A* (`sampling.goals.plan_route`).
* Dynamic: per test scene, `pairs` (object, human start) pairs: the object is one the data
  interacts with ("pick up" segments: the object nearest the hands at the segment's start,
  at its pose there), the route ends where the data's pelvis stood during the interaction,
  and the goal carries the interaction action. Objects are placed through `generate(objects=)`.
* Each pair is sampled k times in one batch (`num_samples=k`); every metric of
  `motiongen.eval.metrics` is computed per sample (APD per pair) and averaged.
* The reference row applies the same metrics to the dataset's own motion in the same scenes.

Pairs depend only on (seed, scene id, setting): evaluating a subset of scenes gives the same
pairs for those scenes. Diffusion noise is seeded per pair the same way.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from motiongen.errors import ConfigError
from motiongen.eval import metrics as M
from motiongen.routing import walkable_map
from motiongen.sampling.goals import Goal, Route, plan_route
from motiongen.skeleton import LEFT_HIP, PELVIS, RIGHT_HIP, joint_set_for
from motiongen.spans import true_runs

SETTINGS = ("static", "dynamic")
MAX_ACTION_SECONDS = 10.0
HAND_NAMES = ("left_wrist", "right_wrist", "left_index1", "right_index1")
_SETTING_CODE = {"static": 0, "dynamic": 1}


@dataclass
class ProtocolConfig:
    k: int = 5                          # samples per pair (one batch)
    pairs: int = 5                      # pairs per scene and setting (paper: 5)
    interaction_pairs: int = 2          # static pairs that end at a seat (when the scene has one)
    static_actions: tuple = ("sit", "lie down")   # interactions a static pair may end with
    dynamic_action: str = "pick up"
    action_seconds: float | None = None  # how long the interaction is held; None: as long as the data did there (≤ 10 s)
    min_distance: float = 2.0           # start-end straight-line distance (m), halved if the room is too small
    body_radius: float = 0.25
    subgoal_spacing: float = 0.6
    max_episodes: int = 24              # per pair; a sample that has not arrived by then counts as a miss
    seed: int = 0
    pskl_frames: int = 60               # PSKL chunk length (frames at 30 fps = 2 s)
    contact_thresh: float = 0.02


@dataclass
class Spot:
    """A place where the data performs an interaction."""
    xz: np.ndarray                      # (2,) pelvis (x, z) during the interaction
    action: str
    object_id: int | None = None
    object_pose: np.ndarray | None = None   # (4, 4) object -> world at the interaction's start
    duration: float = 2.0               # seconds the data spends in the action there


@dataclass
class Pair:
    setting: str
    scene: int
    index: int
    start: np.ndarray                   # (2,) world x, z on free floor
    goal: Goal                          # end point (+ action)
    route: Route                        # A* legs, subgoals (the "midpoints")
    object_id: int | None = None
    object_pose: np.ndarray | None = None   # (4, 4)

    def describe(self) -> dict:
        return {"setting": self.setting, "scene": self.scene, "index": self.index,
                "start": [round(float(v), 4) for v in self.start],
                "end": [round(float(v), 4) for v in self.goal.xz], "action": self.goal.action,
                "duration_s": self.goal.duration, "object_id": self.object_id,
                "path_length_m": round(float(np.linalg.norm(np.diff(self.route.path, axis=0), axis=-1).sum()), 4),
                "subgoals": int(len(self.route.subgoals))}


# ---------------------------------------------------------------------------------------
# Scenes


class SceneContext:
    """Everything the protocol needs about one scene of a MotionDataset, built lazily."""

    def __init__(self, ds, scene_id: int, body_radius: float = 0.25):
        self.ds, self.id = ds, int(scene_id)
        self.grid = ds.grid(self.id)
        self.fmap = walkable_map(self.grid, body_radius)
        self.sequences = [s for s in ds.sequences if s.scene == self.id]
        free = np.argwhere(self.fmap.free)                                                   # (N, 2) cells
        self.free_xz = self.fmap.origin + (free + 0.5) * self.fmap.cell                     # (N, 2) centres
        self._obj_cache: dict[int, tuple] = {}

    @cached_property
    def sdf(self) -> "SurfaceDistance":
        return SurfaceDistance(self.grid)

    def surface(self, points) -> np.ndarray:
        """(N,) distance (m) of points (N, 3) to the nearest surface, the floor y = 0 included."""
        p = np.asarray(points, np.float64)
        return np.minimum(self.sdf(p), p[..., 1])

    def spots(self, action: str, min_sep: float = 0.3) -> list[Spot]:
        """Where the scene's motion data performs `action`: one spot per labelled segment
        (pelvis at its middle frame), spots closer than `min_sep` to an earlier one dropped."""
        names = self.ds.action_names
        if action not in names:
            return []
        a = names.index(action)
        hands = [i for i, n in enumerate(self.ds.joint_set.names) if n in HAND_NAMES]
        out: list[Spot] = []
        for seq in self.sequences:
            lab = np.asarray(self.ds.actions[seq.start:seq.end, a])
            for s, e in true_runs(lab):
                f = seq.start + (s + e) // 2
                xz = np.asarray(self.ds.joints[f, PELVIS], np.float64)[[0, 2]]
                oid = pose = None
                if action == "pick up" and self.ds.object_ids is not None:
                    oid, pose = self._object_near(seq.start + s, hands)
                    if oid is None:
                        continue
                if any(np.linalg.norm(xz - o.xz) < min_sep and o.object_id == oid for o in out):
                    continue
                out.append(Spot(xz, action, oid, pose, (e - s) / self.ds.fps))
        return out

    def object_spots(self, action: str, reach: float = 0.8) -> list[Spot]:
        """Fallback when the data never interacts with an object here: each object at rest,
        approached from the nearest walkable point within `reach` m of it."""
        out = []
        for oid, pose in self.rest_objects():
            xz = self.fmap.nearest_free(pose[[0, 2], 3], reach)
            if xz is not None:
                out.append(Spot(np.asarray(xz, np.float64), action, oid, pose))
        return out

    def _object_near(self, f: int, hands: list[int]):
        ids = np.asarray(self.ds.object_ids[f])
        valid = np.flatnonzero(ids >= 0)
        if not valid.size or not hands:
            return None, None
        poses = np.asarray(self.ds.object_poses[f], np.float64)                             # (K, 4, 4)
        h = np.asarray(self.ds.joints[f, hands], np.float64)                                 # (H, 3)
        d = [np.linalg.norm(h - poses[k, :3, 3], axis=-1).min() for k in valid]
        k = int(valid[int(np.argmin(d))])
        return int(ids[k]), poses[k]

    def rest_objects(self) -> list[tuple[int, np.ndarray]]:
        """[(object id, pose (4, 4))]: the scene's objects at the first frame of its first sequence."""
        if self.ds.object_ids is None or not self.sequences:
            return []
        f = self.sequences[0].start
        ids = np.asarray(self.ds.object_ids[f])
        return [(int(o), np.asarray(self.ds.object_poses[f, k], np.float64)) for k, o in enumerate(ids) if o >= 0]

    def object(self, oid: int):
        """(occupancy grid in the object frame, KD-tree of surface samples in the object frame) or None."""
        if oid not in self._obj_cache:
            from scipy.spatial import cKDTree

            from motiongen.data.voxelize import voxelize_mesh

            mesh = self.ds.object_mesh(oid)
            if mesh is None:
                self._obj_cache[oid] = None
            else:
                import trimesh

                pts, _ = trimesh.sample.sample_surface(mesh, 2000, seed=0)                   # (2000, 3)
                pts = np.concatenate([pts, mesh.vertices])
                self._obj_cache[oid] = (voxelize_mesh(mesh, voxel_size=self.grid.voxel_size), cKDTree(pts))
        return self._obj_cache[oid]

    def objects_for_generate(self, target: tuple[int, np.ndarray] | None = None) -> list[tuple]:
        """[(object grid, pose)] for `generate(objects=)`: the scene's objects at rest, the target
        (if given) at its interaction pose instead of its rest pose."""
        placed = dict(self.rest_objects())
        if target is not None:
            placed[target[0]] = target[1]
        out = []
        for oid, pose in placed.items():
            obj = self.object(oid)
            if obj is not None:
                out.append((obj[0], pose))
        return out

    def object_distance(self, points, oid: int, poses) -> np.ndarray:
        """(F, P) distance (m) from points (F, P, 3) to object `oid`'s surface at poses (F, 4, 4)."""
        obj = self.object(oid)
        pts = np.asarray(points, np.float64)
        if obj is None:
            return np.full(pts.shape[:2], np.inf)
        poses = np.broadcast_to(np.asarray(poses, np.float64), (pts.shape[0], 4, 4))
        R, t = poses[:, :3, :3], poses[:, :3, 3]
        local = np.einsum("fji,fpj->fpi", R, pts - t[:, None])                              # R^T (p - t)
        d, _ = obj[1].query(local.reshape(-1, 3))
        return d.reshape(pts.shape[:2])


class SurfaceDistance:
    """Signed distance (m) to the occupied surface (+ free, - inside), like
    `metrics.SignedDistance` but from KD-trees of the boundary voxels instead of two EDTs of
    the whole grid: ~8x faster on a room grid (the EDTs were the protocol's largest fixed
    cost per scene) and as accurate (to about half a voxel). Points off the grid are free."""

    def __init__(self, grid):
        import scipy.ndimage as ndi
        from scipy.spatial import cKDTree

        occ = grid.dense()                                                                   # (X, Y, Z) bool
        self.grid, vs = grid, grid.voxel_size
        centres = lambda m: grid.origin + (np.argwhere(m) + 0.5) * vs                      # noqa: E731
        # Occupied voxels with a free 6-neighbour (the grid's outside is free) ...
        surf = occ & ~ndi.binary_erosion(occ, border_value=0)
        self._occ = cKDTree(centres(surf)) if surf.any() else None
        # ... and free voxels with an occupied 6-neighbour, for depths inside.
        fsurf = ~occ & ~ndi.binary_erosion(~occ, border_value=1)
        self._free = cKDTree(centres(fsurf)) if fsurf.any() else None
        self._half = 0.5 * vs

    def __call__(self, points) -> np.ndarray:
        """(...,) signed distances at points (..., 3)."""
        p = np.asarray(points, np.float64)
        flat = p.reshape(-1, 3)
        inside = self.grid.occupied(flat, outside=False)                                     # (N,)
        d = np.full(len(flat), 1e3)
        if self._occ is not None and (~inside).any():
            d[~inside] = np.maximum(self._occ.query(flat[~inside])[0] - self._half, 0.0)
        if inside.any():
            depth = self._free.query(flat[inside])[0] - self._half if self._free is not None else 1e3
            d[inside] = -np.maximum(depth, 0.0)
        return d.reshape(p.shape[:-1])


# ---------------------------------------------------------------------------------------
# Pairs


def _rng(seed: int, scene: int, setting: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(scene), _SETTING_CODE[setting]])


def pair_seed(seed: int, setting: str, scene: int, index: int) -> int:
    """Seed of the diffusion noise for one pair: a function of the pair alone."""
    return int(np.random.SeedSequence([int(seed), _SETTING_CODE[setting], int(scene), int(index)]).generate_state(1)[0])


def _try_route(ctx: SceneContext, start, goal: Goal, cfg: ProtocolConfig) -> Route | None:
    try:
        return plan_route(start, [goal], ctx.fmap, "astar", cfg.subgoal_spacing)
    except ConfigError:
        return None


def _random_free(ctx: SceneContext, rng) -> np.ndarray:
    # A random fine free cell, jittered inside it so starts are not on a lattice.
    c = ctx.free_xz[int(rng.integers(len(ctx.free_xz)))]
    return c + rng.uniform(-0.45, 0.45, 2) * ctx.fmap.cell


def make_pairs(ctx: SceneContext, setting: str, cfg: ProtocolConfig, action_names, tries: int = 300) -> list[Pair]:
    """`cfg.pairs` valid pairs for one scene: start on free floor (body-radius clearance),
    end on free floor or at an interaction spot, an A* route between them. Deterministic in
    (cfg.seed, scene, setting). Raises ConfigError when the scene has no valid pair at all."""
    if setting not in SETTINGS:
        raise ConfigError(f"settings: expected a subset of {list(SETTINGS)}, got {setting!r}")
    if not len(ctx.free_xz):
        raise ConfigError(f"scene {ctx.id} has no walkable floor for body_radius={cfg.body_radius} m")
    rng = _rng(cfg.seed, ctx.id, setting)
    vocab = set(action_names)
    if setting == "static":
        spots = [s for a in cfg.static_actions if a in vocab for s in ctx.spots(a)]
        # Interaction pairs at odd positions first (1, 3, ...), so a short run still mixes both kinds.
        order = list(range(1, cfg.pairs, 2)) + list(range(0, cfg.pairs, 2))
        wants = set(order[:min(cfg.interaction_pairs, cfg.pairs)]) if spots else set()
    else:
        if cfg.dynamic_action not in vocab:
            return []
        spots = ctx.spots(cfg.dynamic_action) or ctx.object_spots(cfg.dynamic_action)
        if not spots:
            return []
        wants = set(range(cfg.pairs))
    spot_order = [int(i) for i in rng.permutation(len(spots))] if spots else []
    pairs: list[Pair] = []
    n_spot = 0
    for i in range(cfg.pairs):
        pair = None
        for attempt in range(tries):
            # Small rooms: relax the distance after half the tries rather than fail.
            min_d = cfg.min_distance if attempt < tries // 2 else cfg.min_distance / 2
            start = _random_free(ctx, rng)
            spot = None
            if i in wants and spot_order:
                spot = spots[spot_order[(n_spot + attempt // 10) % len(spot_order)]]
                # Held as long as the data holds it there, so model and data are compared on
                # like segments (sit: 1.8-8.7 s in the test scenes, lie down: 10 s).
                secs = cfg.action_seconds if cfg.action_seconds is not None else min(spot.duration, MAX_ACTION_SECONDS)
                goal = Goal(spot.xz, spot.action, secs)
            else:
                goal = Goal(_random_free(ctx, rng))
            if np.linalg.norm(goal.xz - start) < min_d:
                continue
            route = _try_route(ctx, start, goal, cfg)
            if route is None:
                continue
            pair = Pair(setting, ctx.id, i, start, goal, route,
                        spot.object_id if spot is not None else None,
                        spot.object_pose if spot is not None else None)
            if spot is not None:
                n_spot += 1
            break
        if pair is None:
            if setting == "dynamic":
                continue
            raise ConfigError(f"scene {ctx.id}: could not find a {setting} start/end pair with a collision-free "
                              f"path in {tries} tries (body_radius={cfg.body_radius} m)")
        pairs.append(pair)
    return pairs


# ---------------------------------------------------------------------------------------
# Metrics on one motion


def _hand_idx(names) -> list[int]:
    return [i for i, n in enumerate(names) if n in HAND_NAMES]


def object_contact(ctx: SceneContext, joints, labelled, names, oid_poses, thresh: float) -> tuple[int, int]:
    """(hits, frames) over labelled frames: a hand joint (less its skin offset) within `thresh`
    of the object's surface at that frame's pose, or of the scene/floor. oid_poses: [(oid,
    poses (T, 4, 4))]."""
    frames = np.flatnonzero(labelled)
    idx = _hand_idx(names)
    if not frames.size or not idx:
        return 0, 0
    h = np.asarray(joints, np.float64)[frames][:, idx]                                       # (F, H, 3)
    d = ctx.surface(h.reshape(-1, 3)).reshape(h.shape[:2])
    for oid, poses in oid_poses:
        d = np.minimum(d, ctx.object_distance(h, oid, np.asarray(poses)[frames]))
    d = d - np.array([M.DEFAULT_SKIN_OFFSET.get(names[i], 0.0) for i in idx])
    return int((d < thresh).any(axis=1).sum()), int(frames.size)


def motion_metrics(ctx: SceneContext, joints, fps: float, names, labels, action_names, setting: str,
                   cfg: ProtocolConfig, boundaries, objects=(), vertices=None) -> dict:
    """Per-trajectory metrics for joints (T, J, 3) with per-frame labels (T, A) bool.
    objects: [(oid, poses (T, 4, 4))] for the dynamic setting's object contact/approach.
    vertices: (T', V', 3) body-mesh vertices (any subset of frames and vertices) where the motion
    has a body, for skin penetration."""
    j = np.asarray(joints, np.float64)
    pen = M.scene_penetration(j, ctx.grid, sdf=ctx.sdf)
    flo = M.floor_penetration(j)
    out = {**M.body_metrics(j, fps, joint_set_for(names).parents), "penetration_frames": pen["frame_ratio"],
           "penetration_max_m": pen["max_depth"], "floor_penetration_frames": flo["frame_ratio"],
           "jerk": M.mean_jerk(j, fps)}
    if vertices is not None:
        vp = M.scene_penetration(np.zeros((len(vertices), 0, 3)), ctx.grid, vertices=vertices, sdf=ctx.sdf)
        out["mesh_penetration_frames"], out["mesh_penetration_max_m"] = vp["frame_ratio"], vp["max_depth"]
    b = [x for x in boundaries if 1 <= x < len(j)]
    out["seam_ratio"] = M.seam_jump(j, b).ratio if b else float("nan")
    labels = np.asarray(labels, bool)
    hits = total = 0
    if setting == "static":
        parts = {a: p for a, p in M.DEFAULT_CONTACT_PARTS.items() if a in cfg.static_actions}
        if labels.any():
            r = M.contact_rate(j, labels, action_names, ctx.surface, joint_names=names, expected_parts=parts,
                               thresh=cfg.contact_thresh)
            n = [int(labels[:, action_names.index(a)].sum()) for a in r if a != "all"]
            hits, total = int(round(r["all"] * sum(n))) if n else 0, sum(n)
    elif cfg.dynamic_action in action_names:
        lab = labels[:, action_names.index(cfg.dynamic_action)]
        hits, total = object_contact(ctx, j, lab, names, objects, cfg.contact_thresh)
        idx = _hand_idx(names)
        if objects and idx:
            frames = np.flatnonzero(lab) if lab.any() else np.arange(len(j))
            d = np.min([ctx.object_distance(j[frames][:, idx], oid, np.asarray(p)[frames]).min()
                        for oid, p in objects])
            out["object_dist_m"] = float(d)
    # Pooled later (hits / frames over all trajectories), so keep the counts.
    out["_contact_hits"], out["_contact_frames"] = hits, total
    return out


# ---------------------------------------------------------------------------------------
# Model


@dataclass
class PairResult:
    pair: Pair
    per_sample: list[dict]              # k metric dicts of the output motions
    per_sample_raw: list[dict]          # the same metrics on the network's own joints (before the body)
    apd: float
    joints: np.ndarray                  # (k, T, J, 3) float32 world joints at 30 fps, the whole batch
    kept: list[np.ndarray]              # k arrays (T_s, J, 3): each sample up to its finish
    kept_raw: list[np.ndarray]          # the same for the network's own joints
    completed: float                    # fraction of samples that reached the final goal
    wall_s: float


def body_vertices(bm, body, frames: int, every_frame: int = 3, every_vertex: int = 8) -> np.ndarray:
    """(T', V', 3) mesh vertices of the first `frames` frames of a `BodyMotion`: every 3rd frame,
    every 8th vertex (enough to find skin in furniture; a fraction of the cost of whole meshes)."""
    return bm.motion_vertices(body, slice(0, frames, every_frame), np.arange(0, bm.num_vertices, every_vertex))


def run_pair(loaded, ctx: SceneContext, pair: Pair, cfg: ProtocolConfig, sampler, body_model=None) -> PairResult:
    """Sample k motions for one pair (one batch) and measure them (the output, and the network's
    own joints before they were put on a body)."""
    import torch

    from motiongen.sampling import LoopConfig, generate

    target = (pair.object_id, pair.object_pose) if pair.object_id is not None else None
    objs = ctx.objects_for_generate(target)
    dev = loaded.device if loaded.device.type != "mps" else torch.device("cpu")
    gen = torch.Generator(device=dev).manual_seed(pair_seed(cfg.seed, pair.setting, pair.scene, pair.index))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        # generate warns when samples stop before the goal; the report counts them instead.
        warnings.simplefilter("ignore")
        motion = generate(loaded, ctx.grid, pair.start, route=pair.route, walkable=ctx.fmap, objects=objs,
                          sampler=sampler, num_samples=cfg.k, generator=gen, body_model=body_model,
                          loop=LoopConfig(max_episodes=cfg.max_episodes, out_fps=ctx.ds.fps, source_fps=ctx.ds.fps))
    wall = time.perf_counter() - t0
    names = list(motion.joint_names)
    A = len(motion.action_names)
    joints = motion.joints                                                                   # (k, T, J, 3)
    boundaries = [int(b) for b in motion.episode_starts[1:]]
    goal_xz = pair.goal.xz
    results, raw_results, kept, kept_raw = [], [], [], []
    for s in range(cfg.k):
        # A sample that finished early idles while the batch goes on: cut it at its finish so
        # the padding does not dilute its metrics (APD below uses the full, equal-length batch).
        T = int(motion.finish_frame[s]) + 1 if motion.finish_frame[s] >= 0 else joints.shape[1]
        T = max(T, 4)
        js = joints[s, :T]                                                                   # (T, J, 3)
        kept.append(js)
        kept_raw.append(motion.joints_raw[s, :T])
        lab = np.zeros((T, A), bool)                                                         # (T, A)
        a = motion.actions[s, :T]
        lab[np.flatnonzero(a >= 0), a[a >= 0]] = True
        oposes = [(pair.object_id, np.repeat(pair.object_pose[None], T, 0))] if target else []
        verts = None
        if body_model is not None and motion.bodies is not None:
            verts = body_vertices(body_model, motion.bodies[s], T)
        for out, js_, v in ((results, js, verts), (raw_results, motion.joints_raw[s, :T], None)):
            m = motion_metrics(ctx, js_, motion.fps, names, lab, list(motion.action_names), pair.setting, cfg,
                               boundaries, oposes, vertices=v)
            m.update(_goal_metrics(js_, motion.arrival_frame[s, -1], goal_xz, pair.route.subgoals))
            out.append(m)
    apd = M.apd(joints) if cfg.k >= 2 else float("nan")
    done = float(np.mean(motion.finish_frame >= 0))
    return PairResult(pair, results, raw_results, apd, joints, kept, kept_raw, done, wall)


def _goal_metrics(joints, arrival: int, goal_xz, subgoals) -> dict:
    """Distance of the pelvis and of the body's own centre (hips midpoint) to the final goal at
    the arrival frame; never arrived: the closest approach stands in, so misses still count
    with their real distance. Plus the waypoint distances for the trajectory fail rate."""
    j = np.asarray(joints, np.float64)
    hip = 0.5 * (j[:, LEFT_HIP] + j[:, RIGHT_HIP])[:, [0, 2]]                                   # (T, 2)
    if 0 <= arrival < len(j):
        pelvis = float(np.linalg.norm(j[arrival, PELVIS, [0, 2]] - goal_xz))
        body = float(np.linalg.norm(hip[arrival] - goal_xz))
    else:
        pelvis = float(M.goal_distances(j, np.asarray(goal_xz)[None])[0])
        body = float(np.linalg.norm(hip - goal_xz, axis=-1).min())
    return {"goal_dist_m": pelvis, "goal_dist_body_m": body,
            "_waypoints": M.goal_distances(j, subgoals).tolist()}


# ---------------------------------------------------------------------------------------
# Reference


@dataclass
class ReferenceResult:
    per_sequence: list[dict]
    motions: list[np.ndarray]           # (T_i, J, 3) per sequence


def reference_metrics(ctx: SceneContext, setting: str, cfg: ProtocolConfig, episode_frames: int) -> ReferenceResult:
    """The same metrics on the scene's own motion data. Seams: boundaries every
    `episode_frames` frames (the model's episode length), so the ratio shows what an
    invisible seam looks like on real data. Objects move with the data's per-frame poses."""
    ds = ctx.ds
    names = list(ds.joint_set.names)
    out, motions = [], []
    for seq in ctx.sequences:
        j = np.asarray(ds.joints[seq.start:seq.end], np.float64)
        lab = np.asarray(ds.actions[seq.start:seq.end], bool)
        objs = []
        if setting == "dynamic" and ds.object_ids is not None:
            ids = np.asarray(ds.object_ids[seq.start:seq.end])                               # (T, K)
            poses = np.asarray(ds.object_poses[seq.start:seq.end], np.float64)               # (T, K, 4, 4)
            for k in range(ids.shape[1]):
                for oid in np.unique(ids[:, k]):
                    if oid < 0:
                        continue
                    p = poses[:, k].copy()
                    p[ids[:, k] != oid, :3, 3] = 1e6                                         # absent: far away
                    objs.append((int(oid), p))
        bounds = list(range(episode_frames, len(j), episode_frames))
        m = motion_metrics(ctx, j, ds.fps, names, lab, ds.action_names, setting, cfg, bounds, objs)
        if setting == "dynamic" and cfg.dynamic_action in ds.action_names and objs:
            # Closest hand approach per interaction segment, averaged over the segments.
            a = ds.action_names.index(cfg.dynamic_action)
            idx = _hand_idx(names)
            segs = true_runs(lab[:, a])
            if segs and idx:
                ds_ = []
                for s, e in segs:
                    fr = np.arange(s, e)
                    ds_.append(min(ctx.object_distance(j[fr][:, idx], oid, p[fr]).min() for oid, p in objs))
                m["object_dist_m"] = float(np.mean(ds_))
            else:
                m.pop("object_dist_m", None)
        out.append(m)
        motions.append(j.astype(np.float32))
    return ReferenceResult(out, motions)


# ---------------------------------------------------------------------------------------
# Aggregation


def _chunks(motions, n: int) -> list[np.ndarray]:
    """Non-overlapping n-frame chunks of every motion (PSKL needs one length)."""
    return [m[i:i + n] for m in motions for i in range(0, len(m) - n + 1, n)]


def pskl_sets(a, b, fps: float, n: int) -> tuple[float, float]:
    ca, cb = _chunks(a, n), _chunks(b, n)
    if not ca or not cb:
        return float("nan"), float("nan")
    return M.pskl(ca, cb, fps, length=n)


BODY_KEYS = ("bone_cv", "bone_max_dev", "slide_mps", "foot_skating", "penetration_frames", "penetration_max_m",
             "mesh_penetration_frames", "mesh_penetration_max_m", "floor_penetration_frames", "jerk", "seam_ratio")


def summarize_model(results: list[PairResult], ref_motions: list[np.ndarray], fps: float,
                    cfg: ProtocolConfig, raw: bool = False) -> dict:
    """Setting-level numbers for the model row (means over samples; contact pooled over frames).
    raw: the row of the network's own joints instead of the output motions. Goal success
    counts the body (hips midpoint), which no pin can put on the goal."""
    samples = [m for r in results for m in (r.per_sample_raw if raw else r.per_sample)]
    if not samples:
        return {}
    d_final = [m["goal_dist_body_m"] for m in samples]
    succ = M.goal_success(np.asarray(d_final), (0.2, 0.5))
    out = {k: M.finite_mean(m.get(k) for m in samples) for k in
           BODY_KEYS + ("goal_dist_m", "goal_dist_body_m", "object_dist_m")}
    out["slide_mps"] = M.finite_median(m.get("slide_mps") for m in samples)
    out["success_0.2"], out["success_0.5"] = succ[0.2], succ[0.5]
    out["traj_fail_rate"] = M.trajectory_fail_rate([np.asarray(m["_waypoints"]) for m in samples], 0.5)
    hits, frames = sum(m["_contact_hits"] for m in samples), sum(m["_contact_frames"] for m in samples)
    out["contact_rate"] = hits / frames if frames else float("nan")
    out["apd_m"] = M.finite_mean(r.apd for r in results)
    mine = [x for r in results for x in (r.kept_raw if raw else r.kept)]
    kab, kba = pskl_sets(mine, ref_motions, fps, cfg.pskl_frames)
    out["pskl_gen_ref"], out["pskl_ref_gen"] = kab, kba
    out["completed"] = M.finite_mean(r.completed for r in results)
    out["n_pairs"], out["n_samples"] = len(results), len(samples)
    out["seconds_per_pair"] = M.finite_mean(r.wall_s for r in results)
    return out


def summarize_reference(refs: list[ReferenceResult], fps: float, cfg: ProtocolConfig) -> dict:
    """The reference row: per-sequence means; goal metrics and APD are n/a (see docs/evaluation.md);
    PSKL between two halves of the sequences (alternating), the noise floor of the metric."""
    seqs = [m for r in refs for m in r.per_sequence]
    motions = [x for r in refs for x in r.motions]
    if not seqs:
        return {}
    out = {k: M.finite_mean(m.get(k) for m in seqs) for k in BODY_KEYS + ("object_dist_m",)}
    out["slide_mps"] = M.finite_median(m.get("slide_mps") for m in seqs)
    for k in ("goal_dist_m", "goal_dist_body_m", "success_0.2", "success_0.5", "traj_fail_rate", "apd_m",
              "completed", "seconds_per_pair"):
        out[k] = None
    hits, frames = sum(m["_contact_hits"] for m in seqs), sum(m["_contact_frames"] for m in seqs)
    out["contact_rate"] = hits / frames if frames else float("nan")
    kab, kba = pskl_sets(motions[0::2], motions[1::2], fps, cfg.pskl_frames) if len(motions) >= 2 \
        else (float("nan"), float("nan"))
    out["pskl_gen_ref"], out["pskl_ref_gen"] = kab, kba
    out["n_sequences"] = len(seqs)
    out["n_frames"] = int(sum(len(x) for x in motions))
    return out


def episode_frames(loaded, out_fps: float = 30.0, source_fps: float = 30.0) -> int:
    """Output frames one autoregressive episode adds: (L - k) model frames at the output rate."""
    win = loaded.window
    k = int(loaded.mask.max_transition)
    return int(round((win.length - k) * out_fps / (source_fps / win.stride)))


@dataclass
class Evaluation:
    """Everything one protocol run produced (report.py turns it into files)."""
    settings: list[str]
    pairs: dict[str, list[Pair]]                       # setting -> pairs (all scenes)
    results: dict[str, list[PairResult]]               # setting -> sampled pairs
    references: dict[str, list[ReferenceResult]]      # setting -> one per scene
    model: dict[str, dict]                             # setting -> summary (summarize_model)
    reference: dict[str, dict]                         # setting -> summary (summarize_reference)
    model_raw: dict[str, dict] = field(default_factory=dict)   # setting -> the network's own joints
    contexts: dict[int, SceneContext] = field(repr=False, default_factory=dict)
    notes: list[str] = field(default_factory=list)
    wall_s: float = 0.0


def evaluate(loaded, ds, scene_ids, cfg: ProtocolConfig, settings=SETTINGS, sampler=None,
             progress: bool = True, log=None, body_model=None) -> Evaluation:
    """Run the protocol: pairs for every scene and setting, k samples each, the reference row.
    body_model: the motions' body model (default `load_body_model()`), also for skin penetration."""
    from tqdm import tqdm

    from motiongen.sampling import SamplerSettings

    from motiongen.body.model import load_body_model

    t0 = time.perf_counter()
    sampler = sampler or SamplerSettings()
    body_model = body_model if body_model is not None else load_body_model()
    say = log or (lambda m: None)
    names = list(loaded.action_names)
    ctxs = {sid: SceneContext(ds, sid, cfg.body_radius) for sid in scene_ids}
    pairs: dict[str, list[Pair]] = {}
    notes: list[str] = []
    for st in settings:
        pairs[st] = []
        for sid, ctx in ctxs.items():
            ps = make_pairs(ctx, st, cfg, names)
            pairs[st] += ps
            if st == "static" and not any(p.goal.interacts for p in ps) and cfg.interaction_pairs:
                notes.append(f"scene {sid}: its motion data has no {'/'.join(cfg.static_actions)} segment, "
                             "so all static pairs end on free floor")
            if st == "dynamic" and not ps:
                why = (f"the checkpoint has no {cfg.dynamic_action!r} action" if cfg.dynamic_action not in names
                       else "no object to interact with")
                notes.append(f"scene {sid}: no dynamic pairs ({why})")
    n_total = sum(len(v) for v in pairs.values())
    say(f"evaluating {len(ctxs)} scene(s), {n_total} pair(s) x k={cfg.k}: "
        + ", ".join(f"{st} {len(pairs[st])}" for st in settings))
    results: dict[str, list[PairResult]] = {st: [] for st in settings}
    bar = tqdm(total=n_total, desc="evaluate", unit="pair", disable=not progress, dynamic_ncols=True)
    try:
        for st in settings:
            for pair in pairs[st]:
                bar.set_postfix_str(f"{st} scene {pair.scene} pair {pair.index}")
                results[st].append(run_pair(loaded, ctxs[pair.scene], pair, cfg, sampler, body_model))
                bar.update(1)
    finally:
        bar.close()
    ep = episode_frames(loaded, ds.fps, ds.fps)
    refs = {st: [reference_metrics(ctxs[sid], st, cfg, ep) for sid in ctxs] for st in settings}
    ref_motions = [m for r in refs[settings[0]] for m in r.motions] if settings else []
    model = {st: summarize_model(results[st], ref_motions, ds.fps, cfg) for st in settings}
    model_raw = {st: summarize_model(results[st], ref_motions, ds.fps, cfg, raw=True) for st in settings}
    reference = {st: summarize_reference(refs[st], ds.fps, cfg) for st in settings}
    return Evaluation(list(settings), pairs, results, refs, model, reference, model_raw, ctxs, notes,
                      time.perf_counter() - t0)


__all__ = ["SETTINGS", "ProtocolConfig", "Spot", "Pair", "SceneContext", "make_pairs", "pair_seed",
           "motion_metrics", "object_contact", "PairResult", "run_pair", "ReferenceResult", "reference_metrics",
           "summarize_model", "summarize_reference", "pskl_sets", "episode_frames", "SurfaceDistance",
           "body_vertices",
           "Evaluation", "evaluate"]
