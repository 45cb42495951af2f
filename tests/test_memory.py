"""Memory over long runs: what a run keeps per frame is bounded (issue 18).

No RSS thresholds here (they depend on the machine and the allocator): tracemalloc counts what
the Python side keeps. RSS over 1k/5k/10k frames is in ``benchmarks/memory.md``
(``tools/bench_memory.py``).
"""
from __future__ import annotations

import gc
import json
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from lite_vo.records import PoseRecord, RowRecord
from lite_vo.timing import Timers

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))


def _traced_growth(fn, module) -> tuple[int, int]:
    """(bytes, blocks) still allocated after ``fn()`` that were not before (tracemalloc), counting only
    the allocations made in ``module``'s file: tracemalloc sees every thread, and a thread another test
    left behind in the same worker must not count."""
    tracemalloc.start()
    try:
        keep_only = [tracemalloc.Filter(True, module.__file__)]
        before = tracemalloc.take_snapshot().filter_traces(keep_only)
        keep = fn()
        after = tracemalloc.take_snapshot().filter_traces(keep_only)
    finally:
        tracemalloc.stop()
    diff = after.compare_to(before, "filename")
    del keep
    return sum(d.size_diff for d in diff), sum(d.count_diff for d in diff)


def test_timers_keep_every_value_in_about_4_bytes_and_summarise_them_exactly():
    rng = np.random.default_rng(0)
    values = {name: rng.gamma(2.0, 3.0, 20_000) for name in ("tracking", "mapping", "observe")}
    timers = Timers()

    def fill():
        for i in range(20_000):
            for name, v in values.items():
                timers.add(name, v[i])
        return timers

    size, blocks = _traced_growth(fill, sys.modules[Timers.__module__])
    n_values = 3 * 20_000
    assert size <= 2 * 4 * n_values + 4096        # float32 with doubling capacity; a list of floats is 32 B/value
    assert blocks <= 30                            # a few arrays, not one object per value
    assert timers.nbytes() <= 2 * 4 * n_values
    for name, v in values.items():
        kept = timers.values(name)
        assert kept.dtype == np.float32 and len(kept) == 20_000
        np.testing.assert_array_equal(kept, v.astype(np.float32))   # every value, in order
        s = Timers.summary(kept)
        assert s["count"] == 20_000
        assert s["median"] == pytest.approx(float(np.median(v)), rel=1e-5)
        assert s["p95"] == pytest.approx(float(np.percentile(v, 95)), rel=1e-5)
    assert Timers.summary(timers.values("unknown"))["count"] == 0


def test_pose_record_behaves_as_the_dict_it_replaces():
    rng = np.random.default_rng(1)
    rec, ref, removed = PoseRecord(), {}, []
    lost = []
    for i in range(300):
        if rng.random() < 0.2:                     # lost frame: recorded without a pose
            rec.add(i, 0.1 * i, None)
            lost.append(i)
            continue
        T = np.eye(4)
        T[:3, 3] = rng.normal(size=3)
        rec.add(i, 0.1 * i, T)
        ref[i] = (0.1 * i, T.copy())
        if rng.random() < 0.1 and ref:             # correct or drop an earlier pose (bootstrap)
            j = int(rng.choice(sorted(ref)))
            if rng.random() < 0.5:
                assert rec.correct(j, None)
                del ref[j]
                removed.append(j)
            else:
                T2 = np.eye(4)
                T2[:3, 3] = rng.normal(size=3)
                assert rec.correct(j, T2)
                ref[j] = (ref[j][0], T2)
    assert not rec.correct(10_000, np.eye(4))       # never recorded
    assert not rec.correct(lost[0], None)           # lost and still without a pose: nothing changes
    for j in lost[1:4]:                             # the start-up gives lost frames a pose afterwards
        T3 = np.eye(4)
        T3[:3, 3] = rng.normal(size=3)
        assert rec.correct(j, T3)
        ref[j] = (0.1 * j, T3)
    assert removed
    rec.add(removed[0], 0.1 * removed[0], np.eye(4))  # a removed pose given again comes back
    ref[removed[0]] = (0.1 * removed[0], np.eye(4))
    idx, ts, poses = rec.arrays()
    order = sorted(ref)
    assert len(rec) == len(order) and idx.tolist() == order
    np.testing.assert_array_equal(ts, [ref[i][0] for i in order])
    np.testing.assert_array_equal(poses, np.array([ref[i][1] for i in order]))
    assert order[0] in rec and 10_000 not in rec
    with pytest.raises(ValueError):
        rec.add(order[0] - 1 if order[0] > 0 else -1, 0.0, np.eye(4))   # out of order (and never seen)


