"""Exports of generated motion: the video (`video`, drawn by `video_frame` through the
`follow_camera` with `obstacles` and the skinned bodies of `render_body`) and static trajectory
figures (`trajectory_plot`). BVH export lives in `motiongen.bvh.export`."""
