"""Capture side: multi-view SMPL-X fitting and contact-sensor processing (the multi-view capture
paper, A1 and A2), and the pose prior its fit decodes poses with."""
