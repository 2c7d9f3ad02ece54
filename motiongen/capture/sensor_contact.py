"""Contact sensors -> per-frame joint contact: the algorithm of the multi-view capture paper
(A2) behind `motiongen contact-sensors` (`motiongen.capture.contact_sensors`, which documents it).

Clap synchronisation (`find_claps`, `ClockMap`), resampling to video frames, per-sensor
thresholds (Otsu's), minimum-duration filtering, and the joint contact matrix (`process`,
`joint_contact`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import find_peaks

from motiongen.capture.sensor_csv import SensorRecording
from motiongen.errors import ConfigError, DataError
from motiongen.spans import true_runs

HAND_JOINT_NAMES = ("left_wrist", "right_wrist", "left_index1", "right_index1")


# ---- synchronisation -------------------------------------------------------------------

@dataclass
class ClockMap:
    """Sensor time (s) <-> video frame, fixed by the start and end claps: the frame f0 was
    shot at sensor time t0 and f1 at t1, linearly in between (and beyond)."""

    t0: float
    t1: float
    f0: float
    f1: float
    video_fps: float

    def frame_of(self, t):
        return self.f0 + (np.asarray(t, np.float64) - self.t0) * (self.f1 - self.f0) / (self.t1 - self.t0)

    def time_of(self, frame):
        return self.t0 + (np.asarray(frame, np.float64) - self.f0) * (self.t1 - self.t0) / (self.f1 - self.f0)

    @property
    def drift(self) -> float:
        """Video seconds per sensor second between the claps: 1 when both clocks agree."""
        return (self.f1 - self.f0) / self.video_fps / (self.t1 - self.t0)


def find_claps(rec: SensorRecording, channels: list[int], height: float = 0.5, max_width: float = 0.25,
               min_distance: float = 0.1) -> np.ndarray:
    """Rows (K,) of clap-like peaks, in time order, in the largest reading of `channels` per
    sample: at least `height` of the way from the signal's median to its maximum, as prominent,
    at most `max_width` s wide at half prominence (a clap is a spike; holding or standing on a
    sensor is a plateau), at least `min_distance` s apart (a bouncing clap is one clap)."""
    s = rec.values[:, channels].max(axis=1)                                    # (N,)
    base, top = float(np.median(s)), float(s.max())
    if top - base <= 0:
        return np.zeros(0, np.int64)
    amp = height * (top - base)
    rate = rec.rate
    peaks, _ = find_peaks(s, height=base + amp, prominence=amp, width=(None, max(1.0, max_width * rate)),
                          distance=max(1, int(round(min_distance * rate))))
    return peaks.astype(np.int64)


# ---- resampling, thresholds, filtering -------------------------------------------------

def resample(rec: SensorRecording, clock: ClockMap, frames: np.ndarray, half_width: float = 0.5,
             method: str = "mean") -> np.ndarray:
    """Readings at video frame positions `frames` (F,) -> (F, C) float64. "mean": the mean of
    the samples within each frame's interval [frame - half_width, frame + half_width) (an
    anti-aliasing box filter; linear interpolation where an interval holds no sample, i.e.
    when the sensor is slower than the video); "linear": interpolation at the frame centre."""
    centre = clock.time_of(frames)
    lin = np.stack([np.interp(centre, rec.time, rec.values[:, c]) for c in range(rec.values.shape[1])], 1)
    if method == "linear":
        return lin
    if method != "mean":
        raise ConfigError(f"resample={method!r}: expected mean or linear")
    lo = np.searchsorted(rec.time, clock.time_of(frames - half_width), side="left")
    hi = np.searchsorted(rec.time, clock.time_of(frames + half_width), side="left")
    csum = np.concatenate([np.zeros((1, rec.values.shape[1])), np.cumsum(rec.values, axis=0)])   # (N+1, C)
    n = (hi - lo)[:, None]
    mean = (csum[hi] - csum[lo]) / np.maximum(n, 1)
    return np.where(n > 0, mean, lin)


@dataclass
class Otsu:
    threshold: float        # readings above it are the upper class
    mean_low: float
    mean_high: float
    separability: float     # between-class / total variance, in [0, 1]


def otsu(x: np.ndarray, adc_max: int = 1023) -> Otsu | None:
    """Otsu's threshold of readings x over the integer ADC levels 0..adc_max: the split that
    maximises the between-class variance. Where several splits tie (no readings between two
    levels), the middle of the tied range. None when x holds a single level."""
    hist, _ = np.histogram(x, bins=adc_max + 1, range=(-0.5, adc_max + 0.5))
    levels = np.arange(adc_max + 1, dtype=np.float64)
    n0 = np.cumsum(hist)                                                       # class 0: levels 0..k
    n1 = n0[-1] - n0
    valid = (n0 > 0) & (n1 > 0)
    if not valid.any():
        return None
    s0 = np.cumsum(hist * levels)
    with np.errstate(divide="ignore", invalid="ignore"):
        m0 = s0 / n0
        m1 = (s0[-1] - s0) / n1
        between = n0 * n1 * (m0 - m1) ** 2 / float(n0[-1]) ** 2
    between = np.where(valid, between, -np.inf)
    best = between.max()
    ties = np.flatnonzero(between >= best * (1 - 1e-9))
    breaks = np.flatnonzero(np.diff(ties) > 1)
    run = ties[: breaks[0] + 1] if len(breaks) else ties                       # the first run of tied splits
    k = int(run[0])                                  # tied splits hold the same readings: same class means
    n = float(n0[-1])
    total = float((hist * levels ** 2).sum() / n - (s0[-1] / n) ** 2)
    return Otsu(0.5 * (run[0] + run[-1]) + 0.5, float(m0[k]), float(m1[k]), float(best / total) if total > 0 else 0.0)


@dataclass
class Threshold:
    value: float
    source: str                         # "given" | "otsu" | "unclear" (Otsu found no clear contact level)
    otsu: Otsu | None = None


def propose_threshold(x: np.ndarray, adc_max: int, min_contrast: float) -> Threshold:
    """Otsu's threshold when the two classes' mean readings differ by at least `min_contrast`;
    otherwise the channel shows no clear contact level (never pressed, or pressed throughout)
    and the threshold is the median + min_contrast: flagged "unclear" for the user to check."""
    o = otsu(x, adc_max)
    if o is not None and o.mean_high - o.mean_low >= min_contrast:
        return Threshold(o.threshold, "otsu", o)
    return Threshold(float(min(adc_max, np.median(x) + min_contrast)), "unclear", o)


def filter_min_duration(contact: np.ndarray, min_contact: int = 1, min_gap: int = 1) -> np.ndarray:
    """(F, C) bool with spurious flips removed: first gaps shorter than `min_gap` frames
    between two contacts are filled, then contacts shorter than `min_contact` frames dropped."""
    out = np.array(contact, bool, copy=True)
    F = out.shape[0]
    for c in range(out.shape[1]):
        if min_gap > 1:
            for a, b in true_runs(~out[:, c]):
                if 0 < a and b < F and b - a < min_gap:
                    out[a:b, c] = True
        if min_contact > 1:
            for a, b in true_runs(out[:, c]):
                if b - a < min_contact:
                    out[a:b, c] = False
    return out


# ---- the whole pass --------------------------------------------------------------------

@dataclass
class SensorContact:
    frames: np.ndarray          # (F,) float video frame positions
    signal: np.ndarray          # (F, C) readings resampled to the frames
    contact: np.ndarray         # (F, C) bool after filtering
    raw_contact: np.ndarray     # (F, C) bool before filtering
    thresholds: list[Threshold]
    clock: ClockMap
    clap_samples: tuple[int, int]
    clap_candidates: np.ndarray     # rows of every clap-like peak found (empty when given)
    claps_detected: bool
    trial_rows: tuple[int, int]     # [start, end) rows the thresholds were proposed from
    settings: dict = field(default_factory=dict)


def covered_frames(rec: SensorRecording, clock: ClockMap) -> np.ndarray:
    """Integer video frames whose time lies within the recording."""
    a, b = clock.frame_of(rec.time[[0, -1]])
    return np.arange(int(np.ceil(a - 1e-9)), int(np.floor(b + 1e-9)) + 1, dtype=np.float64)


def process(rec: SensorRecording, video_fps: float, clap_frames, *, frames: np.ndarray | None = None,
            half_width: float = 0.5, clap_samples=None, clap_channels: list[int] | None = None,
            clap_height: float = 0.5, clap_max_width: float = 0.25, max_drift: float = 0.02,
            thresholds: list[float | None] | None = None, min_contrast: float = 100.0, clap_guard: float = 0.5,
            resample_method: str = "mean", min_contact_frames: int = 1, min_gap_frames: int = 1,
            mask_claps: bool = True) -> SensorContact:
    """Synchronise, resample, binarise and filter one recording (module doc).

    clap_frames: video frames (f0, f1) of the start and end claps. frames: video frame
    positions to label (default: every frame the recording covers), each covering
    ±half_width frames. thresholds: per channel, a reading or None (proposed). mask_claps:
    no hand contact within clap_guard s of the two claps (on the clap channels)."""
    if not video_fps > 0:
        raise ConfigError(f"video_fps must be positive, got {video_fps}")
    f0, f1 = (float(f) for f in clap_frames)
    if not f1 > f0:
        raise ConfigError(f"clap_frames=[{f0:g},{f1:g}]: the end clap's frame must come after the start clap's")
    hands = [c for c, j in enumerate(rec.joints) if j in HAND_JOINT_NAMES]
    chans = clap_channels if clap_channels else (hands or list(range(rec.values.shape[1])))
    i0, i1, candidates = _clap_rows(rec, chans, clap_samples, clap_height, clap_max_width)
    clock = _clock(rec, i0, i1, f0, f1, float(video_fps), max_drift)
    frames = _frames_to_label(rec, clock, frames)
    signal = resample(rec, clock, frames, half_width, resample_method)          # (F, C)
    th, trial = _thresholds(rec, clock, (i0, i1), clap_guard, thresholds, min_contrast)
    raw = signal > np.array([t.value for t in th])[None]
    if mask_claps:
        # The claps press the hand sensors against each other, not against the scene.
        t = clock.time_of(frames)
        near = (np.abs(t - clock.t0) <= clap_guard) | (np.abs(t - clock.t1) <= clap_guard)
        for c in chans:
            if rec.joints[c] in HAND_JOINT_NAMES:
                raw[near, c] = False
    contact = filter_min_duration(raw, min_contact_frames, min_gap_frames)
    settings = {"video_fps": video_fps, "half_width": half_width, "resample": resample_method,
                "min_contrast": min_contrast, "clap_guard": clap_guard, "min_contact_frames": min_contact_frames,
                "min_gap_frames": min_gap_frames, "clap_height": clap_height, "clap_max_width": clap_max_width,
                "mask_claps": mask_claps, "clap_channels": [rec.channels[c] for c in chans]}
    return SensorContact(frames, signal, contact, raw, th, clock, (i0, i1), candidates, clap_samples is None,
                         trial, settings)


def _clap_rows(rec: SensorRecording, chans: list[int], clap_samples, clap_height: float,
               clap_max_width: float) -> tuple[int, int, np.ndarray]:
    """Rows (i0, i1) of the start and end claps: `clap_samples` when given, else the first and
    last clap-like peak on channels `chans`; and every peak found (K,) (empty when given)."""
    candidates = np.zeros(0, np.int64)
    if clap_samples is not None:
        i0, i1 = (int(i) for i in clap_samples)
        if not 0 <= i0 < i1 < len(rec.time):
            raise ConfigError(f"clap_samples=[{i0},{i1}]: expected two increasing sample rows in "
                              f"0..{len(rec.time) - 1}")
        return i0, i1, candidates
    candidates = find_claps(rec, chans, clap_height, clap_max_width)
    if len(candidates) < 2:
        raise DataError(rec.path, ",".join(rec.channels[c] for c in chans),
                        f"found {len(candidates)} clap peak(s) (sampling at {rec.rate:.3g} Hz, time in "
                        f"{rec.time_unit}), need a start and an end clap: pass "
                        "clap_samples=[I0,I1] (the two rows), or clap_channels= / clap_height= / clap_max_width=")
    return int(candidates[0]), int(candidates[-1]), candidates


def _clock(rec: SensorRecording, i0: int, i1: int, f0: float, f1: float, video_fps: float,
           max_drift: float) -> ClockMap:
    """The clock map from clap rows (i0, i1) to clap frames (f0, f1), refused when the two
    clocks disagree by more than `max_drift`."""
    clock = ClockMap(float(rec.time[i0]), float(rec.time[i1]), f0, f1, video_fps)
    if abs(clock.drift - 1) > max_drift:
        raise DataError(rec.path, "claps", f"the claps are {clock.t1 - clock.t0:.3f} s apart in the recording (rows "
                                           f"{i0}, {i1}) but {(f1 - f0) / video_fps:.3f} s in the video (frames "
                                           f"{f0:g}, {f1:g} at {video_fps:g} fps): check clap_frames, video_fps, "
                                           f"the time unit, or the clap rows (max_drift={max_drift:g})")
    return clock


def _frames_to_label(rec: SensorRecording, clock: ClockMap, frames: np.ndarray | None) -> np.ndarray:
    """(F,) video frame positions: `frames`, checked to lie within the recording, or (None)
    every frame it covers."""
    covered = covered_frames(rec, clock)
    if len(covered) == 0:
        raise DataError(rec.path, None, "the recording covers no video frame")
    if frames is None:
        return covered
    frames = np.asarray(frames, np.float64)
    first, last = clock.frame_of(rec.time[[0, -1]])
    if frames.min() < first - 1e-6 or frames.max() > last + 1e-6:
        raise DataError(rec.path, None, f"the frames to label, video frames {frames.min():g}..{frames.max():g}, "
                                        f"reach outside the recording, which covers video frames "
                                        f"{first:.1f}..{last:.1f} (check frame_offset and clap_frames)")
    return frames


def _thresholds(rec: SensorRecording, clock: ClockMap, clap_rows: tuple[int, int], clap_guard: float,
                thresholds: list[float | None] | None, min_contrast: float) -> tuple[list[Threshold], tuple[int, int]]:
    """Per channel the given threshold or one proposed from the trial, and the trial's rows [a, b)."""
    C = rec.values.shape[1]
    # Thresholds come from the trial (between the claps, away from them): the claps' spikes
    # and whatever happens before and after the trial are not contact levels.
    a = int(np.searchsorted(rec.time, clock.t0 + clap_guard, side="right"))
    b = int(np.searchsorted(rec.time, clock.t1 - clap_guard, side="left"))
    if b <= a:
        a, b = clap_rows[0] + 1, clap_rows[1]
    given = thresholds if thresholds is not None else [None] * C
    if len(given) != C:
        raise ConfigError(f"thresholds: expected {C} entries (one per sensor column), got {len(given)}")
    th = [Threshold(float(v), "given") if v is not None
          else propose_threshold(rec.values[a:b, c], rec.adc_max, min_contrast) for c, v in enumerate(given)]
    return th, (a, b)


def joint_contact(contact: np.ndarray, joints: list[str], names) -> np.ndarray:
    """Channel contact (F, C) -> joint contact (F, J) over joint names `names`: a joint is in
    contact when any of its sensors is. Every channel's joint must be in `names`."""
    out = np.zeros((contact.shape[0], len(names)), bool)
    for c, j in enumerate(joints):
        out[:, list(names).index(j)] |= contact[:, c]
    return out
