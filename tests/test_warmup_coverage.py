"""`lite-vo warmup` must compile every kernel signature a real run uses (else the first frame on a
board is seconds late): after warmup(), processing frames adds no new numba signature."""
from __future__ import annotations

import importlib

import numpy as np

import lite_vo
from lite_vo.warmup import KERNEL_MODULES, warmup


def _dispatchers():
    out = {}
    for name in KERNEL_MODULES:
        if not name.startswith("lite_vo"):
            continue
        try:
            mod = importlib.import_module(name)
        except ImportError:
            continue
        for attr, obj in vars(mod).items():
            if hasattr(obj, "signatures") and hasattr(obj, "py_func"):
                out[f"{name}.{attr}"] = obj
    return out


def test_a_run_after_warmup_compiles_nothing_new(synth_small):
    warmup([m for m in KERNEL_MODULES if m.startswith("lite_vo")])
    before = {k: len(d.signatures) for k, d in _dispatchers().items()}
    seq = lite_vo.open_sequence(synth_small)
    for init in ("depth", "random"):
        cfg = lite_vo.load_profile("phone", [f'system.init="{init}"'])
        with lite_vo.VisualOdometry(seq.camera, cfg) as vo:
            for fr, _ in zip(seq, range(10)):
                vo.process(fr.image, fr.timestamp, depth=fr.depth)
    after = {k: len(d.signatures) for k, d in _dispatchers().items()}
    new = {k: after[k] - before.get(k, 0) for k in after if after[k] != before.get(k, 0)}
    assert new == {}, f"kernels compiled after warmup (signatures missing from warmup()): {new}"
    assert np.sum(list(before.values())) > 10
