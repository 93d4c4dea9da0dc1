"""Per-image depth: multi-view stereo on the CPU (``mvs``), monocular ONNX models aligned to SfM points
(``mono`` + ``align``)."""
