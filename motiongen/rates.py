"""Rates every part of motiongen agrees on unless a file or a checkpoint says otherwise."""

# Frames per second of motion data and of generated motion: the TRUMANS release, AMASS and BVH
# imports are resampled to it, the sampler's output is written at it, and a checkpoint or npz
# file that records no rate was made at it.
DATA_FPS = 30.0

# Denoising steps of a sampler run (DDIM) when nobody asks for another count.
DEFAULT_STEPS = 25
