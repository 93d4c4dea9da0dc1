"""Camera poses: images in, a sparse model out (``cam_from_world`` per image, intrinsics, 3D points).

- ``ingest``: a photo folder -> the images to use, copied upright; ``photos``: the image gate for one photo (EXIF
  orientation and focal length, unusable photos left out); ``video``: frames sampled from a video; ``given``: the
  images of given cameras (``--poses``), undistorted, and a K matrix file (``--intrinsics``).
- ``sfm``: structure from motion with pycolmap (``run_sfm``, ``SfMConfig``) -> ``OUT/sparse``, one module per
  stage: ``extract``, ``match`` (with ``retrieval`` for large unordered sets), ``mapping``, ``undistort``;
  ``_colmap``: the lazy pycolmap import they share; ``sfm_inputs``: the masks and the upscaled copies of small
  images.
- ``triangulate``: given cameras (COLMAP, transforms.json, ...) -> their sparse points, poses kept.
- ``scale``: the model in metres (a known distance, a marker, GPS) -> the scaled model and transforms.json.
"""
