"""Contact sensors -> per-frame joint contact (`motiongen contact-sensors`), on
generated recordings with known clap times, thresholds and contact intervals."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motiongen.capture.contact_sensors import main
from motiongen.capture.sensor_contact import ClockMap, filter_min_duration, otsu, process, propose_threshold, resample
from motiongen.capture.sensor_csv import SensorRecording, read_sensor_csv
from motiongen.data.format import MotionDataset
from tests.helpers import user_error

REPO = Path(__file__).resolve().parents[1]
HEADER = ("left_hand", "right_hand", "left_foot:heel", "right_foot")
# Contact intervals [a, b) in video frames per column; the right hand also holds something
# for 2 s (a plateau the clap detector must not take for a clap).
INTERVALS = {"left_foot:heel": [(60, 120), (200, 260), (400, 480)], "right_foot": [(90, 180), (300, 420)],
             "right_hand": [(150, 210)]}
BASE, LEVEL = 30.0, 600.0


def write_recording(path, video_fps=30.0, f0=30, clap_times=(1.0, 18.5), duration=20.0, intervals=INTERVALS,
                    seed=0, drift=1.002):
    """A recording at ~100 Hz (millisecond stamps, jittered) whose claps at `clap_times` (s,
    sensor clock) are video frames f0 and f1 (the sensor clock runs `drift` slow, rounded so f1 is a
    whole frame); contact (readings ~600) while the video frame position is in [a - 0.5, b - 0.5)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(9, 12, int(duration * 110)))
    t = np.unique(np.concatenate([[0], t[t < duration * 1000], np.round(np.array(clap_times) * 1000)]))
    ts = t / 1000.0
    f1 = f0 + int(round((clap_times[1] - clap_times[0]) * video_fps * drift))
    clock = ClockMap(clap_times[0], clap_times[1], f0, f1, video_fps)
    v = clock.frame_of(ts)                                                    # (N,) video frame position
    vals = BASE + rng.normal(0, 5, (len(t), len(HEADER)))
    for col, ivs in intervals.items():
        c = HEADER.index(col)
        for a, b in ivs:
            on = (v >= a - 0.5) & (v < b - 0.5)
            vals[on, c] = LEVEL + rng.normal(0, 15, on.sum())
    rows = [int(np.searchsorted(ts, tc)) for tc in clap_times]
    for i in rows:                                                             # a clap: a 5-sample spike
        for c in (0, 1):
            vals[i - 2:i + 3, c] = [300, 700, 950, 700, 300]
    vals = np.clip(np.round(vals), 0, 1023)
    lines = ["time_ms," + ",".join(HEADER)]
    lines += [f"{t[k]}," + ",".join(str(int(x)) for x in vals[k]) for k in range(len(t))]
    Path(path).write_text("\n".join(lines) + "\n")
    return {"rows": tuple(rows), "f0": f0, "f1": f1, "clock": clock}


def truth(frames, ivs):
    on = np.zeros(len(frames), bool)
    for a, b in ivs:
        on |= (frames >= a) & (frames < b)
    return on


# ---- pieces with known answers -------------------------------------------------------------

def test_otsu_two_levels_and_brute_force():
    o = otsu(np.r_[np.full(100, 20), np.full(50, 600)])
    # every split between the two levels ties; the middle one is taken
    assert o.threshold == pytest.approx((20 + 599) / 2 + 0.5) and (o.mean_low, o.mean_high) == (20, 600)
    assert o.separability == pytest.approx(1.0)
    rng = np.random.default_rng(1)
    x = np.clip(np.round(np.r_[rng.normal(80, 20, 3000), rng.normal(500, 60, 1000)]), 0, 1023)
    o = otsu(x)
    ks = np.arange(1023)                                                        # class 0: x <= k
    w0 = np.array([(x <= k).mean() for k in ks])
    m0 = np.array([x[x <= k].mean() if (x <= k).any() else 0 for k in ks])
    m1 = np.array([x[x > k].mean() if (x > k).any() else 0 for k in ks])
    between = w0 * (1 - w0) * (m0 - m1) ** 2
    k = int(np.argmax(between))
    assert (x > o.threshold).sum() == (x > k).sum()                             # the same split
    assert 150 < o.threshold < 400 and o.separability == pytest.approx(between[k] / x.var(), rel=1e-6)
    assert otsu(np.full(10, 7.0)) is None


def test_unclear_channel_gets_a_flagged_threshold_above_its_noise():
    noise = np.round(np.random.default_rng(2).normal(40, 6, 2000))
    th = propose_threshold(noise, 1023, min_contrast=100)
    assert th.source == "unclear" and th.value == pytest.approx(np.median(noise) + 100) and (noise < th.value).all()
    two = np.r_[np.full(500, 40.0), np.full(500, 400.0)]
    assert propose_threshold(two, 1023, 100).source == "otsu"


