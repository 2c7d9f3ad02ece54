"""Evaluation: motion-quality metrics (pure numpy, see motiongen.metrics)."""
