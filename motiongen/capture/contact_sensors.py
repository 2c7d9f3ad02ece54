"""Contact sensors -> per-frame joint contact (the multi-view capture paper, A2).

    motiongen contact-sensors signal=REC.csv video_fps=30 clap_frames=[F0,F1] out=DIR
        [clap_samples=[I0,I1]] [thresholds=[...]] [min_contact_frames=1] [min_gap_frames=1]
        [dataset=DIR sequence=NAME frame_offset=0 merge=replace] ...   (docs/capture.md: every key)

A trial starts and ends with hand claps, which show as short, tall peaks in the hand sensors.
`find_claps` finds them (`scipy.signal.find_peaks`: tall, prominent and narrow; the first and
the last are the start and end events, or `clap_samples=` names the two rows); the two
matching video frames (`clap_frames=`, located by hand in the video) fix a linear map from
sensor time to video frame (`ClockMap`: offset and the clocks' rate ratio, checked against
`video_fps`). Every channel is then resampled to the frames (mean over each frame's interval),
binarised with a per-sensor threshold (given, or Otsu's on the channel's own distribution of
readings within the trial), and runs shorter than `min_contact_frames` / gaps shorter than
`min_gap_frames` are flipped. Outputs (`sensor_outputs`): `contact.npz`, `report.json`, the
check plot `sensors.png` (as Fig. 2 of the multi-view capture paper) and, with
`dataset=`/`sequence=`, the contact labels of the sensors' joints written into that sequence's
`contact.npy`.
"""


from __future__ import annotations

from motiongen.capture.sensor_contact import process
from motiongen.capture.sensor_csv import SensorRecording, read_sensor_csv
from motiongen.capture.sensor_outputs import attach_to_dataset, dataset_frames, make_report, write_outputs
from motiongen.cli import parse_key_values, tool_main
from motiongen.errors import ConfigError

# ---- CLI -------------------------------------------------------------------------------

SPEC = {"signal": (str, None), "video_fps": (float, None), "clap_frames": (list, []), "out": (str, None),
        "clap_samples": (list, []), "clap_channels": (list, []), "clap_height": (float, 0.5),
        "clap_max_width": (float, 0.25), "max_drift": (float, 0.02), "time_unit": (str, "auto"),
        "adc_max": (int, 1023), "joints": (list, []), "thresholds": (list, []), "min_contrast": (float, 100.0),
        "clap_guard": (float, 0.5), "resample": (str, "mean"), "min_contact_frames": (int, 1),
        "min_gap_frames": (int, 1), "plot": (bool, True), "dataset": (str, None), "sequence": (str, None),
        "frame_offset": (float, 0.0), "merge": (str, "replace"), "mask_claps": (bool, True)}
USAGE = "signal=REC.csv video_fps=30 clap_frames=[F0,F1] out=DIR [dataset=DIR sequence=NAME]"


def _numbers(key: str, items: list[str], n: int, kind=float) -> list:
    if len(items) != n:
        raise ConfigError(f"{key}=[...]: expected {n} values, got {len(items)}")
    try:
        return [kind(v) for v in items]
    except ValueError:
        kinds = "integers" if kind is int else "numbers"
        raise ConfigError(f"{key}=[{','.join(items)}]: expected {n} {kinds}") from None


def parse_thresholds(items: list[str], rec: SensorRecording) -> list[float | None]:
    """thresholds=[...]: one entry per channel in column order (a reading, or auto), or
    COLUMN=reading entries for some channels (the others auto)."""
    C = len(rec.channels)
    out: list[float | None] = [None] * C
    named = [("=" in v) for v in items]
    if items and any(named) and not all(named):
        raise ConfigError("thresholds=[...]: give one value per column, or COLUMN=value entries, not both")
    pairs = [v.rsplit("=", 1) for v in items] if any(named) else list(enumerate(items))
    if not any(named) and items and len(items) != C:
        raise ConfigError(f"thresholds=[...]: expected {C} values (one per sensor column: {', '.join(rec.channels)}), "
                          f"got {len(items)}")
    for key, v in pairs:
        c = rec.channel_index(key.strip()) if isinstance(key, str) else key
        if v.strip().lower() == "auto":
            continue
        try:
            out[c] = float(v)
        except ValueError:
            raise ConfigError(f"thresholds: {v!r} is not a number or auto") from None
        if not 0 <= out[c] <= rec.adc_max:
            raise ConfigError(f"thresholds: {out[c]:g} for {rec.channels[c]} is outside 0..{rec.adc_max}")
    return out


def run(argv: list[str]) -> dict:
    o = parse_key_values(argv, SPEC, required=("signal", "video_fps", "clap_frames", "out"), usage=USAGE,
                         doc=__doc__)
    if o["merge"] not in ("replace", "or"):
        raise ConfigError(f"merge={o['merge']!r}: expected replace or or")
    if bool(o["dataset"]) != bool(o["sequence"]):
        raise ConfigError("dataset= and sequence= go together: name the dataset and the sequence to label")
    if o["min_contact_frames"] < 1 or o["min_gap_frames"] < 1:
        raise ConfigError("min_contact_frames and min_gap_frames must be >= 1 (1: no filtering)")
    rec = read_sensor_csv(o["signal"], o["time_unit"], o["adc_max"], o["joints"] or None)
    clap_frames = _numbers("clap_frames", o["clap_frames"], 2)
    clap_samples = _numbers("clap_samples", o["clap_samples"], 2, int) if o["clap_samples"] else None
    clap_channels = [rec.channel_index(c) for c in o["clap_channels"]] or None
    kwargs = dict(clap_samples=clap_samples, clap_channels=clap_channels, clap_height=o["clap_height"],
                  clap_max_width=o["clap_max_width"], max_drift=o["max_drift"],
                  thresholds=parse_thresholds(o["thresholds"], rec), min_contrast=o["min_contrast"],
                  clap_guard=o["clap_guard"], resample_method=o["resample"],
                  min_contact_frames=o["min_contact_frames"], min_gap_frames=o["min_gap_frames"],
                  mask_claps=o["mask_claps"])
    target = None
    if o["dataset"]:
        target = dataset_frames(o["dataset"], o["sequence"], o["video_fps"], o["frame_offset"], rec)
        kwargs.update(frames=target.frames, half_width=target.half_width)
    result = process(rec, o["video_fps"], clap_frames, **kwargs)
    report = make_report(rec, result)
    if target is not None:
        report["dataset"] = attach_to_dataset(target, rec, result, o["merge"], report)
    write_outputs(o["out"], rec, result, report, plot=o["plot"])
    for line in report["summary"]:
        print(line, flush=True)
    return report


main = tool_main(run)


if __name__ == "__main__":
    main()
