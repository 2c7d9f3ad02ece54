"""Hydra configs of train / sample / evaluate (a package so Hydra finds them in an installed motiongen)."""
