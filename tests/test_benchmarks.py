"""The speed figure's script keeps running on today's sampler: it builds its own model, outside
`load_model`, so a field the sampler starts to read (as the swing table did) breaks it silently."""

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


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
