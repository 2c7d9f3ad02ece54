"""Diffusion: schedules, training loss, inpainting masks and samplers. Owns no network."""

from motiongen.diffusion.gaussian import GaussianDiffusion
from motiongen.diffusion.masks import MaskConfig, known_mask, sample_known_mask
from motiongen.diffusion.samplers import (DDIMScheduler, DDPMScheduler, Scheduler, make_scheduler,
                                          sample, spaced_timesteps)
from motiongen.diffusion.schedule import DiffusionConfig, make_betas

__all__ = [
    "GaussianDiffusion", "DiffusionConfig", "make_betas", "MaskConfig", "known_mask",
    "sample_known_mask", "Scheduler", "DDPMScheduler", "DDIMScheduler", "make_scheduler", "sample",
    "spaced_timesteps",
]
