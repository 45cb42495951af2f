"""Keyframe store: policy, memory bound on a long run, corrections, thread safety of snapshots."""
from __future__ import annotations

import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.geometry import exp_se3, make_pose
from lite_vo.keyframes import Keyframe, KeyframeStore, pose_distance, pose_distances

CAM = PinholeIntrinsics(60.0, 60.0, 31.5, 23.5, 64, 48)


def _kf(i, x, scale_id=0, rng=None):
    rng = rng or np.random.default_rng(i)
    d = np.full((48, 64), 0.5, np.float32)
    d.reshape(-1)[rng.permutation(d.size)[:d.size // 2]] = np.nan   # half empty: every keyframe the same size
    return Keyframe.make(i, i / 30, make_pose(np.eye(3), [x, 0, 0]), CAM, np.full((48, 64), 100, np.uint8),
                         d, np.where(np.isfinite(d), 1e-4, np.nan), None, scale_id)


def test_wants_a_keyframe_only_after_enough_motion():
    st = KeyframeStore(min_translation_rel=0.1, min_rotation_deg=5)
    assert st.wants(np.eye(4), 0)
    st.add(_kf(0, 0.0))                                   # median depth 2: 0.2 world units to move
    assert not st.wants(make_pose(np.eye(3), [0.1, 0, 0]), 0)
    assert st.wants(make_pose(np.eye(3), [0.3, 0, 0]), 0)
    assert st.wants(np.eye(4), 1)                         # a new scale always starts a keyframe


def test_memory_stays_within_bound_on_a_long_run():
    one = _kf(0, 0.0).nbytes
    st = KeyframeStore(max_bytes=20 * one + 10, max_keyframes=1000)
    for i in range(500):                                  # a long run along a line, back and forth
        st.add(_kf(i, float(np.sin(i / 40.0)) * 5))
        assert st.nbytes <= st.max_bytes
    assert len(st) == 20 and st.added == 500 and st.removed == 480
    xs = sorted(k.T_world_cam[0, 3] for k in st)
    assert xs[-1] - xs[0] > 8.0                           # thinning keeps the whole path, not the recent past
    assert st.snapshot()[-1].index == 499


def test_pose_distances_match_pose_distance_pairwise():
    rng = np.random.default_rng(5)
    poses = np.stack([exp_se3(rng.normal(size=6) * 0.4) for _ in range(12)])
    d = pose_distances(poses, 1.7)
    naive = np.array([[pose_distance(a, b, 1.7) for b in poses] for a in poses])
    off = ~np.eye(12, dtype=bool)
    np.testing.assert_allclose(d[off], naive[off], rtol=0, atol=1e-12)


def _thin_index_naive(kfs):
    """The thinning rule written out pair by pair (the store's twin): the most redundant keyframe."""
    depth = kfs[-1].median_depth
    best, best_d = 0, np.inf
    for i in range(len(kfs) - 1):
        d = sum(sorted(pose_distance(kfs[i].T_world_cam, kfs[j].T_world_cam, depth)
                       for j in range(len(kfs)) if j != i)[:2])
        if d < best_d - 1e-12:
            best, best_d = i, d
    return best


def test_thinning_drops_the_keyframe_the_pairwise_rule_picks():
    rng = np.random.default_rng(2)
    for n in (2, 3, 9):
        st = KeyframeStore(max_keyframes=1000)
        for i in range(n):
            kf = _kf(i, float(rng.normal()))
            st.add(kf.with_pose(exp_se3(rng.normal(size=6) * 0.3)))
        assert st._thin_index() == _thin_index_naive(st.snapshot())


def test_old_scale_thinned_first_and_corrections_move_keyframes():
    one = _kf(0, 0.0).nbytes
    st = KeyframeStore(max_bytes=3 * one + 10)
    st.add(_kf(0, 0.0, scale_id=0))
    st.add(_kf(1, 1.0, scale_id=0))
    st.add(_kf(2, 2.0, scale_id=1))
    st.add(_kf(3, 3.0, scale_id=1))
    assert [k.index for k in st] == [1, 2, 3]
    assert [k.index for k in st.current()] == [2, 3]
    T = make_pose(np.eye(3), [7.0, 0, 0])
    before = st.snapshot()
    assert st.apply_corrections({2: T, 1: None, 99: T}) == 2
    assert [k.index for k in st] == [2, 3]
    assert st.snapshot()[0].T_world_cam[0, 3] == 7.0
    assert before[1].T_world_cam[0, 3] == 2.0             # snapshots are immutable
    assert not before[1].idepth.flags.writeable


def test_vo_fills_the_store_and_session_hands_it_to_sinks(synth_small):
    import lite_vo
    from lite_vo.session import OutputSink, Session

    class Grab(OutputSink):
        def on_start(self, info):
            self.store = info.keyframes

    g = Grab()
    cfg = lite_vo.load_profile("phone", ['system.init="random"'])
    Session(synth_small, cfg, sinks=[g], pose_source="gt").run()
    kfs = g.store.snapshot()
    assert len(kfs) >= 3
    idx = [k.index for k in kfs]
    assert idx == sorted(idx)
    for a, b in zip(kfs, kfs[1:]):                        # each keyframe moved enough from the previous one
        assert np.linalg.norm(a.T_world_cam[:3, 3] - b.T_world_cam[:3, 3]) > 0 or \
            not np.allclose(a.T_world_cam[:3, :3], b.T_world_cam[:3, :3])


def test_store_bound_comes_from_the_profile(synth_small):
    """``system.keyframe_memory_mb`` bounds the store of a run: a 1.5 MB bound keeps the store under it
    (a keyframe at this size is well under 1 MB), where the default keeps more."""
    import lite_vo
    from lite_vo.session import OutputSink, Session

    class Grab(OutputSink):
        def on_start(self, info):
            self.store = info.keyframes

    sizes = {}
    for mb in (32.0, 1.5):
        g = Grab()
        cfg = lite_vo.load_profile("phone", ['system.init="random"', f"system.keyframe_memory_mb={mb}"])
        Session(synth_small, cfg, sinks=[g], pose_source="gt").run()
        assert g.store.max_bytes == int(mb * 2**20)
        kfs = g.store.snapshot()
        sizes[mb] = (len(kfs), sum(k.nbytes for k in kfs))
    assert sizes[1.5][1] <= 1.5 * 2**20 and sizes[1.5][0] < sizes[32.0][0]
    assert lite_vo.load_profile("board").system.keyframe_memory_mb == 16.0


def test_keyframe_spacing_comes_from_the_profile(synth_small):
    """``system.keyframe_min_move`` / ``keyframe_min_turn_deg`` decide when a map becomes a keyframe: a
    wider spacing makes fewer keyframes on the same run (poses given: the same maps either way), and
    consecutive keyframes are at least that far apart (moved or turned)."""
    import lite_vo
    from lite_vo.session import OutputSink, Session

    class Grab(OutputSink):
        def on_start(self, info):
            self.store = info.keyframes

    kfs = {}
    for move, turn in ((0.03, 3.0), (0.15, 15.0)):
        g = Grab()
        cfg = lite_vo.load_profile("phone", ['system.init="random"', f"system.keyframe_min_move={move}",
                                             f"system.keyframe_min_turn_deg={turn}"])
        Session(synth_small, cfg, sinks=[g], pose_source="gt").run()
        assert (g.store.min_translation_rel, g.store.min_rotation_deg) == (move, turn)
        kfs[move] = g.store.snapshot()
    assert 2 <= len(kfs[0.15]) < len(kfs[0.03])
    for a, b in zip(kfs[0.15], kfs[0.15][1:]):
        if a.scale_id != b.scale_id:
            continue
        depth = a.median_depth if np.isfinite(a.median_depth) else 1.0     # as the store measures it
        moved = np.linalg.norm(b.T_world_cam[:3, 3] - a.T_world_cam[:3, 3]) / depth
        c = (np.trace(a.T_world_cam[:3, :3].T @ b.T_world_cam[:3, :3]) - 1.0) / 2.0
        turned = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
        assert moved > 0.15 or turned > 15.0, (moved, turned)


def _colour_jpeg_copy(src, dst):
    """The sequence ``src`` (grey PNGs) as tinted colour JPEGs in ``dst`` (the same luma, about)."""
    import shutil

    import cv2
    shutil.copytree(src, dst)
    lines = []
    for line in (dst / "rgb.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            lines.append(line)
            continue
        t, name = line.split()
        g = cv2.imread(str(dst / name), cv2.IMREAD_GRAYSCALE).astype(np.float32)
        bgr = np.clip(np.dstack([0.8 * g, g, 1.2 * g]), 0, 255).astype(np.uint8)
        (dst / name).unlink()
        name = name.replace(".png", ".jpg")
        cv2.imwrite(str(dst / name), bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
        lines.append(f"{t} {name}")
    (dst / "rgb.txt").write_text("\n".join(lines) + "\n")
    return dst


def test_session_decodes_colour_for_the_keyframes_only(synth_small, tmp_path, monkeypatch):
    """A run with no sink showing frames reads a colour JPEG's luma plane and decodes its colour only
    when the frame becomes a keyframe (a colour decode costs ~3x a grey one); the keyframes keep colour."""
    import lite_vo
    from lite_vo.io import sequences
    from lite_vo.keyframes import Keyframe
    from lite_vo.session import OutputSink, Session

    seq = _colour_jpeg_copy(synth_small, tmp_path / "jpeg")
    decoded, made = [], []
    real_decode, real_make = sequences._decode_colour, Keyframe.make
    monkeypatch.setattr(sequences, "_decode_colour", lambda *a: decoded.append(1) or real_decode(*a))
    monkeypatch.setattr(Keyframe, "make", staticmethod(lambda *a, **k: made.append(a[7] is not None) or real_make(*a, **k)))

    class Grab(OutputSink):
        def on_start(self, info):
            self.store = info.keyframes

    g = Grab()
    cfg = lite_vo.load_profile("phone", ['system.init="random"'])
    res = Session(seq, cfg, sinks=[g], pose_source="gt").run()
    assert len(res.poses) == 45 and 3 <= len(made) < 45
    assert len(decoded) == len(made) and all(made)            # one colour decode per keyframe, each with colour
    kfs = g.store.snapshot()
    assert kfs and all(k.color is not None and k.color.shape[:2] == k.image.shape for k in kfs)
