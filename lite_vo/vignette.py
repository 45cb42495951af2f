"""Vignetting estimated from a run (self-calibration): ``lite-vo run ... --estimate-vignette``.

A camera darkens its image towards the corners (``I = V(x) * E`` for the irradiance ``E``). When
the camera moves, one scene point is seen at different distances from the image centre, so the
ratio of its intensities in two frames carries ``V(u) / V(p)``. The VO's own maps give these
correspondences for free: every pixel ``p`` of a published semi-dense map has an inverse depth,
so it lands at ``u`` in the next published map's frame (the same correspondences the depth
filter's propagation uses). Over a run, the points cross the image at every radius.

Model (radial about the principal point, the optical axis, as the vignette of most lenses; ``rho`` =
distance from it over the distance to the farthest image corner, so 1 there)::

    V(rho) = 1 + k1 rho^2 + k2 rho^4 + k3 rho^6
    I_new(u) = a * V(u) / V(p) * I_old(p) + b        (a, b per pair of maps: exposure changes)

Fitted by alternating the per-pair ``(a, b)`` (weighted linear least squares) with Gauss-Newton
steps on ``k`` (all pairs together), Huber-weighted, each residual weighted by the intensity
gradient at ``u`` (a sub-pixel error of the pose or the depth moves an edge's intensity a lot).
The result is written in DSO's format (``vignette.png``, 16 bit, maximum 1, at the camera's native
resolution), so ``lite-vo run ... --photometric DIR`` corrects every image with it on the next run.

The model, the correspondences and the fit live in :mod:`lite_vo.vignette_fit` (re-exported here), which the VO
also uses to estimate the vignette during a run (``system.auto_vignette``). numpy only; cv2 for the PNG.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from .errors import InputError
from .io import write_file_atomic
from .session import OutputSink
from .vignette_fit import (CORNER_RANGE, INTENSITY_SIGMA, MAX_CORNER_STD, MAX_FRAME_GAP,
                          MAX_POINTS_PER_PAIR, MIN_POINTS_PER_PAIR, PAIR_OUTLIER_FACTOR, POSITION_SIGMA_PX,
                          SATURATION, OnlineVignette, PairSamples, VignetteFit, correspondences, fit_problem,
                          fit_vignette, radial_frame, radius2, vignette_image, vignette_of)

log = logging.getLogger(__name__)

__all__ = ["CORNER_RANGE", "INTENSITY_SIGMA", "MAX_CORNER_STD", "MAX_FRAME_GAP", "MAX_POINTS_PER_PAIR",
           "MIN_POINTS_PER_PAIR", "PAIR_OUTLIER_FACTOR", "POSITION_SIGMA_PX", "SATURATION", "OnlineVignette",
           "PairSamples", "VignetteFit", "VignetteSink", "correspondences", "fit_problem", "fit_vignette",
           "radial_frame", "radius2", "vignette_image", "vignette_of", "write_vignette"]

def write_vignette(folder: Path, fit: VignetteFit, camera, map_camera, given: np.ndarray | None = None) -> Path:
    """``folder/vignette.png`` (16 bit, maximum 65535 = 1) and ``folder/vignette.json`` (the fit);
    ``given``: a vignette the images were already corrected with (multiplied in)."""
    import cv2
    folder = Path(folder)
    v = vignette_image(fit, camera, map_camera)
    if given is not None:
        v = v * np.asarray(given, np.float64)
        v = v / v.max()
    path = folder / "vignette.png"
    if not cv2.imwrite(str(path), np.round(v * 65535.0).astype(np.uint16)):
        raise InputError(f"{path}: could not write the vignette image")
    write_file_atomic(folder / "vignette.json", json.dumps(fit.to_dict(), indent=2) + "\n")
    return path


class VignetteSink(OutputSink):
    """Collects the correspondences of consecutive published maps during a run and, at the end,
    fits the vignette and writes ``vignette.png`` / ``vignette.json`` into ``folder`` (a run that
    gives too little or too weak data writes no PNG, only ``vignette.json`` with ``"written": false`` and
    the reason). ``camera``: the sequence's
    :class:`~lite_vo.camera.Camera` (the PNG is at its native resolution). ``given``: the
    :class:`~lite_vo.photometric.PhotometricCalibration` the run already corrected with, if any: with a
    vignette, the fit is what was left and the written vignette is the product of both; its inverse
    response is written beside it (``pcalib.txt``), so the folder is the whole calibration."""

    #: it fits the images as they come: a Session with this sink turns ``system.auto_vignette`` off
    wants_raw_images = True

    def __init__(self, folder, camera, given=None) -> None:
        self.folder = Path(folder)
        self.camera = camera
        self.given = given
        self.pairs: list[PairSamples] = []
        self.previous = None
        self.fit: VignetteFit | None = None
        self.error: str | None = None

    def on_map(self, published) -> None:
        if self.previous is not None:
            p = correspondences(self.previous, published)
            if p is not None:
                self.pairs.append(p)
        self.previous = published

    def on_finish(self, end) -> None:
        frame = radial_frame(self.previous.camera) if self.previous is not None else (0.0, 0.0, 1.0)
        try:
            self.fit = fit_vignette(self.pairs, frame)
            problem = fit_problem(self.fit)
            if problem:
                raise InputError(f"vignette estimate rejected: {problem}")
        except InputError as err:
            self.error = str(err)
            log.warning("%s; no vignette.png written", err)
            record = self.fit.to_dict() if self.fit is not None else {}
            record.update(written=False, reason=self.error)
            write_file_atomic(self.folder / "vignette.json", json.dumps(record, indent=2) + "\n")
            return
        given = self.given
        path = write_vignette(self.folder, self.fit, self.camera, self.previous.camera,
                              given.vignette if given is not None else None)
        if given is not None and given.inverse_response is not None:
            write_file_atomic(self.folder / "pcalib.txt", " ".join(f"{v:.6f}" for v in given.inverse_response) + "\n")
        f = self.fit
        log.info("vignette: %.1f %% +- %.1f at the corners (%d pairs of maps, %d points) -> %s",
                 100 * f.corner, 100 * f.corner_std, f.pairs, f.samples, path)