def test_row_record_reads_back_as_the_list_of_dicts():
    rows = [{"frame": i, "t": i / 30, "density": 0.5 + i / 100, "compared": 10 * i} for i in range(50)]
    rec = RowRecord(("frame", "t", "density", "compared"), ints=("frame", "compared"))
    for r in rows:
        rec.append(r)
    assert len(rec) == 50 and rec.to_list() == rows and rec[-1] == rows[-1]
    assert json.loads(json.dumps(rec.to_list())) == rows
    np.testing.assert_array_equal(rec.column("t"), [r["t"] for r in rows])
    assert rec.nbytes() <= 2 * 8 * 4 * 64


def test_a_session_keeps_no_python_objects_per_frame(synth_small, tmp_path):
    """Over 60 frames of a long run with every output sink (the synthetic room played back and
    forth), the objects still allocated grow by a bound, not by one set of objects per frame
    (poses, timer values, depth accuracy rows)."""
    from pingpong import write_pingpong

    from lite_vo import load_profile
    from lite_vo.runner import run_sequence
    from lite_vo.session import OutputSink

    first, last = 70, 130
    seq = write_pingpong(synth_small, tmp_path / "pingpong", last)
    snaps = {}

    class Snapshots(OutputSink):
        def __init__(self):
            self.n = 0

        def on_frame(self, event):
            self.n += 1
            if self.n == 10:                       # traced well before the first snapshot: objects that live
                tracemalloc.start()                # for many frames (reference buffers) are traced in both
            if self.n in (first, last):
                gc.collect()                       # garbage in reference cycles is not kept
                snaps[self.n] = tracemalloc.take_snapshot()

    try:
        run_sequence(seq, load_profile("phone", ['system.init="depth"']), tmp_path / "out",
                     max_frames=last, sinks=[Snapshots()], kitti=True)
    finally:
        tracemalloc.stop()
    diff = snaps[last].compare_to(snaps[first], "lineno")
    # the run's own bookkeeping: the driver, the sinks, the VO and their records; the numba
    # dispatcher's own caches (attributed to the lines calling kernels in mapping/tracking) are not ours
    bookkeeping = ("session.py", "sinks.py", "system.py", "records.py", "timing.py")
    kept = {str(d.traceback): d.count_diff for d in diff
            if d.count_diff > 0 and "lite_vo" in d.traceback[0].filename
            and Path(d.traceback[0].filename).name in bookkeeping}
    # before issue 18: ~7 objects per frame here (pose dicts, tuples and 4x4 arrays in the driver
    # and the trajectory sink, a dict per depth accuracy row, timer floats); now arrays that double
    assert sum(kept.values()) <= last - first, kept


def test_the_reader_returns_free_memory_every_n_frames(monkeypatch):
    from lite_vo import session

    calls = []
    monkeypatch.setattr(session, "trim_malloc", lambda: calls.append(1) or True)
    frames = list(session.prefetch(list(range(250)), 0, None, trim_every=100))
    assert frames == list(range(250)) and len(calls) == 2
    calls.clear()
    assert list(session.prefetch(list(range(250)), 0, None, trim_every=0)) == list(range(250)) and not calls


def test_malloc_trimming_is_a_no_op_without_glibc(monkeypatch):
    import platform

    from lite_vo import session

    monkeypatch.setattr(session, "_glibc", None)
    monkeypatch.setattr(platform, "system", lambda: "Darwin")
    assert session.trim_malloc() is False
    monkeypatch.setattr(session, "_glibc", None)           # looked up again
    monkeypatch.setattr(platform, "system", lambda: "Linux")
    monkeypatch.setattr(platform, "libc_ver", lambda *a, **k: ("", ""))   # musl
    assert session.trim_malloc() is False


def test_the_vo_is_freed_before_the_exports(synth_small, monkeypatch):
    """The sinks' ``on_finish`` (map.ply, plots) runs after the VO's working state was released, so the
    exports reuse its memory instead of adding to the run's peak; the keyframe store stays readable."""
    import weakref

    import lite_vo
    from lite_vo import session as session_mod
    from lite_vo.session import OutputSink, Session

    made = []
    real = session_mod.VisualOdometry

    def spy(*a, **k):
        vo = real(*a, **k)
        made.append(weakref.ref(vo))
        return vo

    monkeypatch.setattr(session_mod, "VisualOdometry", spy)

    class Check(OutputSink):
        def on_start(self, info):
            self.store = info.keyframes

        def on_finish(self, end):
            self.alive_at_finish = made[0]() is not None
            self.keyframes_at_finish = len(self.store)

    c = Check()
    Session(synth_small, lite_vo.load_profile("phone", ['system.init="random"']), sinks=[c], pose_source="gt").run()
    assert len(made) == 1 and not c.alive_at_finish and c.keyframes_at_finish > 0
