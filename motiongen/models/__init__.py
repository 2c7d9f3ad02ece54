"""Networks: the transformer denoiser and its scene / action encoders."""

from motiongen.models.condition import Condition, drop_conditions
from motiongen.models.presets import PRESETS, ModelConfig, model_config
from motiongen.models.denoiser import Denoiser, EncodedCondition, build_model, count_parameters

__all__ = [
    "Condition", "drop_conditions", "ModelConfig", "PRESETS", "model_config", "Denoiser",
    "EncodedCondition", "build_model", "count_parameters",
]
