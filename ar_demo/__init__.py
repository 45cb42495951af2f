"""ar_demo: the AR physics demo of thesis chapter 5.3 on top of lite_vo.

Ground plane from the accelerometer (:mod:`ar_demo.ground`), variational in-painting of the
semi-dense map (:mod:`ar_demo.inpaint`, eq. 5.6), collision mesh (:mod:`ar_demo.mesh`), world-model
builder (:mod:`ar_demo.world_model`), pybullet physics with a racecar (:mod:`ar_demo.physics`),
moderngl off-screen rendering (:mod:`ar_demo.render`), video, panels and the render thread
(:mod:`ar_demo.video`), the world the car lives in (:mod:`ar_demo.world`), the VO output sink that
wires them (:mod:`ar_demo.sink`: :class:`ARSink`), :func:`ar_demo.run.run_ar`, and the ``ar`` and
``demo`` commands (:mod:`ar_demo.cli`, registered with ``lite-vo`` through entry points).

May import lite_vo, numpy, numba, cv2, pybullet, trimesh, moderngl; lite_vo never imports ar_demo.
Submodules are imported lazily so ``import ar_demo`` stays cheap.
"""
from __future__ import annotations

_LAZY = {
    "ARConfig": ("ar_demo.config", "ARConfig"),
    "ar_config": ("ar_demo.config", "ar_config"),
    "run_ar": ("ar_demo.run", "run_ar"),
    "ARSink": ("ar_demo.sink", "ARSink"),
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'ar_demo' has no attribute {name!r}")
