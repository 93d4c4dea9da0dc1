"""Camera poses: images in, a sparse model out (``cam_from_world`` per image, intrinsics, 3D points).

- ``ingest``: a photo folder or a video -> the images to use (EXIF focal length, frames sampled from a video).
- ``sfm``: structure from motion with pycolmap (extract, match, map, undistort) -> ``OUT/sparse``;
  ``sfm_inputs``: its masks and the upscaled copies of small images.
- ``triangulate``: given cameras (COLMAP, transforms.json, ...) -> their sparse points, poses kept.
- ``scale``: the model in metres (a known distance, a marker, GPS) -> the scaled model and transforms.json.
"""
