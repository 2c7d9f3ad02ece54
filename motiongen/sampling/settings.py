"""What the sampler is told and what it returns: sampler settings, the episode loop's
configuration, one sampled episode, and the resulting `Motion`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from motiongen.checks import require_choice, require_range
from motiongen.errors import ConfigError
from motiongen.rates import DATA_FPS, DEFAULT_STEPS
from motiongen.sampling.goals import Route
from motiongen.skeleton import PELVIS

# What became of each goal of a sample (`Motion.goal_outcome`, `progress.goal_outcomes`).
REACHED, STALLED, EPISODE_LIMIT, NOT_ATTEMPTED = "reached", "stalled", "episode limit", "not attempted"


@dataclass
class SamplerSettings:
    sampler: str = "ddim"          # ddpm | ddim
    # Denoising steps (ddpm: respaced when < the training steps); None = the checkpoint's own:
    # DEFAULT_STEPS (25), or the step count a distilled student was trained for.
    steps: int | None = None
    eta: float = 0.0               # DDIM stochasticity
    # Classifier-free guidance; 1 = conditional pass only; None = 1 (a distilled student has its
    # teacher's guidance folded in).
    guidance_scale: float | None = None

    def __post_init__(self):
        # Checked here, before any model is loaded, for every app built on these keys.
        if self.sampler not in ("ddpm", "ddim"):
            raise ConfigError(f"sampler: expected ddpm or ddim, got {self.sampler!r}")
        if self.steps is not None and self.steps < 1:
            raise ConfigError(f"steps must be >= 1, got {self.steps}")

    @classmethod
    def of(cls, keys: SamplerSettings) -> SamplerSettings:
        """These settings alone, out of an app's config built on them (the `sample` and
        `evaluate` keys)."""
        return cls(**{name: getattr(keys, name) for name in cls.__dataclass_fields__})


def resolve_sampler(s: SamplerSettings, loaded, default_steps: int = DEFAULT_STEPS) -> SamplerSettings:
    """The settings a run of `loaded` uses: keys left unset take the checkpoint's own values
    (a model trained by `train`: `default_steps`, guidance 1; a distilled student, its
    `distill` entry: its step count, guidance 1). A student asked for another step count, or
    for a sampler other than deterministic DDIM, is refused: it was trained for neither."""
    guidance = 1.0 if s.guidance_scale is None else float(s.guidance_scale)
    student = getattr(loaded, "distill", None)
    if student is None:
        return replace(s, steps=default_steps if s.steps is None else s.steps, guidance_scale=guidance)
    n = int(student["steps"])
    if s.steps is not None and s.steps != n:
        raise ConfigError(f"steps={s.steps}: this checkpoint is a {n}-step distilled student and samples in "
                          f"{n} steps only (leave steps unset, or sample its teacher {student.get('teacher')})")
    if s.sampler != "ddim" or s.eta != 0:
        raise ConfigError(f"sampler={s.sampler} eta={s.eta:g}: a distilled student samples with deterministic "
                          "DDIM (sampler=ddim eta=0), the path it was trained on")
    return replace(s, steps=n, guidance_scale=guidance)


FOOT_HEIGHTS = ("network", "body", "free")


@dataclass
class LoopConfig:
    warmup: int = 2                # episodes standing at the start before walking
    keep_warmup: bool = False      # include the warm-up frames in the output
    transition: int | None = None  # pinned frames k; None = the checkpoint's mask.max_transition
    reach: float | None = None     # max target distance per episode (m); None = from the stats
    reach_fraction: float = 0.7    # reach = this x the farthest pelvis offset seen in training
    lookahead: bool = True         # target the farthest visible subgoal within reach
    tolerance: float = 0.25        # pelvis distance (m) that counts as arriving
    max_episodes: int = 200
    # Episodes after every sample has finished at a last goal without an action: a body that
    # reached it within `tolerance`, still walking, comes to rest there instead of the motion
    # ending in the middle of a step (a goal with an action already ends acting). Evaluation
    # cuts each sample at its finish, so these frames are never measured. 0: end on arrival.
    settle: int = 1
    # Seconds of motion without progress towards its current subgoal (coming STALL_MARGIN = 0.1 m
    # closer, passing a subgoal, acting) after which a sample stops there and its goal fails;
    # null or 0 = never (evaluation). 20 s: a walk covers a detour's subgoals one by one and an
    # action counts as progress, so only a body that stands or wanders for that long trips it.
    stall_s: float | None = 20.0
    out_fps: float = DATA_FPS
    source_fps: float | None = None  # rate of the training data (before stride); None = the checkpoint's
    project: bool = True           # one body: each episode projected onto it, and the final solve
    # Each window's skeleton scaled to the body's size before it is projected (sampling/
    # projection.py, `scale_to_body`): the body then stands as tall as the network's pose says
    # instead of bending its legs under a smaller network skeleton. Needs a body (project).
    body_scale: bool = True
    foot_lock: bool = True         # the final solve holds predicted planted feet in place
    # The height a planted foot is held at: the network's own prediction ("network"), the
    # projected body's ("body": 1-2 cm higher where the body's legs are shorter than the
    # network's), or whatever suits the rest of the solve ("free": the feet rise to let the body
    # travel further than its stride; docs/results.md, "The output's feet float").
    foot_height: str = "network"
    pin_goal: bool = False         # write the goal into the result (the public code); default: the model predicts it
    # Gaussian sigma (output frames) over the non-foot joints before the final solve; 0 = off;
    # None = by the model's frame rate (assemble.smoothing_for_rate: 2 at 15 fps or more, off below).
    smooth: float | None = None
    # Seconds over which each episode's first free frames take on the pinned frames' velocity
    # (assemble.blend_seam); 0 = off; None = this default. On at every model rate: with the final
    # solve's swing clearance the 10 fps models gain from it as the 15 fps demo does (docs/quality.md).
    seam_blend: float | None = 0.6
    solve_smoothness: float | None = None  # final solve's joint-acceleration weight; None = by model rate (assemble.solve_smoothness_for_rate)
    # How the final solve is solved: refined (the joint-space minimum, then 40 L-BFGS
    # iterations over the rotations from it): on the validation scenes a walk as straight as the
    # network's and a jerk near the data's, where lbfgs (80 iterations from the analytic start)
    # stops short with the pelvis shaking at 4-8 Hz; lbfgs keeps a little lower PSKL and dynamic
    # skating. joint-space (the minimum in joint space in closed form, put on the body
    # analytically; body/joint_solve.py): ~20x faster, but further from the data's motion
    # spectrum (PSKL) in the dynamic setting (docs/sampling.md, docs/results.md).
    solve: str = "refined"
    # Processes solving a batch's samples side by side in the final solve, from
    # assemble.PARALLEL_MIN_SAMPLES samples on (fewer stay here): 0 = as many as torch has
    # threads (one per core by default; `threads=N` or an `evaluate jobs=N` worker's share gives
    # fewer, so parallel evaluations do not oversubscribe the cores), 1 = none. Each sample's
    # result is the same either way.
    solve_workers: int = 0
    # Actions done with a hand on the nearest placed object: the final solve puts the nearer
    # hand on it over the frames so labelled. () leaves hands where the network put them.
    hand_actions: tuple[str, ...] = ("pick up",)
    # Actions whose episodes tell the network where the hand goes: the wrist nearer the nearest
    # placed object, at a point `palm` out from its surface, as a goal at the window's last frame
    # (the hand goal the checkpoint was trained on with mask.p_hand > 0; others ignore it).
    # The network reaches for the object itself; () = no hand goal.
    hand_goal: tuple[str, ...] = ("pick up",)
    # The episode that walks onto the spot of such an action (its last subgoal) gets the same
    # hand goal: the network plans its arrival with the wrist ending at the object. Without it
    # the body arrives with the object 0.2-0.3 m to its side, does not turn on the spot, and its
    # own hand is on the object on a third as many pick-up frames (docs/results.md, "The hand
    # goal on arrival").
    hand_goal_on_arrival: bool = True
    # In the episodes of an action with a hand goal (not the one walking onto its spot), a
    # checkpoint trained with a facing goal (mask.p_facing > 0) is also asked to end facing the
    # object from its pelvis goal, as the data's people stand to what they pick up; others
    # ignore it.
    facing_goal: bool = True
    # The episode that walks onto such an action's spot is asked to end facing the object too,
    # where it is given the hand goal (hand_goal_on_arrival; without it, nothing is asked there).
    # Off by default: so asked, the demo network turned early and stopped 0.2 m off the spot
    # (9 of 20 motions stalled; docs/results.md, "A facing goal as an angle").
    facing_on_arrival: bool = False
    # Actions done on a surface (a seat, a bed): while acting, the goal also gives the pelvis
    # height, `seat_offset` m above the top of the furniture under the goal (the pelvis joint of
    # a seated SMPL-X body; the synthetic data's median is 0.095). Needs a checkpoint trained
    # with mask.p_goal_y > 0.
    seat_actions: tuple[str, ...] = ("sit", "lie down")
    seat_offset: float = 0.10
    seat_shift: bool = True        # the clean-up moves a seated body onto its seat and holds the pelvis there
    swing_clearance: bool = True   # the final solve keeps an unplanted foot from being pulled below its predicted height
    # A foot's swing between two plants rises at least as high as the training data's swings of
    # that length (sampling/swing.py): the lock turns the network's shuffle into steps, and this
    # keeps those steps from gliding over the floor. Needs a body (the final solve).
    swing_lift: bool = True

    def __post_init__(self):
        require_choice("loop.foot_height", self.foot_height, FOOT_HEIGHTS)
        require_range("loop.solve_workers", self.solve_workers, 0, 1024, integer=True)
        if self.stall_s is not None and not 0 <= self.stall_s < float("inf"):
            raise ConfigError(f"loop.stall_s: expected seconds >= 0 (0 or null: off), got {self.stall_s}")


# The clean-up's stages, each as the LoopConfig fields that switch it off (evaluation's ablation
# rows). Stages of the episode loop change what the next episode is conditioned on, so switching
# one off means sampling again; the others act after the last episode and can be redone on the
# same episodes (`generate(cleanups=)`).
CLEANUP_STAGES: dict[str, dict] = {
    "projection": {"project": False},
    "body_scale": {"body_scale": False},
    "seam_blend": {"seam_blend": 0.0},
    "foot_lock": {"foot_lock": False},
    "foot_height": {"foot_height": "free"},
    "clearance": {"swing_clearance": False},
    "swing_lift": {"swing_lift": False},
    "smoothing": {"smooth": 0.0},
    "hand_goal": {"hand_goal": ()},
    "hand_reach": {"hand_actions": ()},
    "seat_height": {"seat_shift": False},
}
IN_LOOP_STAGES = ("projection", "body_scale", "seam_blend", "hand_goal")
# The LoopConfig fields only the clean-up after the last episode reads.
POST_LOOP_FIELDS = frozenset({"foot_lock", "foot_height", "swing_clearance", "swing_lift", "smooth", "hand_actions", "seat_shift",
                              "solve_smoothness", "solve", "solve_workers"})


@dataclass
class Episode:
    kind: str                      # warmup | walk | act | idle (majority over samples)
    start: int                     # index of its first *new* frame in the model-rate output
    transition: int                # frames pinned at the start of the window
    target: np.ndarray             # (S, 2) world pelvis target (after clamping)
    window: np.ndarray             # (S, L, J, 3) world joints of the whole window (after projection)
    to_world: np.ndarray           # (S, 4, 4) the window's local -> world frame
    raw: np.ndarray | None = None  # (S, L, J, 3) world joints as the network predicted them


@dataclass
class Motion:
    """The result of `generate`: world joints at `fps` and everything needed to explain them."""

    joints: np.ndarray             # (S, T, J, 3) float32 world, y-up, metres, at fps: the output
    fps: float
    joint_names: list[str]
    model_joints: np.ndarray       # (S, Tm, J, 3) float32 at the model rate (projected)
    model_fps: float
    actions: np.ndarray            # (S, T) int16 action index per output frame, -1 = none
    action_names: list[str]
    episode_starts: np.ndarray     # (E,) int: first output frame of each episode's new frames
    episode_kinds: list[str]
    route: Route
    arrival_frame: np.ndarray      # (S, G) int output frame of arrival at each goal, -1 = never
    arrival_error: np.ndarray      # (S, G) output pelvis (x, z) closest approach near that frame (m), nan = never
    arrival_error_body: np.ndarray  # (S, G) same for the hips' midpoint
    finish_frame: np.ndarray       # (S,) output frame where the sample reached its final goal, -1 = never
    completed: bool                # every sample reached every goal
    wall_time: float               # seconds spent generating
    joints_raw: np.ndarray | None = None   # (S, T, J, 3) the network's joints at fps, before any body
    planted: np.ndarray | None = None      # (S, T, C) bool predicted planted flags of contact_joints
    contact_joints: list[str] = field(default_factory=list)
    bodies: list | None = None             # one motiongen.body.solve.BodyMotion per sample
    episodes: list[Episode] = field(default_factory=list, repr=False)
    # (S, G) str per goal: reached | stalled | episode limit | not attempted (progress.goal_outcomes)
    goal_outcome: np.ndarray | None = None
    # name -> the same episodes cleaned up with another LoopConfig (`generate(cleanups=)`)
    variants: dict = field(default_factory=dict, repr=False)

    def failed_goals(self) -> list[dict]:
        """Every goal a sample did not reach: {sample, goal (1-based), reason, distance_m (from
        the pelvis at the motion's last frame)}; [] when the motion is complete."""
        if self.goal_outcome is None:
            return []
        end = self.joints[:, -1, PELVIS][:, [0, 2]]                                       # (S, 2)
        return [{"sample": int(s), "goal": int(g) + 1, "reason": str(self.goal_outcome[s, g]),
                 "distance_m": round(float(np.linalg.norm(end[s] - self.route.goals[g].xz)), 3)}
                for s, g in zip(*np.nonzero(self.goal_outcome != REACHED))]

    @property
    def num_samples(self) -> int:
        return self.joints.shape[0]

    @property
    def duration(self) -> float:
        """Seconds of motion per sample."""
        return (self.joints.shape[1] - 1) / self.fps

    @property
    def real_time_factor(self) -> float:
        """Seconds of motion produced (all samples) per second of compute."""
        return self.num_samples * self.duration / max(self.wall_time, 1e-9)
