"""The names and fixed fields of the motiongen dataset format (docs/data_format.md), shared by
the reader (`format`), the writer (`dataset_writer`) and the contact-label columns."""

FORMAT_NAME = "motiongen-dataset"
FORMAT_VERSION = 1
SMPLX_FIELDS = {"global_orient": 3, "body_pose": 63, "transl": 3, "betas": 10}
# TRUMANS convention (the TRUMANS supplement, B.2): split by scene id.
DEFAULT_SPLITS = {"train": list(range(1, 71)), "val": list(range(71, 81)), "test": list(range(91, 101))}