def test_min_duration_filter():
    c = np.array([1, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 1, 0], bool)[:, None]
    # gaps shorter than 2 frames between contacts are filled (not the one at the start)
    np.testing.assert_array_equal(filter_min_duration(c, 1, 2)[:, 0], [1, 1, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 1, 0])
    # contacts shorter than 3 frames are dropped
    np.testing.assert_array_equal(filter_min_duration(c, 3, 1)[:, 0], [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 0])
    # fill first, then drop: the filled run 0..3 survives
    np.testing.assert_array_equal(filter_min_duration(c, 3, 2)[:, 0], [1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 0])
    np.testing.assert_array_equal(filter_min_duration(c, 1, 1), c)


def test_resample_mean_over_the_frame_and_linear_at_its_centre():
    t = np.arange(0, 1.0, 0.001)                                                # 1 kHz
    rec = SensorRecording("x", t, np.where(t < 0.5, 100.0, 500.0)[:, None], ["left_foot"], ["left_foot"], "s", 1023)
    clock = ClockMap(0.0, 1.0, 0.0, 10.0, 10.0)                                 # frame k at k / 10 s
    # frame 5 covers [0.45, 0.55): half at 100, half at 500
    np.testing.assert_allclose(resample(rec, clock, np.array([2.0, 5.0, 8.0]))[:, 0], [100, 300, 500])
    np.testing.assert_allclose(resample(rec, clock, np.array([2.0, 5.0, 8.0]), method="linear")[:, 0], [100, 500, 500])
    # a sensor slower than the video: frames between samples are interpolated
    slow = SensorRecording("x", np.array([0.0, 1.0]), np.array([[0.0], [1000.0]]), ["a"], ["left_foot"], "s", 1023)
    np.testing.assert_allclose(resample(slow, clock, np.array([2.5]))[:, 0], [250])


def test_clock_map_is_linear_and_invertible():
    c = ClockMap(1.0, 11.0, 30.0, 331.0, 30.0)
    assert c.frame_of(6.0) == pytest.approx(180.5) and c.time_of(c.frame_of(3.3)) == pytest.approx(3.3)
    assert c.drift == pytest.approx(301 / 300)


# ---- end to end ------------------------------------------------------------------------------

