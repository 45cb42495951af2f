"""VisualOdometry end to end on a small synthetic sequence: determinism, accuracy, threads,
loss and recovery, sinks, bad input."""
from __future__ import annotations

import time

import numpy as np
import pytest

import lite_vo
from lite_vo.errors import InputError
from lite_vo.eval import evaluate
from lite_vo.io import Trajectory
from lite_vo.runner import run_sequence
from lite_vo.system import VisualOdometry


def _traj(res):
    return Trajectory(np.asarray(res.timestamps), np.asarray(res.poses).reshape(-1, 4, 4))


def _frames(path, n=None):
    seq = lite_vo.open_sequence(path)
    frames = list(seq)
    return seq, frames[:n] if n else frames


def test_sync_mode_is_deterministic(synth_small):
    cfg = lite_vo.load_profile("phone", ['system.init="depth"'])
    a = run_sequence(synth_small, cfg, max_frames=30)
    b = run_sequence(synth_small, cfg, max_frames=30)
    assert len(a.poses) == len(b.poses) == 30
    assert np.array_equal(np.asarray(a.poses), np.asarray(b.poses))


def test_depth_initialised_run_tracks_every_frame_accurately(synth_small):
    cfg = lite_vo.load_profile("phone", ['system.init="depth"'])
    res = run_sequence(synth_small, cfg)
    seq = lite_vo.open_sequence(synth_small)
    assert res.status == "ok"
    assert res.info["frames"]["tracked"] == len(seq)
    ev = evaluate(seq.groundtruth, _traj(res), align="se3").to_dict()
    # metric run: drift below 5% of the path length
    assert ev["ate_pct_of_path"] < 5.0, ev


def test_gt_poses_random_init_converges_depth(synth_small):
    cfg = lite_vo.load_profile("phone", ['system.init="random"'])
    res = run_sequence(synth_small, cfg, pose_source="gt")
    acc = res.info["depth_accuracy"]
    assert acc is not None and acc["frames"] > 0
    assert acc["median_abs_rel_error"] < 0.05, acc
    assert acc["density"] > 0.10, acc


def test_depth_images_mode_tracks_without_mapping(synth_small):
    cfg = lite_vo.load_profile("phone")
    res = run_sequence(synth_small, cfg, depth_source="images", max_frames=20)
    assert res.info["frames"]["tracked"] == 20
    assert res.timing["mapping"]["count"] == 0
    seq = lite_vo.open_sequence(synth_small)
    ev = evaluate(seq.groundtruth, _traj(res), align="se3").to_dict()
    assert ev["ate_rmse_m"] < 0.02, ev


def test_realtime_mode_uses_a_mapping_thread_and_tracks(synth_small):
    sync_cfg = lite_vo.load_profile("phone", ['system.init="depth"'])
    rt_cfg = lite_vo.load_profile("phone", ['system.init="depth"', 'system.mode="realtime"',
                                            "system.realtime_speed=0.5"])
    seq = lite_vo.open_sequence(synth_small)
    sync = evaluate(seq.groundtruth, _traj(run_sequence(synth_small, sync_cfg)), align="se3").to_dict()
    rt_res = run_sequence(synth_small, rt_cfg)
    counts = rt_res.info["frames"]
    assert counts["tracked"] >= 0.9 * counts["in"]
    assert rt_res.timing["mapping"]["count"] >= 2  # the mapping thread ran
    rt = evaluate(seq.groundtruth, _traj(rt_res), align="se3").to_dict()
    assert rt["ate_rmse_m"] < max(3 * sync["ate_rmse_m"], 0.01), (rt, sync)


def test_realtime_mode_maps_at_most_every_map_every_th_frame(synth_small):
    """Realtime mode maps at most as often as sync mode: only frames whose index is a multiple of
    ``map_every`` (after the start-up, ``map_every_startup`` before) reach the mapping thread."""
    seq, frames = _frames(synth_small, 40)
    cfg = lite_vo.load_profile("phone", ['system.init="depth"', 'system.mode="realtime"', "system.map_every=3",
                                         "system.map_every_startup=5", "system.startup_s=0.5"])
    mapped = []
    with VisualOdometry(seq.camera, cfg) as vo:
        t0 = frames[0].timestamp
        for fr in frames:
            vo.process(fr.image, fr.timestamp, depth=fr.depth)
            time.sleep(0.02)                                # let the mapping thread take the frame
            mapped += [(m.frame_index, m.timestamp - t0) for m in vo.take_published_maps()]
    later = [i for i, t in mapped[1:] if t >= 0.5]         # the first map is the initialisation's
    early = [i for i, t in mapped[1:] if t < 0.5]
    assert len(later) >= 3, mapped
    assert all(i % 3 == 0 for i in later) and all(i % 5 == 0 for i in early), mapped


