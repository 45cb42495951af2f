"""The vignette estimated while the VO runs (``system.auto_vignette``, lite_vo.vignette.OnlineVignette)."""
from __future__ import annotations

import numpy as np
import pytest
from test_vignette import _vignetted_copy

import lite_vo
from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.keyframes import Keyframe, KeyframeStore
from lite_vo.mapping import MapFrame, Mapper, MappingConfig
from lite_vo.mapping.mapper import image_gradients


@pytest.fixture(scope="module")
def synth_90(tmp_path_factory):
    """90 frames (3 s) of the synthetic room, hand-held, 320x240, seed 0: the start-up takes the first
    second, the estimate needs a few maps after it."""
    from lite_vo.synth import generate_sequence
    out = tmp_path_factory.mktemp("synth90") / "room"
    generate_sequence(out, scene="room", trajectory="handheld", n_frames=90, seed=0, width=320, height=240)
    return out


def _run(seq, auto: bool):
    opened = lite_vo.open_sequence(seq)
    cfg = lite_vo.load_profile("phone", ['system.mode="sync"', f"system.auto_vignette={str(auto).lower()}"])
    vo = lite_vo.VisualOdometry(opened.camera, cfg)
    poses, vigs, events = [], [], {}
    try:
        for fr in opened:
            r = vo.process(fr.image, fr.timestamp)
            poses.append(None if r.T_world_cam is None else r.T_world_cam.copy())
            vigs.append(vo._vig_version)
            events.setdefault(r.event, r.index)
    finally:
        vo.close()
    return vo, poses, vigs, events


def test_a_vignetted_camera_is_corrected_during_the_run_and_a_clean_one_is_left_alone(synth_90, tmp_path):
    seq = tmp_path / "vig"
    _vignetted_copy(synth_90, seq)                   # 50 % at the corners
    vo, poses, vigs, events = _run(seq, True)
    est = vo.vignette_estimate
    assert est is not None and est.version >= 1         # adopted while the run went on ...
    first = vigs.index(1)
    assert first == events["bootstrap"]                 # ... from the start-up's two-view map on (its replayed maps)
    assert vo.vignette_summary()["from_frames"][0] == first
    assert all(v >= 1 for v in vigs[first:])
    assert abs(est.corner - 0.5) < 0.1                  # 1.0 without the estimate
    assert all(p is not None for p in poses[first:])    # the switch loses no frame
    # the centre stays as it was, the corners are brightened by the inverse
    assert est.vignette[120, 160] > 0.97 and est.vignette[0, 0] < 0.6
    # the clean room: the estimate finds no vignette worth correcting, and the run is the same as with it off
    vo_on, poses_on, vigs_on, _ = _run(synth_90, True)
    _, poses_off, _, _ = _run(synth_90, False)
    assert set(vigs_on) == {0}
    assert vo_on.vignette_estimate.done and "no vignetting" in vo_on.vignette_estimate.reason
    for a, b in zip(poses_on, poses_off):
        assert (a is None and b is None) or np.array_equal(a, b)
    # on by default
    assert lite_vo.load_profile("phone").system.auto_vignette is True


def test_in_realtime_mode_the_estimate_runs_off_the_tracking_thread(synth_90, tmp_path, monkeypatch):
    """A fit takes 10-120 ms: in realtime mode it runs in the estimator's own thread (the tracking thread
    would drop frames meanwhile), and its correction is still adopted and applied."""
    import threading

    import lite_vo.vignette_fit as VF
    seq = tmp_path / "vig"
    _vignetted_copy(synth_90, seq)
    threads = []
    offer = VF.OnlineVignette.offer_maps

    def recording(self, maps, version):
        threads.append(threading.current_thread().name)
        return offer(self, maps, version)

    monkeypatch.setattr(VF.OnlineVignette, "offer_maps", recording)
    opened = lite_vo.open_sequence(seq)
    cfg = lite_vo.load_profile("phone", ['system.mode="realtime"'])
    vo = lite_vo.VisualOdometry(opened.camera, cfg)
    posed = []
    try:
        for fr in opened:
            posed.append(vo.process(fr.image, fr.timestamp).T_world_cam is not None)
            # frames come as fast as they are processed here; a camera gives the estimator ~33 ms per frame:
            # let it finish what it was given before the next frame, so the test does not depend on timing
            vo._vig_worker.submit(lambda: None).result(timeout=60)
    finally:
        vo.close()
    assert threads and all(t.startswith("lite_vo-vignette") for t in threads)
    assert vo._vig_worker is None                       # shut down by close()
    summary = vo.vignette_summary()
    assert summary["corrections"] >= 1 and abs(summary["corner"] - 0.5) < 0.1
    assert all(posed[summary["from_frames"][0]:])


