"""What `contact_sensors` writes: `contact.npz`, `report.json`, the check plot (the multi-view
capture paper's Fig. 2: raw traces, dashed per-sensor thresholds, shaded contact, the clap events) and the
contact labels of a dataset sequence (`contact.npy`, replaced atomically)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from motiongen.capture.sensor_contact import SensorContact, joint_contact
from motiongen.capture.sensor_csv import SensorRecording
from motiongen.data.format import MotionDataset
from motiongen.errors import DataError
from motiongen.skeleton import JOINT_SETS
from motiongen.spans import true_runs


def _replace_npz(path: Path, **arrays) -> None:
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def _replace_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_outputs(out: str | Path, rec: SensorRecording, res: SensorContact, report: dict, plot: bool = True) -> None:
    """contact.npz, report.json (`make_report`'s) and (plot) sensors.png under `out`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = JOINT_SETS["body+index1" if any(j.endswith("index1") for j in rec.joints) else "body"].names
    _replace_npz(out / "contact.npz", frames=res.frames, contact=res.contact, raw_contact=res.raw_contact,
                 signal=res.signal.astype(np.float32), channels=np.array(rec.channels), joints=np.array(rec.joints),
                 thresholds=np.array([t.value for t in res.thresholds]), joint_names=np.array(names),
                 joint_contact=joint_contact(res.contact, rec.joints, names), video_fps=np.array(res.clock.video_fps),
                 clap_samples=np.array(res.clap_samples), clap_frames=np.array([res.clock.f0, res.clock.f1]))
    if plot:
        plot_sensors(out / "sensors.png", rec, res)
        report["plot"] = "sensors.png"
    _replace_text(out / "report.json", json.dumps(report, indent=2))


def make_report(rec: SensorRecording, res: SensorContact) -> dict:
    c = res.clock
    i0, i1 = res.clap_samples
    channels = []
    for k, (name, joint, th) in enumerate(zip(rec.channels, rec.joints, res.thresholds)):
        runs = true_runs(res.contact[:, k])
        entry = {"column": name, "joint": joint, "threshold": round(th.value, 2), "threshold_source": th.source,
                 "contact_fraction": round(float(res.contact[:, k].mean()), 4), "contact_runs": len(runs),
                 "frames_flipped_by_filter": int((res.contact[:, k] != res.raw_contact[:, k]).sum())}
        if th.otsu is not None:
            entry["otsu"] = {"threshold": round(th.otsu.threshold, 2), "mean_low": round(th.otsu.mean_low, 1),
                             "mean_high": round(th.otsu.mean_high, 1), "separability": round(th.otsu.separability, 3)}
        channels.append(entry)
    report = {"signal": rec.path, "samples": int(len(rec.time)), "sample_rate_hz": round(rec.rate, 3),
              "time_unit": rec.time_unit, "adc_max": rec.adc_max,
              "claps": {"samples": [i0, i1], "sensor_times_s": [round(c.t0, 6), round(c.t1, 6)],
                        "video_frames": [c.f0, c.f1], "found": "detected" if res.claps_detected else "given",
                        "candidates": [int(x) for x in res.clap_candidates],
                        "clock_drift_ppm": round((c.drift - 1) * 1e6, 1)},
              "frames": {"count": int(len(res.frames)), "first": float(res.frames[0]), "last": float(res.frames[-1])},
              "threshold_rows": list(res.trial_rows), "settings": res.settings, "channels": channels}
    summary = [f"claps at rows {i0}, {i1} ({'detected' if res.claps_detected else 'given'}) = video frames "
               f"{c.f0:g}, {c.f1:g}; clocks differ by {(c.drift - 1) * 1e6:+.0f} ppm; "
               f"{len(res.frames)} frames labelled"]
    for ch in channels:
        summary.append(f"  {ch['column']} -> {ch['joint']}: threshold {ch['threshold']:g} ({ch['threshold_source']}), "
                       f"contact {100 * ch['contact_fraction']:.1f} % of frames in {ch['contact_runs']} runs")
        if ch["threshold_source"] == "unclear":
            summary.append(f"  warning: {ch['column']} shows no clear contact level; check sensors.png and pass "
                           f"thresholds=[{ch['column']}=VALUE]")
    report["summary"] = summary
    return report


def plot_sensors(path: Path, rec: SensorRecording, res: SensorContact, dpi: int = 100) -> Path:
    """One row per sensor: the raw trace against video frames, its threshold (dashed), the
    labelled contact (shaded), the clap events (dotted); on the right the histogram of the
    trial's readings the threshold was chosen from."""
    # Imported here, when plotting (plot=false skips it): matplotlib is heavy (~0.5 s), and choosing
    # its backend on import would change it for every program importing motiongen.
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy, as above
    from matplotlib.figure import Figure  # heavy, as above

    C = rec.values.shape[1]
    fig = Figure(figsize=(11, 1.0 + 1.7 * C), dpi=dpi)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(C, 2, width_ratios=(6, 1), hspace=0.45, wspace=0.04)
    x = res.clock.frame_of(rec.time)                                            # (N,) video frames
    step = float(np.median(np.diff(res.frames))) if len(res.frames) > 1 else 1.0
    a, b = res.trial_rows
    ax0 = None
    for c in range(C):
        ax = fig.add_subplot(grid[c, 0], sharex=ax0)
        ax0 = ax0 or ax
        th = res.thresholds[c]
        for s, e in true_runs(res.contact[:, c]):
            ax.axvspan(res.frames[s] - step / 2, res.frames[e - 1] + step / 2, color="#f4a261", alpha=0.35, lw=0)
        ax.plot(x, rec.values[:, c], lw=0.7, color="#264653")
        ax.axhline(th.value, ls="--", lw=1.0, color="#e76f51")
        for f in (res.clock.f0, res.clock.f1):
            ax.axvline(f, ls=":", lw=1.0, color="#6a4c93")
        ax.set_ylim(-0.02 * rec.adc_max, 1.04 * rec.adc_max)
        ax.set_ylabel("reading", fontsize=8)
        ax.set_title(f"{rec.channels[c]} -> {rec.joints[c]}: threshold {th.value:.0f} ({th.source})", fontsize=9,
                     loc="left")
        ax.tick_params(labelsize=7)
        h = fig.add_subplot(grid[c, 1], sharey=ax)
        h.hist(rec.values[a:b, c], bins=64, range=(0, rec.adc_max), orientation="horizontal", color="#2a9d8f",
               log=True)
        h.axhline(th.value, ls="--", lw=1.0, color="#e76f51")
        h.tick_params(labelsize=6, labelleft=False)
    ax0.set_xlim(x[0], x[-1])
    fig.axes[-2].set_xlabel("video frame (dotted: start / end clap; shaded: contact)", fontsize=8)
    fig.suptitle(f"{Path(rec.path).name}: raw sensor readings, thresholds (dashed) and contact", fontsize=10)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.png")
    fig.savefig(tmp, format="png")
    os.replace(tmp, path)
    return path


# ---- into a dataset --------------------------------------------------------------------

@dataclass
class DatasetTarget:
    root: Path
    sequence: str
    start: int                  # the sequence's rows [start, end) of the per-frame arrays
    end: int
    joint_names: tuple[str, ...]
    frames: np.ndarray          # (T,) video frame position of each of the sequence's frames
    half_width: float           # video frames either side that one dataset frame covers
    frame_offset: float


def dataset_frames(root: str | Path, sequence: str, video_fps: float, frame_offset: float,
                   rec: SensorRecording) -> DatasetTarget:
    """Where a dataset sequence's frames lie in the video: frame k at video frame
    frame_offset + k * video_fps / dataset fps. Checks that the dataset has the sensors' joints."""
    ds = MotionDataset.open(root, check_values=False)
    seq = next((s for s in ds.sequences if s.name == sequence), None)
    if seq is None:
        raise DataError(Path(root) / "sequences.json", sequence, "no sequence with this name")
    names = ds.joint_set.names
    for col, j in zip(rec.channels, rec.joints):
        if j not in names:
            raise DataError(Path(root) / "meta.json", "joint_names",
                            f"sensor column {col!r} labels joint {j!r}, which this dataset's joint set "
                            f"({ds.joint_set.name}) lacks")
    ratio = video_fps / ds.fps
    frames = frame_offset + ratio * np.arange(seq.num_frames, dtype=np.float64)
    return DatasetTarget(Path(root), seq.name, seq.start, seq.end, tuple(names), frames, ratio / 2, frame_offset)


def attach_to_dataset(t: DatasetTarget, rec: SensorRecording, res: SensorContact, merge: str, report: dict) -> dict:
    """Write the sensors' joint contact into the sequence's rows of `contact.npy`: the
    sensors' joints take the sensor labels (merge="replace") or keep what they had as well
    (merge="or"); other joints and sequences are untouched. The new file is written beside the
    old one and renamed over it (readers that have it memory-mapped keep the old one);
    `meta.json` `contact_sensors.<sequence>` then records where the labels came from."""
    path = t.root / "contact.npy"
    contact = np.load(path, allow_pickle=False)                                # (N, J) bool, a copy in RAM
    if contact.ndim != 2 or contact.shape[1] != len(t.joint_names) or contact.dtype != bool:
        raise DataError(path, "contact", f"expected (N, {len(t.joint_names)}) bool, "
                                         f"found {contact.dtype} {contact.shape}")
    jc = joint_contact(res.contact, rec.joints, t.joint_names)                 # (T, J)
    cols = sorted({t.joint_names.index(j) for j in rec.joints})
    before = contact[t.start:t.end, cols].copy()
    if merge == "replace":
        contact[t.start:t.end, cols] = jc[:, cols]
    else:
        contact[t.start:t.end, cols] |= jc[:, cols]
    tmp = path.with_name(f".contact.{os.getpid()}.tmp.npy")
    with open(tmp, "wb") as f:
        np.save(f, contact, allow_pickle=False)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    meta_path = t.root / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta.setdefault("contact_sensors", {})[t.sequence] = {
        "signal": rec.path, "columns": rec.channels, "joints": rec.joints, "merge": merge,
        "frame_offset": t.frame_offset, "video_fps": res.clock.video_fps, "clap_samples": list(res.clap_samples),
        "clap_frames": [res.clock.f0, res.clock.f1],
        "thresholds": {ch: round(th.value, 2) for ch, th in zip(rec.channels, res.thresholds)}}
    _replace_text(meta_path, json.dumps(meta, indent=2))
    changed = int((contact[t.start:t.end, cols] != before).sum())
    report["summary"].append(f"dataset {t.root}: sequence {t.sequence!r} frames {t.end - t.start}, joints "
                             f"{', '.join(t.joint_names[c] for c in cols)}: {changed} labels changed ({merge})")
    return {"root": str(t.root), "sequence": t.sequence, "joints": [t.joint_names[c] for c in cols],
            "labels_changed": changed, "merge": merge}