def test_loss_is_reported_as_a_gap_and_tracking_recovers(synth_small):
    seq, frames = _frames(synth_small, 36)
    cfg = lite_vo.load_profile("phone", ['system.init="depth"'])
    rng = np.random.default_rng(0)
    results, maps = [], []
    with VisualOdometry(seq.camera, cfg) as vo:
        for fr in frames:
            img = fr.image
            if 20 <= fr.index < 24:  # the camera is covered: noise
                img = rng.integers(0, 255, size=img.shape, dtype=np.uint8)
            results.append(vo.process(img, fr.timestamp, depth=fr.depth))
            maps += vo.take_published_maps()
    lost = [r.index for r in results if r.lost]
    assert set(lost) == {20, 21, 22, 23}
    assert all(r.T_world_cam is None for r in results if r.lost)
    after = [r for r in results if r.index >= 24]
    assert not any(r.lost for r in after)
    assert after[0].event == "recovered"
    # the recovered poses are still right
    gt = seq.groundtruth.poses
    T0 = np.linalg.inv(gt[0])
    err = np.linalg.norm((T0 @ gt[35])[:3, 3] - results[35].T_world_cam[:3, 3])
    assert err < 0.03
    # every published map reached the caller once, in order, at mapping resolution
    assert maps and maps[0].frame_index == 0 and maps[0].idepth.shape == (vo.map_intrinsics.height, vo.map_intrinsics.width)
    assert [m.frame_index for m in maps] == sorted({m.frame_index for m in maps})
    assert not any(m.frame_index in range(20, 24) for m in maps)     # lost frames are not mapped
    assert vo.take_published_maps() == []


@pytest.mark.parametrize("relocalise", [True, False])
def test_ten_black_frames_are_lost_and_tracking_recovers_in_the_same_map(synth_small, relocalise):
    seq, frames = _frames(synth_small, 40)
    cfg = lite_vo.load_profile("phone", ['system.init="depth"', f"tracking.relocalise={str(relocalise).lower()}"])
    results = []
    with VisualOdometry(seq.camera, cfg) as vo:
        for fr in frames:
            img = np.zeros_like(fr.image) if 20 <= fr.index < 30 else fr.image   # the lens is covered
            results.append(vo.process(img, fr.timestamp, depth=fr.depth))
    assert [r.index for r in results if r.lost] == list(range(20, 30))
    assert not any(r.event == "reinit" for r in results)
    assert results[30].event in ("recovered", "relocalised")
    gt = seq.groundtruth.poses
    T0 = np.linalg.inv(gt[0])
    for i in (30, 39):
        assert np.linalg.norm((T0 @ gt[i])[:3, 3] - results[i].T_world_cam[:3, 3]) < 0.03


def test_long_loss_reinitialises_the_map(synth_small):
    seq, frames = _frames(synth_small, 30)
    cfg = lite_vo.load_profile("phone", ['system.init="depth"', "system.max_lost_frames=3"])
    rng = np.random.default_rng(1)
    with VisualOdometry(seq.camera, cfg) as vo:
        events = []
        for fr in frames:
            img = fr.image if not 10 <= fr.index < 16 else rng.integers(0, 255, size=fr.image.shape, dtype=np.uint8)
            events.append(vo.process(img, fr.timestamp, depth=fr.depth).event)
    assert "reinit" in events
    assert vo.counts["reinit"] >= 1


def test_bad_input_is_a_clear_error(synth_small):
    seq, frames = _frames(synth_small, 3)
    cfg = lite_vo.load_profile("phone")
    vo = VisualOdometry(seq.camera, cfg)
    vo.process(frames[0].image, 1.0)
    with pytest.raises(InputError, match="timestamps must increase"):
        vo.process(frames[1].image, 1.0)
    with pytest.raises(InputError, match="320x240|size|calibration"):
        vo.process(np.zeros((100, 100), np.uint8), 2.0)
    with pytest.raises(InputError, match="not finite"):
        vo.process(frames[1].image, float("nan"))
    vo.close()
    given = VisualOdometry(seq.camera, cfg, pose_source="given")
    with pytest.raises(InputError, match="NaN"):
        given.process(frames[0].image, 1.0, T_world_cam=np.full((4, 4), np.nan))
    given.close()


