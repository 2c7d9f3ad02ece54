"""Generate motion with a trained model: `python sample.py ckpt=PATH [scene=...] [goals=[[x,z],...]] ...`.

Autoregressive sampling towards goal points through a scene (docs/sampling.md). Everything
about the model comes from the checkpoint; `--help` lists every key (SampleConfig).
The demo: `python sample.py ckpt=runs/demo/.../checkpoints/last.pt scene=synthetic:91`.
Same as `motiongen sample ...`.
"""

if __name__ == "__main__":
    from motiongen.commands import run_script

    run_script("sample")
