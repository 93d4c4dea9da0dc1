"""Per-image depth: images with their cameras and sparse points in, a z-depth map (with confidence, and normals
from PatchMatch) per view out, in ``OUT/depth``.

- ``methods``: the depth methods, in one registry (``methods/__init__.py``): per view, run by ``mvs``
  (``patchmatch``: PatchMatch stereo, its numba kernels in ``patchmatch/kernels.py``; ``sweep``: plane-sweep
  stereo), or writing the whole stage (``mono``: monocular ONNX models; ``given``: a folder of depth maps).
- ``config``: the stage's settings (``MVSConfig``) and per-view result (``DepthResult``).
- ``mvs``: multi-view stereo on the CPU, the orchestration (``run_mvs``: which views, their plan, the report);
  ``graph``: its task graph (the method's tasks, then the filter per view); ``work``: what the tasks share
  (context, images and masks at working resolution, the work folder's files).
- ``select``: the source views of each view and its depth range; ``views``: which views get a depth map.
- ``filter`` (+ ``_filter_kernel``, numba): the multi-view geometric consistency filter; ``fill``: small gaps
  after it; ``planar``: the planar prior and texture tests.
- ``mono`` + ``align``: monocular ONNX depth models, aligned to the SfM points.
"""
