"""Exports of generated motion: the video (`video`, drawn by `video_frame` with `obstacles` and
the skinned bodies of `render_body`, through a camera: `camera`, chosen by `video_camera` among
`adaptive_camera`, `follow_camera` and a top view) and static trajectory figures
(`trajectory_plot`). BVH export lives in `motiongen.bvh.export`."""