def test_cli_finds_claps_thresholds_and_contact_intervals(tmp_path):
    known = write_recording(tmp_path / "rec.csv")
    out = tmp_path / "out"
    main([f"signal={tmp_path / 'rec.csv'}", "video_fps=30", f"clap_frames=[{known['f0']},{known['f1']}]", f"out={out}"])
    report = json.loads((out / "report.json").read_text())
    assert report["claps"]["samples"] == list(known["rows"]) and report["claps"]["found"] == "detected"
    assert report["claps"]["candidates"] == list(known["rows"])               # the grasp plateau is no clap
    assert report["claps"]["clock_drift_ppm"] == pytest.approx((known["clock"].drift - 1) * 1e6, abs=1)
    with np.load(out / "contact.npz") as z:
        frames, contact, th = z["frames"], z["contact"], z["thresholds"]
        assert list(z["joints"]) == ["left_wrist", "right_wrist", "left_foot", "right_foot"]
        names = list(z["joint_names"])
        jc = z["joint_contact"]
    assert frames[0] == 0 and frames[-1] == 600 and np.all(np.diff(frames) == 1)
    for c, col in enumerate(HEADER):
        np.testing.assert_array_equal(contact[:, c], truth(frames, INTERVALS.get(col, [])), err_msg=col)
        np.testing.assert_array_equal(jc[:, names.index(report["channels"][c]["joint"])], contact[:, c])
    for c in (1, 2, 3):                                                          # Otsu between the two levels
        assert report["channels"][c]["threshold_source"] == "otsu" and BASE + 100 < th[c] < LEVEL - 100
    # the left hand never touches anything but the other hand: no clear level, no contact
    assert report["channels"][0]["threshold_source"] == "unclear" and not contact[:, 0].any()
    png = (out / "sensors.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert w == 1100 and h > 4 * 150                                            # one row per sensor
    assert not [p for p in out.iterdir() if ".tmp" in p.name]


def test_given_clap_rows_thresholds_and_filtering(tmp_path):
    known = write_recording(tmp_path / "rec.csv")
    rec = read_sensor_csv(tmp_path / "rec.csv")
    # a one-frame flip of each kind on the left heel: a spike while lifted, a dropout while down
    v = known["clock"].frame_of(rec.time)
    rec.values[(v >= 149.5) & (v < 150.5), 2] = LEVEL
    rec.values[(v >= 89.5) & (v < 90.5), 2] = BASE
    base = process(rec, 30.0, (known["f0"], known["f1"]), clap_samples=known["rows"], thresholds=[None, None, 250, 700])
    assert not base.claps_detected and len(base.clap_candidates) == 0
    assert [t.source for t in base.thresholds[2:]] == ["given", "given"] and base.thresholds[2].value == 250
    assert not base.contact[:, 3].any()                                          # 700 is above the contact level
    heel = base.contact[:, 2]
    f = base.frames.astype(int)
    assert heel[f == 150].all() and not heel[f == 90].any()
    clean = filter_min_duration(base.raw_contact, 3, 3)[:, 2]
    np.testing.assert_array_equal(clean, truth(base.frames, INTERVALS["left_foot:heel"]))
    # the same through the CLI keys, thresholds by column name
    out = tmp_path / "out"
    main([f"signal={tmp_path / 'rec.csv'}", "video_fps=30", f"clap_frames=[{known['f0']},{known['f1']}]",
          f"clap_samples=[{known['rows'][0]},{known['rows'][1]}]", "thresholds=[right_foot=700,left_foot:heel=250]",
          "min_contact_frames=3", "min_gap_frames=3", "plot=false", f"out={out}"])
    report = json.loads((out / "report.json").read_text())
    assert report["claps"]["found"] == "given" and not (out / "sensors.png").exists()
    assert [ch["threshold"] for ch in report["channels"][2:]] == [250, 700]


def test_video_faster_than_dataset_and_attach_to_a_sequence(tmp_path):
    """60 fps video, 30 fps dataset: dataset frame k of sequence s1_1 is video frame
    frame_offset + 2k and covers two video frames."""
    from helpers import make_dataset

    root = make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=2, T=120)
    before = np.load(root / "contact.npy")
    before[:, 15] = True                                                         # the head: not a sensor joint
    np.save(root / "contact.npy", before)
    ivs = {"left_foot:heel": [(120, 240), (400, 500)], "right_hand": [(300, 360)]}
    known = write_recording(tmp_path / "rec.csv", video_fps=60.0, f0=60, intervals=ivs)
    offset = 100
    main([f"signal={tmp_path / 'rec.csv'}", "video_fps=60", f"clap_frames=[{known['f0']},{known['f1']}]",
          f"out={tmp_path / 'out'}", f"dataset={root}", "sequence=s1_1", f"frame_offset={offset}", "plot=false"])
    ds = MotionDataset.open(root)                                                # still a valid dataset
    seq = next(s for s in ds.sequences if s.name == "s1_1")
    contact = np.asarray(ds.contact)
    video = offset + 2 * np.arange(seq.num_frames)
    names = list(ds.joint_set.names)
    rows = slice(seq.start, seq.end)
    np.testing.assert_array_equal(contact[rows, names.index("left_foot")], truth(video, ivs["left_foot:heel"]))
    np.testing.assert_array_equal(contact[rows, names.index("right_wrist")], truth(video, ivs["right_hand"]))
    assert not contact[rows, names.index("right_foot")].any() and not contact[rows, names.index("left_wrist")].any()
    others = np.ones(len(contact), bool)
    others[rows] = False
    np.testing.assert_array_equal(contact[others], before[others])               # other sequences untouched
    assert contact[:, 15].all()                                                  # other joints untouched
    meta = json.loads((root / "meta.json").read_text())
    assert meta["contact_sensors"]["s1_1"]["clap_frames"] == [known["f0"], known["f1"]]
    assert not [p for p in root.iterdir() if ".tmp" in p.name]
    # merge=or keeps what the dataset had for the sensors' joints
    extra = np.load(root / "contact.npy")
    extra[seq.start:seq.start + 3, names.index("right_foot")] = True
    np.save(root / "contact.npy", extra)
    main([f"signal={tmp_path / 'rec.csv'}", "video_fps=60", f"clap_frames=[{known['f0']},{known['f1']}]",
          f"out={tmp_path / 'out'}", f"dataset={root}", "sequence=s1_1", f"frame_offset={offset}", "plot=false",
          "merge=or"])
    after = np.load(root / "contact.npy")
    assert after[seq.start:seq.start + 3, names.index("right_foot")].all()
    np.testing.assert_array_equal(after[rows, names.index("left_foot")], truth(video, ivs["left_foot:heel"]))


# ---- user errors ------------------------------------------------------------------------------

