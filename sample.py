"""Generate motion with a trained model: `python sample.py ckpt=PATH [scene=...] [goals=[[x,z],...]] ...`.

Autoregressive sampling towards goal points through a scene (docs/sampling.md). Everything
about the model comes from the checkpoint; motiongen/configs/sample.yaml lists every key.
The demo: `python sample.py ckpt=runs/demo/.../checkpoints/last.pt scene=synthetic:91`.
Same as `motiongen sample ...`.
"""

if __name__ == "__main__":
    from motiongen.apps import run_app

    run_app("sample")