def test_frames_tracked_against_a_replaced_map_are_not_mapped_into_the_new_one(synth_small):
    seq, frames = _frames(synth_small, 3)
    cfg = lite_vo.load_profile("phone", ['system.init="depth"'])
    with VisualOdometry(seq.camera, cfg) as vo:
        vo.process(frames[0].image, frames[0].timestamp, depth=frames[0].depth)
        stale = vo._preprocess(frames[1].image, frames[1].timestamp, None)
        stale.T_world_cam = np.eye(4)
        stale.mapper = object()  # the map it was tracked against has been replaced
        ref_before, mapped_before = vo._current_reference(), vo.counts["mapped"]
        vo._map_frame(stale)
        assert vo._current_reference() is ref_before and vo.counts["mapped"] == mapped_before
        stale.mapper = vo._mapper
        vo._map_frame(stale)
        assert vo._current_reference() is not ref_before and vo.counts["mapped"] == mapped_before + 1


def test_a_map_published_while_a_new_scale_is_installed_keeps_its_own_scale(synth_small):
    """Realtime mode: the mapping thread may publish a map of the old mapper after a re-initialisation or a
    start-up's two-view map took a new scale id but before the new mapper is installed. Its keyframe must keep
    the old scale (relocalisation only tries keyframes of the current scale: a random map's keyframe taken for
    one of the two-view map sent a realtime run into relocalising frame after frame)."""
    seq, frames = _frames(synth_small, 3)
    cfg = lite_vo.load_profile("phone", ['system.init="depth"'])
    with VisualOdometry(seq.camera, cfg) as vo:
        vo.process(frames[0].image, frames[0].timestamp, depth=frames[0].depth)
        old_scale = vo._scale_id
        assert {k.scale_id for k in vo.keyframes.snapshot()} == {old_scale}
        frame = vo._preprocess(frames[1].image, frames[1].timestamp, None)
        frame.T_world_cam = np.eye(4)
        frame.mapper = vo._mapper
        vo._scale_id += 1          # a new map is being made (its mapper not installed yet) ...
        vo._map_frame(frame)       # ... when the mapping thread publishes the old mapper's map
        assert vo.counts["mapped"] == 1
        assert {k.scale_id for k in vo.keyframes.snapshot()} == {old_scale}


def test_plain_intrinsics_of_undistorted_input_work_like_the_camera(synth_small):
    seq, frames = _frames(synth_small, 8)
    cfg = lite_vo.load_profile("phone", ['system.init="depth"'])
    poses = []
    for cam in (seq.camera, seq.camera.intrinsics):
        with VisualOdometry(cam, cfg) as vo:
            poses.append([vo.process(f.image, f.timestamp, depth=f.depth).T_world_cam for f in frames])
    assert vo.map_intrinsics.width == 320
    np.testing.assert_array_equal(np.asarray(poses[0]), np.asarray(poses[1]))


def test_depth_evaluation_runs_off_the_tracking_thread_and_keeps_its_rows(synth_small, monkeypatch):
    """The sampled depth evaluation runs on a worker thread: process() does not wait for it, the series
    waits for every pending row when read, in frame order, with the same values as computed inline."""
    import threading
    from lite_vo import system as S
    seq, frames = _frames(synth_small, 40)
    cfg = lite_vo.load_profile("phone", ['system.init="random"', "system.depth_eval_every=1"])

    def run(evaluate_depth):
        monkeypatch.setattr(S, "_evaluate_depth", evaluate_depth)
        vo = VisualOdometry(seq.camera, cfg)
        for fr in frames:
            vo.process(fr.image, fr.timestamp, depth=fr.depth)
        rows = [dict(r) for r in vo.depth_accuracy_series]
        vo.close()
        return rows

    real = S._evaluate_depth
    threads, gate = set(), threading.Event()

    def slow(*args):
        threads.add(threading.current_thread().name)
        gate.wait(5.0)                         # held until every frame was processed
        return real(*args)

    inline = run(real)
    vo_thread = threading.current_thread().name
    monkeypatch.setattr(S, "_evaluate_depth", slow)
    vo = VisualOdometry(seq.camera, cfg)
    for fr in frames:
        vo.process(fr.image, fr.timestamp, depth=fr.depth)
    assert len(vo._depth_jobs) > 1            # queued, not evaluated while tracking
    gate.set()
    rows = [dict(r) for r in vo.depth_accuracy_series]
    vo.close()
    assert threads and vo_thread not in threads
    assert len(rows) == len(inline) > 3
    assert [r["frame"] for r in rows] == sorted(r["frame"] for r in rows)
    for a, b in zip(rows, inline):
        assert a.keys() == b.keys() and all(a[k] == b[k] or (a[k] != a[k] and b[k] != b[k]) for k in a)
