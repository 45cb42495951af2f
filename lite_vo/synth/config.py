"""Settings of the synthetic-sequence generator (:class:`SynthConfig`).

Owns every number the renderer, the exposure model and the sensor model use. Imports only the
standard library and :mod:`lite_vo.config_fields`.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

from ..config_fields import param
from ..errors import ConfigError


@dataclass(frozen=True)
class SynthConfig:
    """Renderer, camera, exposure and sensor settings of :func:`lite_vo.synth.generate_sequence`."""
    focal_640_px: float = param(525.0, "focal length fx = fy in pixels for a 640 px wide image "
                                "(scaled with the width; TUM Kinect-like)", 50.0, 5000.0)
    supersample: int = param(3, "anti-aliasing: ss x ss rays per pixel are averaged (see "
                             "adaptive_aa)", 1, 6)
    adaptive_aa: bool = param(True, "supersample only pixels at geometric edges (their 3x3 "
                              "neighbourhood sees several faces); textures are band-limited by "
                              "trilinear mip-mapping anyway. False: supersample every pixel")
    lod_bias: float = param(0.0, "added to the mip level chosen from the sample footprint "
                            "(> 0 blurs more, < 0 sharper with more aliasing)", -3.0, 3.0)
    min_cos: float = param(0.1, "grazing-angle clamp of |cos| when estimating the texture "
                           "footprint (area-based mip selection)", 0.01, 1.0)
    blur_window_s: float = param(1.0 / 60.0, "motion blur: exposure time covered by the "
                                 "sub-frame renders, centred on the frame timestamp", 0.0, 0.2)
    exposure_gain_amp: float = param(0.15, "exposure changes: relative amplitude of the smooth "
                                     "per-frame gain", 0.0, 0.9)
    exposure_offset_amp: float = param(8.0, "exposure changes: amplitude of the smooth per-frame "
                                       "offset (grey levels)", 0.0, 100.0)
    exposure_period_s: float = param(7.0, "exposure changes: base period of the gain/offset "
                                     "sinusoids (seconds)", 0.5, 1000.0)
    accel_noise_std: float = param(0.0, "white noise std of the accelerometer (m/s^2)", 0.0, 10.0)
    accel_rate_hz: float = param(0.0, "accelerometer.txt sample rate (Hz) over the frames' time "
                                 "span; 0: one sample at each frame timestamp", 0.0, 2000.0)
    depth_scale: float = param(5000.0, "depth PNG units per metre (TUM: 5000)", 1.0, 1e5)
    start_time_s: float = param(0.0, "timestamp of the first frame (seconds)", 0.0, 1e10)
    png_compression: int = param(1, "cv2 PNG compression level (0 fastest .. 9 smallest)", 0, 9)

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
            if (lo is not None and value < lo) or (hi is not None and value > hi):
                raise ConfigError(f"synth config: {f.name}={value!r} outside [{lo}, {hi}]")
