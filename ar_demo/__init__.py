"""ar_demo: the AR physics demo of thesis chapter 5.3 on top of lite_vo.

Ground plane from the accelerometer (:mod:`ar_demo.ground`), variational in-painting of the
semi-dense map (:mod:`ar_demo.inpaint`, eq. 5.6), collision mesh (:mod:`ar_demo.mesh`), world-model
builder (:mod:`ar_demo.world_model`), pybullet physics with a racecar (:mod:`ar_demo.physics`),
moderngl off-screen rendering (:mod:`ar_demo.render`), video and panels (:mod:`ar_demo.video`), and
the pipeline / VO output sink (:mod:`ar_demo.pipeline`: :func:`run_ar`, :class:`ARSink`).

May import lite_vo, numpy, numba, cv2, pybullet, trimesh, moderngl; lite_vo never imports ar_demo.
Submodules are imported lazily so ``import ar_demo`` stays cheap.
"""
from __future__ import annotations

_LAZY = {
    "ARConfig": ("ar_demo.config", "ARConfig"),
    "ar_config": ("ar_demo.config", "ar_config"),
    "run_ar": ("ar_demo.pipeline", "run_ar"),
    "ARSink": ("ar_demo.pipeline", "ARSink"),
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'ar_demo' has no attribute {name!r}")
