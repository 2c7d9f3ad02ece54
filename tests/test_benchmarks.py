"""Benchmark scripts that docs/results.md's figures come from. The speed figure's script keeps
running on today's sampler: it builds its own model, outside `load_model`, so a field the
sampler starts to read (as the swing table did) breaks it silently. The toe-clearance script
counts what it says on a hand-made motion."""

import importlib
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from motiongen.data.windows import WindowDataset
from motiongen.skeleton import BODY_JOINT_NAMES
from tests.helpers import make_dataset
from tests.test_sample_cli import _checkpoint

REPO = Path(__file__).resolve().parents[1]


def benchmark(name: str):
    """The module benchmarks/<name>.py (the folder on sys.path only while it is imported, as the
    scripts import their neighbours by name)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(REPO / "benchmarks"))


def test_sample_benchmark_prints_a_row_with_the_full_clean_up(tmp_path):
    cmd = [sys.executable, str(REPO / "benchmarks" / "sample.py"), "preset=tiny", "episodes=2", "samplers=ddim-2",
           "batches=1", "precisions=fp32,int8", "threads=1"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line.split() for line in done.stdout.splitlines() if line.split()[:1] == ["ddim-2"]]
    assert len(rows) == 2 and rows[1][2] == "int8", done.stdout          # int8 layers sample the same walk
    assert rows[1][5] == rows[0][5]                                       # seconds of motion
    # sampler batch precision solve memo motion-s wall-s RTF frames/s x-first body-% peak-MiB
    _, batch, prec, solve, _, motion_s, wall_s, rtf, _, ratio, body, _ = rows[0]
    assert (batch, prec, solve) == ("1", "fp32", "refined")                  # the default final solve
    assert float(motion_s) > 1.0 and float(wall_s) > 0
    assert abs(float(rtf) - float(motion_s) / float(wall_s)) < 0.1 * float(rtf)     # the printed columns are rounded
    assert float(ratio) == 1.0 and 0 < float(body) < 100
    for prec in ("fp32", "int8-encoders", "int8"):
        assert re.search(rf"ceiling at batch 1, {prec}, .*\n  at most [\d.]+x real time for 2 steps", done.stdout)


def test_toe_clearance_counts_the_toes_that_move():
    """A toe gliding at 1 m/s 2 cm up, the other still: only the glide counts, at 0.02 m; lifted
    to 12 cm over its middle frames, those transitions count at the higher frame's height. The
    pelvis walking at 0.8 m/s is the speed each counted transition is binned by."""
    fast_toe_heights = benchmark("toe_clearance").fast_toe_heights
    from motiongen.metrics import TOE_JOINTS
    fps, T = 30.0, 11
    j = np.zeros((T, 22, 3))
    left, right = TOE_JOINTS
    j[:, left, 0] = np.arange(T) / fps                   # 1 m/s along x
    j[:, left, 1] = 0.02
    j[:, right, 1] = 0.02                                # still
    j[:, 0, 2] = 0.8 * np.arange(T) / fps                # the pelvis at 0.8 m/s along z
    h, v = fast_toe_heights(j, fps)
    assert np.allclose(h, 0.02) and len(h) == T - 1 and np.allclose(v, 0.8)
    j[4:7, left, 1] = 0.12
    h, _ = fast_toe_heights(j, fps)
    assert np.allclose(np.sort(h), [0.02] * 6 + [0.12] * 4)   # transitions 3-4 ... 6-7 touch a lifted frame


def test_toe_clearance_travel_is_how_far_pelvis_and_toes_go():
    """A pelvis that moves 1.2 m with one toe stepping 0.9 m and the other still: pelvis 1.2,
    toes 0.45 (their mean); a window that comes back where it started travelled nothing."""
    travel = benchmark("toe_clearance").travel
    from motiongen.metrics import TOE_JOINTS
    j = np.zeros((2, 12, 22, 3))
    j[0, :, 0, 2] = np.linspace(0.0, 1.2, 12)
    j[0, 6:, TOE_JOINTS[0], 2] = 0.9
    j[1, :, 0, 0] = np.sin(np.linspace(0.0, np.pi, 12))      # out and back along x
    pelvis, toes = travel(j)
    assert np.allclose(pelvis, [1.2, 0.0]) and np.allclose(toes, [0.45, 0.0])


def test_chained_windows_hand_on_the_networks_own_frames(tmp_path):
    """Along a sequence, the chained network's window 2 starts with its own last 2 frames of
    window 1, in the world (the loop's hand-over); given the data's frames instead it starts
    with the data's. The first window is the same either way."""
    chained = benchmark("chained_windows")
    K, chain_starts, run_chains = chained.K, chained.chain_starts, chained.run_chains
    model_and_data = benchmark("network_facing").model_and_data
    ckpt = _checkpoint(make_dataset(tmp_path / "ds", T=150) / "ckpt.pt")
    loaded, ds = model_and_data(str(ckpt))
    wd = WindowDataset(ds, "val", loaded.window, loaded.stats)
    starts = chain_starts(ds, wd, "val", 2, 10)
    assert len(starts) == 2                                      # one chain in each of the two val sequences
    data, given = run_chains(loaded, wd, starts, 2, 2, own=False)
    _, own = run_chains(loaded, wd, starts, 2, 2, own=True)
    assert np.allclose(own[:, 0], given[:, 0])
    assert np.allclose(own[:, 1, :K], own[:, 0, -K:], atol=1e-4)
    assert np.allclose(given[:, 1, :K], data[:, 1, :K], atol=1e-4)
    assert not np.allclose(own[:, 1, K:], given[:, 1, K:], atol=1e-3)
    assert np.allclose(data[:, 1, :K], data[:, 0, -K:], atol=1e-4)   # the data's windows overlap by K frames


def test_seams_counts_skating_by_distance_to_an_episode_start(tmp_path):
    """Toes that slide fast and low only over frames 40-43 (an episode starts at 42): every
    skating transition lies within 3 frames of that seam, none elsewhere, at 30 fps and at the
    model's 10 fps (every third frame)."""
    skating_near_seams = benchmark("seams").skating_near_seams
    from motiongen.metrics import TOE_JOINTS
    T = 90
    j = np.zeros((1, T, 22, 3), np.float32)
    j[:, :, list(TOE_JOINTS), 1] = 0.02
    for toe in TOE_JOINTS:
        j[0, 40:, toe, 0] = np.minimum(np.arange(T - 40), 3) * 0.1          # 3 m/s for 3 transitions
    np.savez(tmp_path / "motion.npz", joints_raw=j, fps=30.0, model_fps=10.0, episode_starts=np.array([0, 42]),
             joint_names=np.array(BODY_JOINT_NAMES))
    line = skating_near_seams(str(tmp_path / "motion.npz"))
    rates = re.findall(r"at (\d+) fps ([\d.]+); near a seam \(\d+% of frames\) ([\d.]+), elsewhere ([\d.]+)", line)
    assert [r[0] for r in rates] == ["30", "10"], line                # the output's rate, then the model's
    for _, total, near, elsewhere in rates:
        assert float(elsewhere) == 0 and float(near) > 0, line
    assert rates[0][1] == f"{3 / (T - 1):.3f}", line                  # 3 of the T - 1 transitions at 30 fps


def test_seams_reports_the_loops_own_step_into_each_episode():
    """A pelvis that moves 1 cm per model frame and 20 cm into the first frame of each episode
    (output frames 30 and 60 at 30 fps, model frames 10 and 20 at 10 fps): 20 / 1 cm."""
    seam_steps = benchmark("seams").seam_steps
    T = 90
    step = np.full(T // 3, 0.01)                                            # step[i]: into model frame i
    step[[10, 20]] = 0.20
    x = np.cumsum(step)                                                     # (30,) model frames
    j = np.zeros((2, T, 22, 3))
    j[:, :, :, 0] = np.repeat(x, 3)[None, :, None]                          # each model frame held 3 output frames
    line = seam_steps({"joints_raw": j, "joint_names": np.array(BODY_JOINT_NAMES),
                       "episode_starts": np.array([0, 30, 60])}, 3)
    assert "pelvis 20.0 / 1.0" in line and "head 20.0 / 1.0" in line, line


def test_seams_measures_feet_behind_the_pelvis_on_walking_windows(capsys):
    """The data's toes under its pelvis as it walks 1.2 m; the network's stay where they start:
    0 cm for the data at every frame, for the network the pelvis's travel at that frame. A
    window that stands is not counted."""
    feet_behind = benchmark("seams").feet_behind
    L = 13
    walk = np.zeros((L, 22, 3))
    walk[:, :, 2] = np.linspace(0, 1.2, L)[:, None]                         # everything moves 0.1 m per frame
    stay = walk.copy()
    stay[:, [BODY_JOINT_NAMES.index("left_foot"), BODY_JOINT_NAMES.index("right_foot")], 2] = 0.0
    data = np.stack([walk, np.zeros((L, 22, 3))])
    net = np.stack([stay, np.zeros((L, 22, 3))])
    feet_behind(data, net, list(BODY_JOINT_NAMES))
    out = capsys.readouterr().out
    assert "1 windows" in out and "frames [1, 3, 6, 9, 12]" in out, out
    assert re.search(r"data +0\.0 0\.0 0\.0 0\.0 0\.0", out), out
    assert re.search(r"network +10\.0 30\.0 60\.0 90\.0 120\.0", out), out


def test_window_speed_reads_the_pace_by_episode_phase():
    """Episodes of 42 output frames at 30 fps (21 model frames at 15 fps) after a 6-frame warm-up;
    the pelvis steps at 0.2 m/s over each episode's first 10 output frames and at 1.0 m/s after:
    model frames 0-4 read 0.2, 5-20 read 1.0 (the warm-up, shorter, is not counted)."""
    ws = benchmark("window_speed")
    starts = np.array([0, 6, 48, 90, 132])
    T = 174
    v = np.ones(T - 1)
    for a in starts[1:]:
        v[a:a + 10] = 0.2
    j = np.zeros((1, T, 22, 3))
    j[0, 1:, :, 2] = np.cumsum(v / 30.0)[:, None]
    phase = ws.speed_by_phase(j, starts, 30.0, 2)
    assert phase.shape == (21,)
    np.testing.assert_allclose(phase[:5], 0.2, atol=1e-9)
    np.testing.assert_allclose(phase[5:], 1.0, atol=1e-9)


def test_window_speed_compares_the_walking_windows_frame_by_frame():
    """The data walks 1.2 m/s across 13 frames at 10 fps; the network the same until its last 4
    steps, at 0.3 m/s; a window that stands is not counted."""
    ws = benchmark("window_speed")
    L = 13
    data = np.zeros((2, L, 22, 3))
    data[0, :, :, 2] = (np.arange(L) * 0.12)[:, None]
    net = data.copy()
    net[0, -4:, :, 2] = (data[0, -5, 0, 2] + 0.03 * np.arange(1, 5))[:, None]
    d, m, n = ws.speed_by_window_frame(data, net, 10.0)
    assert n == 1
    np.testing.assert_allclose(d, 1.2, atol=1e-9)
    np.testing.assert_allclose(m[:-4], 1.2, atol=1e-9)
    np.testing.assert_allclose(m[-4:], 0.3, atol=1e-9)


def test_seam_and_toe_scripts_refuse_bad_input_in_one_line(tmp_path):
    """An unknown key, a bad number, a missing file, nothing to measure, a motion of one
    episode: one line naming it on stderr, exit status 2, no traceback."""
    one = tmp_path / "one.npz"
    np.savez(one, joints=np.zeros((1, 40, 22, 3)), joints_raw=np.zeros((1, 40, 22, 3)), fps=30.0, model_fps=15.0,
             episode_starts=np.array([0]))
    cases = {"seams.py": [["bogus=1"], ["windows=abc"], [str(tmp_path / "none.npz")], []],
             "toe_clearance.py": [["bogus=1"], ["windows=abc"], [str(tmp_path / "none.npz")], ["split=val"]],
             "window_speed.py": [["bogus=1"], ["windows=abc"], [str(tmp_path / "none.npz")], [], [str(one)]],
             "pskl_by_action.py": [["bogus=1"], [], ["ckpt=none.npz"]]}
    for script, argvs in cases.items():
        for argv in argvs:
            done = subprocess.run([sys.executable, str(REPO / "benchmarks" / script), *argv], capture_output=True,
                                  text=True, timeout=120, cwd=tmp_path)
            err = done.stderr.strip().splitlines()
            assert done.returncode == 2 and len(err) == 1 and "Traceback" not in done.stderr, (script, argv, done.stderr)
            assert any(word in err[0] for word in ("bogus", "abc", "none.npz", "usage", "episodes")), (script, argv, err)


def test_pskl_by_action_reads_the_walking_pace():
    walk = np.zeros((60, 22, 3))
    walk[:, 0, 0] = 0.02 * np.arange(60)                # 0.02 m a frame at 30 fps
    np.testing.assert_allclose(benchmark("pskl_by_action").pace([walk], 30.0), [0.6])