def test_user_errors_exit_2_and_leave_the_dataset_alone(tmp_path, capsys):
    from helpers import make_dataset

    known = write_recording(tmp_path / "rec.csv")
    good = tmp_path / "rec.csv"
    claps = f"clap_frames=[{known['f0']},{known['f1']}]"
    base = ["video_fps=30", claps, f"out={tmp_path / 'o'}", "plot=false"]
    assert "does not exist" in user_error(capsys, main, [f"signal={tmp_path / 'none.csv'}"] + base)
    lines = good.read_text().splitlines()

    def variant(name, line, col=None, value=None, text=None):
        """The good file with line `line` (1-based) changed: one cell, or the whole line."""
        p = tmp_path / name
        rows = list(lines)
        if text is not None:
            rows[line - 1] = text
        else:
            cells = rows[line - 1].split(",")
            cells[col] = value
            rows[line - 1] = ",".join(cells)
        p.write_text("\n".join(rows) + "\n")
        return [f"signal={p}"] + base

    assert "line 6 column 3" in user_error(capsys, main, variant("nan.csv", 6, 2, "x"))
    assert "line 8: reading 2000" in user_error(capsys, main, variant("range.csv", 8, 2, "2000"))
    assert "line 10 " in user_error(capsys, main, variant("time.csv", 10, text=lines[8]))
    assert "line 5 has 4 values" in user_error(capsys, main, variant("short.csv", 5, text="40,1,2,3"))
    assert "[left_knuckle]" in user_error(capsys, main, variant("joint.csv", 1, 1, "left_knuckle"))
    assert "header line" in user_error(capsys, main, variant("nohead.csv", 1, text=lines[1]))
    # claps: without the end clap only one is found
    one = tmp_path / "one.csv"
    data = np.loadtxt(good, delimiter=",", skiprows=1)
    i1 = known["rows"][1]
    data[i1 - 2:i1 + 3, 1:3] = BASE
    np.savetxt(one, data, fmt="%d", delimiter=",", header="time_ms," + ",".join(HEADER), comments="")
    assert "clap_samples" in user_error(capsys, main, [f"signal={one}"] + base)
    assert "check clap_frames" in user_error(capsys, main, [f"signal={good}", "video_fps=30", "clap_frames=[30,500]",
                                                  f"out={tmp_path / 'o'}"])
    assert "0.1 Hz, time in s" in user_error(capsys, main, [f"signal={good}", "time_unit=s"] + base)
    assert "time unit" in user_error(capsys, main, [f"signal={good}", "time_unit=s", f"clap_samples=[{known['rows'][0]},"
                                                                           f"{known['rows'][1]}]"] + base)
    assert "after the start" in user_error(capsys, main, [f"signal={good}", "video_fps=30", "clap_frames=[50,40]",
                                                f"out={tmp_path / 'o'}"])
    assert "expected 4 values" in user_error(capsys, main, [f"signal={good}", "thresholds=[1,2]"] + base)
    assert "no sensor channel" in user_error(capsys, main, [f"signal={good}", "thresholds=[nose=3]"] + base)
    assert "merge" in user_error(capsys, main, [f"signal={good}", "merge=and"] + base)
    assert "go together" in user_error(capsys, main, [f"signal={good}", f"dataset={tmp_path}"] + base)
    assert "missing clap_frames" in user_error(capsys, main, [f"signal={good}", "video_fps=30", f"out={tmp_path / 'o'}"])
    # dataset: unknown sequence; frames outside the recording -> contact.npy unchanged
    root = make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=1, T=60)
    old = (root / "contact.npy").read_bytes()
    assert "no sequence" in user_error(capsys, main, [f"signal={good}", f"dataset={root}", "sequence=nope"] + base)
    assert "outside the recording" in user_error(capsys, main, [f"signal={good}", f"dataset={root}", "sequence=s1_0",
                                                      "frame_offset=580"] + base)
    index = variant("index.csv", 1, 1, "left_index1")[0]
    assert "lacks" in user_error(capsys, main, [index, f"dataset={root}", "sequence=s1_0"] + base)
    assert (root / "contact.npy").read_bytes() == old and "contact_sensors" not in (root / "meta.json").read_text()


def test_module_entry_point_exit_code(tmp_path):
    """`python -m` runs the same entry (the successful path is tested in-process above)."""
    write_recording(tmp_path / "rec.csv")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    bad = subprocess.run([sys.executable, "-m", "motiongen.capture.contact_sensors", f"signal={tmp_path / 'rec.csv'}",
                          "video_fps=30", f"out={tmp_path / 'out'}", "clap_frames=[1]"],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert bad.returncode == 2 and bad.stderr.startswith("error: clap_frames") and "Traceback" not in bad.stderr
    assert not (tmp_path / "out").exists()
