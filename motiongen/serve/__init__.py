"""`motiongen serve`: steer a body live from a web page (docs/serve.md).

`session` runs the generation thread and the playback clock around a
`motiongen.sampling.live.LiveSampler`; `server` serves the page and the JSON API; `launch`
builds both from the command's keys; `downloads` writes what was generated as npz, BVH or glTF.
"""
