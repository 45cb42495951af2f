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
    n_kf = n_points = 0
    for init in ("depth", "random"):
        # every published map a keyframe: the cloud's cross-keyframe check runs within ten frames
        cfg = lite_vo.load_profile("phone", [f'system.init="{init}"', "system.keyframe_min_move=0",
                                             "system.keyframe_min_turn_deg=0"])
        with lite_vo.VisualOdometry(seq.camera, cfg) as vo:
            for fr, _ in zip(seq, range(10)):
                vo.process(fr.image, fr.timestamp, depth=fr.depth)
            n_kf = max(n_kf, len(vo.keyframes))
            n_points += len(vo.point_cloud().points)         # map.ply's cloud: its kernels too
    assert n_kf >= 2 and n_points > 0                        # (the cross-keyframe check ran)
    after = {k: len(d.signatures) for k, d in _dispatchers().items()}
    new = {k: after[k] - before.get(k, 0) for k in after if after[k] != before.get(k, 0)}
    assert new == {}, f"kernels compiled after warmup (signatures missing from warmup()): {new}"
    assert np.sum(list(before.values())) > 10


_RUNTIME_PROBE = r"""
import importlib, json, sys
import lite_vo
from lite_vo.warmup import CORE_KERNEL_MODULES, warmup

def counts():
    out = {}
    for name in CORE_KERNEL_MODULES:
        for attr, obj in vars(importlib.import_module(name)).items():
            if hasattr(obj, "signatures") and hasattr(obj, "py_func"):
                out[f"{name}.{attr}"] = len(obj.signatures)
    return out

warmup(CORE_KERNEL_MODULES, runtime=True)       # what Session.run loads before the first frame
runtime = counts()
seq = lite_vo.open_sequence(sys.argv[1])
for profile, init in (("phone", "depth"), ("phone", "random"), ("board", "depth")):
    cfg = lite_vo.load_profile(profile, [f'system.init="{init}"'])
    with lite_vo.VisualOdometry(seq.camera, cfg) as vo:
        for fr, _ in zip(seq, range(10)):
            vo.process(fr.image, fr.timestamp, depth=fr.depth)
after_run = counts()
warmup(CORE_KERNEL_MODULES)                     # `lite-vo warmup`: everything the tests and tools use too
full = counts()
print(json.dumps({"runtime": runtime, "after_run": after_run, "full": full}))
"""


def test_the_runtime_warmup_loads_what_a_run_uses_and_less_than_everything(synth_small):
    """Session.run warms up with runtime=True (each loaded kernel costs memory): a run afterwards loads
    no further kernel signature, and the full warm-up (`lite-vo warmup`) loads strictly more."""
    import json
    import subprocess
    import sys
    warmup([m for m in KERNEL_MODULES if m.startswith("lite_vo")])      # cache everything (no compile below)
    out = subprocess.run([sys.executable, "-c", _RUNTIME_PROBE, str(synth_small)], capture_output=True, text=True,
                         check=True, timeout=600)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    new = {k: v - res["runtime"].get(k, 0) for k, v in res["after_run"].items() if v != res["runtime"].get(k, 0)}
    assert new == {}, f"kernel signatures a run loaded that the runtime warm-up left out: {new}"
    assert sum(res["full"].values()) > sum(res["runtime"].values()) > 10
