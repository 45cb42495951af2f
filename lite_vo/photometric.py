"""Real cameras: photometric calibration (DSO format) and the per-frame photometric state.

Owns:

* :class:`PhotometricCalibration` - inverse response ``G^-1`` (``pcalib.txt``: 256 values), vignette
  ``V(x)`` (``vignette.png``, 8 or 16 bit, normalised to max 1) and optional exposure times;
  :meth:`~PhotometricCalibration.correct` turns a raw image into ``G^-1(I) / V(x)`` (times the
  reference exposure over the frame's), float32, before anything else sees it.
* :func:`load_photometric` - finds and reads those files (one-line :class:`InputError` on bad input).
* :func:`affine_transfer`, :func:`compose_affine` - the brightness chain ``I = A * J + B``.
* :class:`PhotometricMonitor` - tracking thread only: the brightness ``(A, B)`` of the last tracked
  frame, the sharpness history (motion-blur score) and the smoothed noise estimate.

Imports numpy, OpenCV (lazily, to read PNGs), :mod:`lite_vo.image` and :mod:`lite_vo.errors` only.
"""
from __future__ import annotations

import statistics
from collections import deque
from pathlib import Path

import numpy as np

from .errors import InputError
from .image import sharpness

PCALIB_FILE = "pcalib.txt"
VIGNETTE_FILE = "vignette.png"
TIMES_FILE = "times.txt"


class PhotometricCalibration:
    """Inverse response, vignette and exposure times of a camera (any of them may be absent).

    ``inverse_response``: (256,) float, ``G^-1`` of every 8-bit value, normalised (as DSO does) to
    ``G^-1(0) = 0``, ``G^-1(255) = 255``; ``vignette``: (H, W) float in (0, 1] at the raw image size;
    ``exposures``: ``{timestamp: exposure}`` (any unit; only ratios matter), looked up within 1 ms.
    """

    def __init__(self, inverse_response: np.ndarray | None = None, vignette: np.ndarray | None = None,
                 exposures: dict | None = None):
        if inverse_response is not None:
            g = np.asarray(inverse_response, np.float64)
            if g.shape != (256,) or not np.all(np.isfinite(g)) or not np.all(np.diff(g) > 0):
                raise InputError("inverse response: expected 256 finite, strictly increasing values")
            inverse_response = (255.0 * (g - g[0]) / (g[-1] - g[0])).astype(np.float32)
        if vignette is not None:
            v = np.asarray(vignette, np.float64)
            if v.ndim != 2 or not np.all(np.isfinite(v)) or not v.max() > 0:
                raise InputError("vignette: expected a 2-D image with a positive maximum")
            v = v / v.max()
            vignette = np.maximum(v, 1e-3).astype(np.float32)      # never divide by (almost) 0
        self.inverse_response = inverse_response
        self.vignette = vignette
        self._inv_vignette = None if vignette is None else (1.0 / vignette).astype(np.float32)
        self.exposures = dict(exposures or {})
        self._times = np.array(sorted(self.exposures)) if self.exposures else np.zeros(0)
        self.reference_exposure = float(np.median(list(self.exposures.values()))) if self.exposures else None

    def exposure_at(self, timestamp: float) -> float | None:
        """The exposure of the frame at ``timestamp`` (within 1 ms), or None."""
        if self._times.size == 0:
            return None
        i = int(np.searchsorted(self._times, timestamp))
        near = [t for t in self._times[max(i - 1, 0):i + 1] if abs(t - timestamp) <= 1e-3]
        return self.exposures[min(near, key=lambda t: abs(t - timestamp))] if near else None

    def correct(self, image: np.ndarray, exposure: float | None = None) -> np.ndarray:
        """``G^-1(I) / V(x)`` (and ``* reference_exposure / exposure`` when both are known), float32.

        ``image``: grey, uint8 (looked up) or float 0..255 (interpolated in ``G^-1``), at the raw
        camera resolution (the vignette's size)."""
        img = np.asarray(image)
        if img.ndim != 2:
            raise InputError(f"photometric correction: expected a grey image, got shape {img.shape}")
        if self.inverse_response is None:
            out = img.astype(np.float32)
        elif img.dtype == np.uint8:
            out = self.inverse_response[img]
        else:
            out = np.interp(img.astype(np.float32), np.arange(256, dtype=np.float32),
                            self.inverse_response).astype(np.float32)
        if self._inv_vignette is not None:
            if self._inv_vignette.shape != out.shape:
                raise InputError(f"photometric correction: vignette is {self._inv_vignette.shape[1]}x"
                                 f"{self._inv_vignette.shape[0]}, image is {out.shape[1]}x{out.shape[0]}")
            out = out * self._inv_vignette
        if exposure is not None and self.reference_exposure is not None and exposure > 0:
            out = out * np.float32(self.reference_exposure / exposure)
        return np.ascontiguousarray(out, dtype=np.float32)


def _read_pcalib(path: Path) -> np.ndarray:
    try:
        text = path.read_text()
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror})") from None
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        raise InputError(f"{path}: expected 256 numbers (the inverse response G^-1)") from None
    if len(values) != 256:
        raise InputError(f"{path}: expected 256 numbers (the inverse response G^-1), found {len(values)}")
    g = np.array(values)
    if not np.all(np.diff(g) > 0):
        raise InputError(f"{path}: the inverse response must increase strictly")
    return g


def _read_vignette(path: Path) -> np.ndarray:
    import cv2
    v = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if v is None:
        raise InputError(f"{path}: cannot read the vignette image")
    if v.ndim == 3:
        v = cv2.cvtColor(v, cv2.COLOR_BGR2GRAY)
    if v.dtype not in (np.uint8, np.uint16) or not v.max() > 0:
        raise InputError(f"{path}: expected an 8- or 16-bit grey image with a positive maximum")
    return v.astype(np.float64)


