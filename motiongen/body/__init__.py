"""SMPL-X body model and joints → body-parameter fitting (see docs/body.md).

model.py (file loading, fast joint kinematics, LBS mesh), rotations.py, procedural.py (a
licence-free model file in the official layout), motion.py (synthetic motion), mlp.py and
train_mlp.py (3-frame joints → parameters network), fit.py (initialisation + refinement).
Depends only on motiongen.skeleton/geometry/errors/paths (and data.format for training data).
"""
