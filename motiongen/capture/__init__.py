"""Capture side: multi-view SMPL-X fitting and contact-sensor processing (seed 000, 002)."""