def _read_exposures(path: Path) -> dict:
    """DSO's times.txt: ``id timestamp exposure`` per line; lines without a third column are skipped."""
    out = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if len(parts) < 3:
            continue
        try:
            ts, exp = float(parts[1]), float(parts[2])
        except ValueError:
            raise InputError(f"{path}:{n}: expected 'id timestamp exposure', got {line.strip()!r}") from None
        if not (np.isfinite(ts) and np.isfinite(exp) and exp > 0):
            raise InputError(f"{path}:{n}: exposure must be a positive number")
        out[ts] = exp
    return out


def load_photometric(directory: str | Path | None, sequence_dir: str | Path | None = None
                     ) -> PhotometricCalibration | None:
    """The photometric calibration of a sequence, or None when there is none.

    ``directory`` (``--photometric DIR``): must hold ``pcalib.txt`` and/or ``vignette.png``.
    Without it, the files are picked up beside ``calib.txt`` in ``sequence_dir``. Exposure times
    come from ``times.txt`` (third column, as DSO) in ``directory`` or ``sequence_dir`` (exposure
    times alone are a calibration too: the images are scaled by the exposure ratio)."""
    seq = Path(sequence_dir) if sequence_dir is not None else None
    if directory is not None:
        d = Path(directory)
        if not d.is_dir():
            raise InputError(f"{d}: photometric calibration folder not found")
        if not (d / PCALIB_FILE).exists() and not (d / VIGNETTE_FILE).exists():
            raise InputError(f"{d}: no {PCALIB_FILE} or {VIGNETTE_FILE} in the photometric calibration folder")
    elif seq is not None and seq.is_dir():
        d = seq
    else:
        return None
    g = _read_pcalib(d / PCALIB_FILE) if (d / PCALIB_FILE).exists() else None
    v = _read_vignette(d / VIGNETTE_FILE) if (d / VIGNETTE_FILE).exists() else None
    exposures = {}
    for folder in (d, seq):
        if folder is not None and (folder / TIMES_FILE).exists():
            exposures = _read_exposures(folder / TIMES_FILE)
            break
    if g is None and v is None and not exposures:
        return None
    try:
        return PhotometricCalibration(g, v, exposures)
    except InputError as err:
        raise InputError(f"{d}: {err}") from None


# --------------------------------------------------------------------------- brightness chain
def affine_transfer(src: tuple, dst: tuple) -> tuple[float, float]:
    """``(a, b)`` with ``I_dst = a * I_src + b`` for two frames of brightness ``src``, ``dst``
    (each ``I = A * J + B`` for a common ``J``)."""
    a = float(dst[0]) / float(src[0])
    return a, float(dst[1]) - a * float(src[1])


def compose_affine(ref: tuple, rel: tuple) -> tuple[float, float]:
    """The brightness ``(A, B)`` of a frame with ``I = rel_a * I_ref + rel_b`` and ``I_ref = A_r J + B_r``."""
    return float(rel[0]) * float(ref[0]), float(rel[0]) * float(ref[1]) + float(rel[1])


class PhotometricMonitor:
    """Per-frame photometric state (tracking thread only).

    ``affine``: brightness ``(A, B)`` of the last tracked frame; ``noise_sigma``: smoothed image noise
    estimate (grey levels at the mapping resolution); ``residual_sigma``: smoothed robust std of the
    tracking residuals (grey levels at the tracking level); the sharpness history of the last
    ``blur_window`` frames.
    """

    def __init__(self, blur_window: int = 15, noise_smoothing: float = 0.2):
        self.affine = (1.0, 0.0)
        self.noise_sigma = float("nan")
        self.residual_sigma = float("nan")
        self._alpha = float(noise_smoothing)
        self._history: deque = deque(maxlen=max(int(blur_window), 1))

    def sharpness(self, image: np.ndarray) -> float:
        """The frame's sharpness relative to the median of the recent frames (1 = typical, lower =
        blurred; see :func:`lite_vo.image.sharpness`); the frame joins the history."""
        s = sharpness(image)
        if not np.isfinite(s):
            return 1.0
        self._history.append(s)
        med = statistics.median(self._history)       # np.median's value, a fifth of its cost on 15 floats
        return s / med if med > 0 else 1.0

    def affine_guess(self, ref_affine: tuple) -> tuple[float, float]:
        """Starting ``(a, b)`` of the next frame relative to a reference of brightness ``ref_affine``:
        the last frame's brightness (exposure changes slowly)."""
        return affine_transfer(ref_affine, self.affine)

    def accept(self, ref_affine: tuple, relative: tuple, residual_sigma: float, noise_sigma: float) -> tuple:
        """Book a tracked frame: its brightness (returned) and its noise estimates (smoothed)."""
        self.affine = compose_affine(ref_affine, relative)
        for name, value in (("residual_sigma", residual_sigma), ("noise_sigma", noise_sigma)):
            if np.isfinite(value):
                old = getattr(self, name)
                setattr(self, name, value if not np.isfinite(old) else (1 - self._alpha) * old + self._alpha * value)
        return self.affine

    def tracking_sigma(self, sigma_i: float, noise_gain: float, sharpness_score: float) -> float:
        """Intensity noise std for the tracking weights: ``max(sigma_i, noise_gain * residual_sigma)``,
        widened for a blurred frame (divided by its sharpness score when below 1: its residuals at
        edges are larger, its pose gets less say against the robust weights)."""
        s = float(sigma_i)
        if noise_gain > 0 and np.isfinite(self.residual_sigma):
            s = max(s, noise_gain * self.residual_sigma)
        if np.isfinite(sharpness_score) and 0 < sharpness_score < 1:
            s /= sharpness_score
        return s
