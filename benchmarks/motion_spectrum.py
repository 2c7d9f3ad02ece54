"""Where PSKL comes from: acceleration power per frequency band, data vs generated (not a timed test).

    python benchmarks/motion_spectrum.py ckpt=PATH [scenes=91,95,97,100] [setting=static] [pairs=3]
                                         [sampler=ddim] [steps=10] [eta=0] [precision=auto|fp32|bf16]
                                         [solve.KEY=VALUE ...] [loop.KEY=VALUE ...]

Runs the `evaluate.py` protocol (k = 5, DDIM-10 unless sampler=/steps=/eta= say otherwise,
seed 0) on a few test scenes of one setting and prints, for the data, the network's own joints
and the output motions:
- foot skating (evaluate.py's figure) and grounded-toe slide, what a smoother output must keep;
- PSKL against the data, in nats and in multiples of the data's split-half value;
- the share of acceleration power in each frequency band (mean over joints and axes), the
  normalised spectra PSKL compares (motiongen.metrics.pskl, 2 s chunks at 30 fps), and
  the rms acceleration in each band, which says whether a share is off by excess or deficit;
- the floor set by the model's frame rate: the data taken to 10, 15 and 30 fps and resampled
  back the way generated motion is (motiongen.sampling.assemble.resample), scored against itself.
`solve.KEY=VALUE` overrides a field of the final body solve (motiongen.body.solve.SOLVE_CONFIG)
for this run, e.g. solve.w_contact=300; `loop.KEY=VALUE` one of the sampler's clean-up
keys, as evaluate.py takes them (loop.project, foot_lock, pin_goal, smooth, seam_blend,
solve_smoothness), e.g. loop.seam_blend=0 or loop.solve_smoothness=200 (the solve's
joint-acceleration weight, which the loop sets by the model's frame rate).
"""

from __future__ import annotations

import dataclasses
import sys
import time
import warnings

import numpy as np

BANDS = [(0, 2), (2, 3), (3, 5), (5, 8), (8, 15.01)]


def _args(argv):
    out = {"ckpt": None, "scenes": "91,95,97,100", "setting": "static", "pairs": "3",
           "sampler": "ddim", "steps": "10", "eta": "0", "precision": "auto"}
    for a in argv:
        k, _, v = a.partition("=")
        out[k] = v
    if not out["ckpt"]:
        sys.exit("usage: python benchmarks/motion_spectrum.py ckpt=PATH [scenes=..] [setting=static|dynamic]")
    return out


def band_power(motions, fps: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per band (len(BANDS),): the share of acceleration power (mean over the 3J features of
    the normalised spectra PSKL compares) and the rms acceleration [m/s^2] (root of the mean
    over features of the band's power, Parseval-scaled)."""
    from motiongen.eval.pskl_sets import _chunks
    chunks = _chunks(motions, n)
    acc = np.stack([np.diff(c, n=2, axis=0).reshape(n - 2, -1) for c in chunks]) * fps ** 2   # (N, E, F)
    power = np.mean(np.abs(np.fft.fft(acc, axis=1)) ** 2, axis=0)                             # (E, F)
    share = power / power.sum(0, keepdims=True)
    freqs = np.abs(np.fft.fftfreq(n - 2, 1 / fps))
    bands = [(freqs >= lo) & (freqs < hi) for lo, hi in BANDS]
    return (np.array([share[b].sum(0).mean() for b in bands]),
            np.array([np.sqrt(power[b].sum(0).mean()) / (n - 2) for b in bands]))


def main(argv) -> None:
    a = _args(argv)
    warnings.simplefilter("ignore")
    import motiongen.body.solve as solve
    from omegaconf import OmegaConf

    from motiongen.importers.sources import open_dataset
    from motiongen.eval.pairs import ProtocolConfig
    from motiongen.eval.protocol import evaluate
    from motiongen.eval.pskl_sets import pskl_equal, reference_halves
    from motiongen.eval.evaluate_config import dataset_config, loop_overrides
    from motiongen.sampling import SamplerSettings
    from motiongen.sampling.assemble import resample
    from motiongen.loading.build import load_model

    # each value in its field's type (max_steps is an int)
    over = {k[6:]: type(getattr(solve.SOLVE_CONFIG, k[6:]))(float(v)) for k, v in a.items() if k.startswith("solve.")}
    if over:
        solve.SOLVE_CONFIG = dataclasses.replace(solve.SOLVE_CONFIG, **over)
    # the same keys and checks as evaluate.py's loop group
    loop_over = loop_overrides(OmegaConf.from_dotlist([f"{k[5:]}={v}" for k, v in a.items() if k.startswith("loop.")]))
    loaded = load_model(a["ckpt"], "cpu", precision=a["precision"])
    ds = open_dataset(dataset_config(None, loaded.config), verbose=False)
    setting, scenes = a["setting"], [int(s) for s in a["scenes"].split(",")]
    pc = ProtocolConfig(k=5, pairs=int(a["pairs"]), loop=loop_over)
    t0 = time.perf_counter()
    sampler = SamplerSettings(a["sampler"], int(a["steps"]), float(a["eta"]), 1.0)
    ev = evaluate(loaded, ds, scenes, pc, settings=[setting], sampler=sampler, progress=False)
    fps, n = 30.0, pc.pskl_frames
    refs = [m for r in ev.references[setting] for m in r.motions]
    floor = ev.reference[setting]["pskl_gen_ref"]
    rows = {"data": refs,
            "network joints": [x for r in ev.results[setting] for x in r.kept_raw],
            "output": [x for r in ev.results[setting] for x in r.kept]}
    for stride in (3, 2, 1):
        rows[f"data at {30 // stride} fps, resampled"] = [resample(m[::stride][None], fps / stride, fps)[0] for m in refs]
    print(f"{a['ckpt']}: setting {setting}, scenes {scenes}, {pc.pairs} pairs x {pc.k} samples, "
          f"{time.perf_counter() - t0:.0f} s; data split-half PSKL {floor:.3f} nats"
          + f"; {a['sampler']}-{a['steps']} eta {a['eta']} {a['precision']}" + (f"; solve {over}" if over else "")
          + (f"; loop {loop_over}" if loop_over else ""))
    head = "".join(f"{lo:g}-{min(hi, 15):g} Hz".rjust(10) for lo, hi in BANDS)
    from motiongen.metrics import foot_skating_ratio, grounded_slide
    print(f"{'':30s}{'skating':>8s}{'slide':>7s}  (mean over motions; slide m/s, median over grounded toes)")
    for name in ("data", "network joints", "output"):
        ms = rows[name]
        print(f"{name:30s}{np.mean([foot_skating_ratio(m, fps) for m in ms]):8.3f}"
              f"{np.nanmean([grounded_slide(m, fps) for m in ms]):7.3f}")
    print(f"{'share of power per band':30s}{'PSKL(m,data) (data,m)':>26s}{head}")
    rms = {}
    # Each row against one half of the data at the half's size; the data row is the other half.
    other, half = reference_halves(refs, n)
    for name, motions in rows.items():
        kab, kba, _ = pskl_equal(other if name == "data" else motions, half, fps, n)
        share, rms[name] = band_power(motions, fps, n)
        print(f"{name:30s}{kab:7.3f} {kba:6.3f} ({kab / floor:4.1f}x {kba / floor:4.1f}x)"
              + "".join(f"{x:10.3f}" for x in share))
    print(f"{'rms acceleration [m/s^2]':56s}{head}")
    for name, r in rms.items():
        print(f"{name:56s}" + "".join(f"{x:10.3f}" for x in r))


if __name__ == "__main__":
    main(sys.argv[1:])