def test_the_mapper_re_expresses_its_images_in_a_new_correction():
    cam = PinholeIntrinsics(100.0, 100.0, 31.5, 23.5, 64, 48)
    m = Mapper(MappingConfig(), cam, seed=0)
    rng = np.random.default_rng(3)
    imgs = [rng.uniform(0, 200, (48, 64)).astype(np.float32) for _ in range(3)]
    m.initialize_random(MapFrame(0, 0.0, imgs[0], np.eye(4)))
    m.add_reference(MapFrame(1, 0.1, imgs[1], np.eye(4)))
    ratio = np.linspace(1.0, 2.0, 64, dtype=np.float32)[None, :].repeat(48, 0)
    before = {slot: m._buf_images[slot].copy() for _, slot in m._buffer}
    m.rescale_images(ratio, 1)
    assert m.image_version == 1
    for slot, img in before.items():
        np.testing.assert_allclose(m._buf_images[slot], img * ratio, rtol=1e-6)
    np.testing.assert_allclose(m._cur.image, imgs[0] * ratio, rtol=1e-6)
    gx, gy, mg = image_gradients(imgs[0] * ratio)
    np.testing.assert_allclose(m._cur.gx, gx, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(m._cur.maxgrad, mg, rtol=1e-5, atol=1e-4)
    with pytest.raises(InputError, match="ratio has shape"):
        m.rescale_images(np.ones((10, 10), np.float32), 2)


def test_the_keyframe_store_re_expresses_its_images():
    cam = PinholeIntrinsics(100.0, 100.0, 31.5, 23.5, 64, 48)
    store = KeyframeStore()
    img = np.full((48, 64), 100, np.uint8)
    idepth = np.full((48, 64), 0.5, np.float32)
    store.add(Keyframe.make(0, 0.0, np.eye(4), cam, img, idepth, idepth * 0.01))
    ratio = np.ones((48, 64), np.float32)
    ratio[:, :32] = 3.0
    store.rescale_images(ratio)
    kf = store.snapshot()[0]
    assert kf.image.dtype == np.uint8 and not kf.image.flags.writeable
    assert np.all(kf.image[:, :32] == 255) and np.all(kf.image[:, 32:] == 100)     # clipped at white
    np.testing.assert_allclose(np.nan_to_num(kf.idepth), idepth)


def test_run_reports_the_vignette_it_corrected_and_estimate_vignette_turns_it_off(synth_90, tmp_path, capsys):
    import json

    from lite_vo.cli.main import main
    seq = tmp_path / "vig"
    _vignetted_copy(synth_90, seq)
    out = tmp_path / "out"
    assert main(["run", str(seq), "--out", str(out), "--quiet", "--mode", "sync", "--set", "system.auto_vignette=true"]) == 0
    said = capsys.readouterr().out
    vr = json.loads((out / "run.json").read_text())["vignette_during_run"]
    assert vr["corrections"] >= 1 and abs(vr["corner"] - 0.5) < 0.1 and vr["from_frames"] == sorted(vr["from_frames"])
    assert f"vignette during the run: {100 * vr['corner']:.1f} % in the corners, corrected from frame {vr['from_frames'][0]} on" in said
    timing = json.loads((out / "timing.json").read_text())
    assert timing["stages"]["vignette"]["count"] >= 1
    # a calibration run fits the images as they come: the correction during the run is off for it
    cal = tmp_path / "cal"
    assert main(["run", str(seq), "--out", str(cal), "--quiet", "--mode", "sync", "--estimate-vignette",
                 "--set", "system.auto_vignette=true"]) == 0
    capsys.readouterr()
    assert "vignette_during_run" not in json.loads((cal / "run.json").read_text())
    assert abs(json.loads((cal / "vignette.json").read_text())["corner"] - 0.5) < 0.1
    # on by default; turned off: not in run.json
    off = tmp_path / "off"
    assert main(["run", str(seq), "--out", str(off), "--quiet", "--mode", "sync", "--max-frames", "10",
                 "--set", "system.auto_vignette=false"]) == 0
    assert "vignette_during_run" not in json.loads((off / "run.json").read_text())
    default = tmp_path / "default"
    assert main(["run", str(seq), "--out", str(default), "--quiet", "--mode", "sync"]) == 0
    capsys.readouterr()
    assert json.loads((default / "run.json").read_text())["vignette_during_run"] == vr


def _feed(est, monkeypatch, k_true, n_maps, version, seed):
    """Offer ``n_maps`` stand-in maps whose pairs show the vignette ``k_true`` (as test_vignette's fits see it)."""
    from test_vignette import _pairs
    import lite_vo.vignette_fit as VF
    pool = iter(_pairs(np.array(k_true), n_pairs=3 * n_maps, n=1500, seed=seed))
    monkeypatch.setattr(VF, "correspondences", lambda old, new, max_points: next(pool))
    return [est.offer(object(), version) for _ in range(n_maps)]


@pytest.mark.parametrize("second, rounds, ended", [
    ((-0.1, 0.0, 0.0), 2, "corrections applied"),           # what the first left: a refinement, applied
    ((-0.005, 0.0, 0.0), 1, "converged"),                   # nothing left worth a change
    ((-0.6, 0.0, 0.0), 1, "kept the estimate"),              # 40 % more fall-off: a disagreement, not applied
])
def test_the_online_estimate_refines_converges_or_keeps_its_first_correction(monkeypatch, second, rounds, ended):
    from test_vignette import MAP_CAM

    from lite_vo.vignette_fit import OnlineVignette
    est = OnlineVignette(MAP_CAM)
    out = _feed(est, monkeypatch, (-0.5, 0.0, 0.0), 4, 0, seed=1)     # 0 + 1 + 2 + 3 pairs: the fit at the fourth map
    assert out[:3] == [None, None, None] and out[3] is not None and est.version == 1
    assert abs(est.corner - 0.5) < 0.02
    np.testing.assert_allclose(out[3], 1.0 / est.vignette.astype(np.float32), rtol=1e-6)
    assert est.offer(object(), 0) is None and est._previous == []      # a map made before the switch: ignored
    first = est.corner
    out = _feed(est, monkeypatch, second, 4, 1, seed=2)
    assert est.done and ended in est.reason and est.version == rounds
    if rounds == 2:
        assert est.corner == pytest.approx(first * 0.9, abs=0.02)       # the product of both rounds
    else:
        assert est.corner == first and all(o is None for o in out)


def test_the_online_estimate_ends_without_a_change_on_a_lens_without_vignetting(monkeypatch):
    from test_vignette import MAP_CAM

    from lite_vo.vignette_fit import OnlineVignette
    est = OnlineVignette(MAP_CAM)
    out = _feed(est, monkeypatch, (0.0, 0.0, 0.0), 4, 0, seed=3)
    assert all(o is None for o in out) and est.done and est.version == 0
    assert "no vignetting to correct" in est.reason and est.corner == 1.0


@pytest.mark.parametrize("k1, corrected", [(-0.1, False), (-0.25, True)])
def test_the_online_estimate_leaves_a_mild_fall_off_alone(monkeypatch, k1, corrected):
    """Corners 90 % as bright as the centre (KITTI's camera: 92.5 % at first) are left as they are; 75 % are
    corrected (ONLINE_MIN_CORNER_DROP, 15 %)."""
    from test_vignette import MAP_CAM

    from lite_vo.vignette_fit import ONLINE_MIN_CORNER_DROP, OnlineVignette
    assert ONLINE_MIN_CORNER_DROP == pytest.approx(0.15)
    est = OnlineVignette(MAP_CAM)
    out = _feed(est, monkeypatch, (k1, 0.0, 0.0), 4, 0, seed=4)
    if corrected:
        assert out[3] is not None and est.version == 1 and est.corner == pytest.approx(1.0 + k1, abs=0.02)
    else:
        assert all(o is None for o in out) and est.done and est.version == 0
        assert "no vignetting to correct (corners 9" in est.reason and est.corner == 1.0


def test_with_given_poses_a_random_maps_first_maps_are_not_used(synth_90, tmp_path, capsys):
    """A random start without a two-view start-up (given poses): its first maps still hold the random
    depths; the estimate waits VIGNETTE_YOUNG_MAPS maps (with them it found 24.5 % on ICL's 50 %)."""
    import json

    from lite_vo.cli.main import main
    from lite_vo.system import VIGNETTE_YOUNG_MAPS
    seq = tmp_path / "vig"
    _vignetted_copy(synth_90, seq)
    out = tmp_path / "out"
    assert main(["run", str(seq), "--out", str(out), "--quiet", "--mode", "sync", "--poses", "gt", "--init", "random",
                 "--set", "system.auto_vignette=true"]) == 0
    capsys.readouterr()
    info = json.loads((out / "run.json").read_text())
    vr = info["vignette_during_run"]
    mapped = [e["frame"] for e in info["events"] if e["event"] == "init"]
    assert mapped == [0]
    # a map every 4th frame at the start: the init map and VIGNETTE_YOUNG_MAPS more are passed over, then four
    # maps give the fit its six pairs (without the wait: the first correction at frame 45 here)
    assert vr["corrections"] >= 1 and vr["from_frames"][0] >= 4 * (VIGNETTE_YOUNG_MAPS + 4)
    assert abs(vr["corner"] - 0.5) < 0.1
