"""Camera models, calibration and camera files (thesis §3.2-3.3); pipeline code (numpy, scipy, OpenCV only).

* :mod:`bench.camera.model` - the projection chain (pinhole, intrinsics with skew, distortion) and ``CameraModel``;
* :mod:`bench.camera.heikkila` - the thesis's Heikkilä parameters (Eq. 74-86) and their mapping to OpenCV's;
* :mod:`bench.camera.io` - ``camera.yaml`` (OpenCV FileStorage keys); :mod:`bench.camera.presets` - named cameras;
* :mod:`bench.camera.dlt`, :mod:`bench.camera.calibration` - calibration from views of a target.
"""
