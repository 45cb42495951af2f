"""AR pipeline end to end on a tiny synthetic sequence: video frame count and size, trajectory,
summary, the CLI commands and their lazy imports."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("moderngl", reason="the AR demo needs the [ar] extra (moderngl)")
pytest.importorskip("pybullet", reason="the AR demo needs the [ar] extra (pybullet)")

from ar_demo.config import ARConfig
from ar_demo.run import run_ar, write_summary
from ar_demo.world import semi_dense_from_depth
from ar_demo.render import RenderUnavailable, create_context
from ar_demo.video import VideoWriter, colorize_idepth, compose_panels, read_video_info
from lite_vo.cli.main import main
from lite_vo.errors import InputError

W, H, N = 160, 120, 12


@pytest.fixture(scope="module")
def egl():
    try:
        create_context().release()
    except RenderUnavailable as err:
        pytest.skip(f"EGL off-screen OpenGL is unavailable here ({err}); AR video tests skipped")


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    from lite_vo.synth import generate_sequence
    path = tmp_path_factory.mktemp("ar_seq") / "room"
    generate_sequence(path, scene="room", trajectory="handheld", n_frames=N, seed=1, width=W, height=H)
    return path


def _cfg(**kw):
    base = dict(start_after_s=0.0, world_update_every=2)
    base.update(kw)
    return ARConfig(**base)


def test_video_writer_roundtrip(tmp_path):
    path = tmp_path / "v.mp4"
    with VideoWriter(path, 10.0, (64, 48)) as w:
        for k in range(7):
            w.write(np.full((48, 64, 3), 20 * k, np.uint8))
    assert read_video_info(path) == (7, 64, 48)
    with pytest.raises(InputError):
        VideoWriter(tmp_path / "v.avi", 10.0, (64, 48))


def test_colorize_and_panels():
    d = np.full((12, 16), np.nan)
    d[3, 4], d[5, 6] = 0.2, 1.0
    img = colorize_idepth(d)
    assert img.shape == (12, 16, 3) and img[0, 0].sum() == 0          # black where empty
    assert img[5, 6, 0] > img[5, 6, 2] and img[3, 4, 2] > img[3, 4, 0]  # near red, far blue
    out = compose_panels(np.zeros((48, 64, 3), np.uint8), img, None)
    assert out.shape == (48, 96, 3)


def test_semi_dense_from_depth_keeps_gradient_pixels():
    img = np.zeros((20, 20), np.float32)
    img[:, 10:] = 100.0
    depth = np.full((20, 20), 2.0, np.float32)
    depth[0, 0] = 0.0
    idepth, var = semi_dense_from_depth(img, depth, 5.0, 1e-4)
    ok = np.isfinite(idepth)
    assert ok[:, 9:11].all() and ok.sum() == 40
    np.testing.assert_allclose(idepth[ok], 0.5)
    np.testing.assert_allclose(var[ok], 1e-4 * 0.25)


@pytest.mark.parametrize("panels", [False, True])
def test_run_ar_gt_video_frames_and_size(egl, sequence, tmp_path, panels):
    out = tmp_path / "ar.mp4"
    summary = run_ar(sequence, out, poses="gt", max_frames=10, cfg=_cfg(panels=panels, async_world=not panels),
                     trajectory_out=tmp_path / "traj.txt", mesh_out=tmp_path / "mesh.obj")
    n, w, h = read_video_info(out)
    assert n == 10 and summary["frames_written"] == 10
    assert (w, h) == ((W + W // 2, H) if panels else (W, H))
    rows = [r for r in (tmp_path / "traj.txt").read_text().splitlines() if not r.startswith("#")]
    assert len(rows) == 10 and len(rows[0].split()) == 8
    assert summary["ground_plane"]["source"].startswith("imu")
    n_up = np.array(summary["ground_plane"]["normal_world"])
    assert np.degrees(np.arccos(n_up @ [0, 0, 1])) < 3.0               # synth world: z up
    if panels:   # synchronous world (deterministic): a rebuild every world_update_every frames
        assert summary["world_models_built"] >= 2 and summary["world_updates"] >= 2
    else:        # asynchronous: how many builds finish within 10 frames depends on the machine's load
        assert summary["world_models_built"] >= 1 and summary["world_updates"] >= 1
    assert (tmp_path / "mesh.obj").stat().st_size > 0
    write_summary(summary, tmp_path)
    assert json.loads((tmp_path / "summary.json").read_text())["frames_written"] == 10
    assert "render" in (tmp_path / "summary.txt").read_text()


def test_run_ar_with_the_visual_odometry(egl, sequence, tmp_path):
    out = tmp_path / "est.mp4"
    summary = run_ar(sequence, out, poses="estimate", max_frames=8, cfg=_cfg(),
                     overrides=["resolution.map_width=160"])
    assert read_video_info(out)[:1] == (8,)
    assert summary["poses"] == "estimate" and summary["frames_in"] == 8


def test_cli_ar_and_refuses_overwrite(egl, sequence, tmp_path, capsys):
    out = tmp_path / "cli.mp4"
    args = ["ar", str(sequence), "--out", str(out), "--poses", "gt", "--max-frames", "4", "--quiet",
            "--ar-set", "start_after_s=0", "--set", "resolution.map_width=160"]
    assert main(args) == 0
    assert read_video_info(out)[0] == 4
    assert main(args) == 1                                             # exists, no --force
    assert "exists" in capsys.readouterr().err
    assert main(args + ["--force"]) == 0
    assert main(["ar", str(sequence), "--out", str(tmp_path / "x.avi")]) == 1
    assert main(["ar", str(sequence), "--out", str(tmp_path / "y.mp4"), "--ar-set", "bogus=1"]) == 1


def test_cli_demo_refuses_non_empty_folder(tmp_path, capsys):
    (tmp_path / "keep.txt").write_text("x")
    assert main(["demo", "--out", str(tmp_path)]) == 1
    assert "not empty" in capsys.readouterr().err


def test_cli_modules_import_no_ar_packages():
    code = ("import sys, ar_demo.cli.ar, ar_demo.cli.demo, lite_vo.cli.main as m; m.build_parser(); "
            "bad = [k for k in ('pybullet', 'moderngl', 'trimesh') if k in sys.modules]; "
            "print(','.join(bad)); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, f"imported at module level: {r.stdout} {r.stderr}"


def test_cli_ar_without_the_extra_says_how_to_install(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "pybullet", None)        # import pybullet -> ImportError
    assert main(["ar", str(tmp_path), "--out", str(tmp_path / "v.mp4")]) == 1
    assert "pip install 'lite-vo[ar]'" in capsys.readouterr().err


def _box_scene():
    """A 160x120 camera 1 m above the floor looking at a box: (intrinsics, T_world_cam, inverse depth)."""
    from lite_vo.camera import PinholeIntrinsics
    from naive_ar import idepth_from_depth, look_at, raycast_depth
    intr = PinholeIntrinsics(120.0, 120.0, 79.5, 59.5, 160, 120)
    T = look_at([0.0, 0.0, 1.0], [2.0, 0.0, 0.0])
    depth, _ = raycast_depth(T, intr.K, 160, 120, boxes=[(1.5, -0.3, 0, 1.9, 0.3, 0.3)])
    return intr, T, idepth_from_depth(depth)


def test_sink_resets_world_on_monocular_reinit(egl, tmp_path):
    """ARSink fed by hand (as the session would): starts the world, and a monocular re-initialisation
    (new scale) restarts it; a lost frame writes the camera image only."""
    import lite_vo
    from ar_demo.sink import ARSink
    from lite_vo.session import FrameEvent, PublishedMap, RunEnd, SessionInfo
    from lite_vo.system import FrameResult

    intr, T, idepth = _box_scene()
    valid = np.isfinite(idepth)
    var = np.full(idepth.shape, 1e-4)
    sink = ARSink(_cfg(start_after_monocular_s=0.0, ground_min_support=50), tmp_path / "s.mp4", fps=10)
    sink.on_start(SessionInfo("hand", "hand", 7, lite_vo.load_profile("phone"), "phone", intr, intr))
    image = np.full((120, 160), 100.0, np.float32)
    for i in range(6):
        event = "init" if i == 0 else "reinit" if i == 4 else ""
        quality = {"init": "random"} if event else {}
        sink.on_map(PublishedMap(i, i * 0.1, T, intr, image, np.nan_to_num(idepth), var, valid))
        sink.on_frame(FrameEvent(FrameResult(i, i * 0.1, T, False, quality, event=event), image))
        if i == 2:
            sink.flush()                                              # the world thread caught up
            assert sink.world.started and sink.metric is False
            assert sink.world.ground.source == "ransac"               # no accelerometer given
    sink.on_frame(FrameEvent(FrameResult(6, 0.6, None, True, {}, event="lost"), image))
    sink.on_finish(RunEnd("ok", {}, {}, [], False))
    assert any("reset" in e for e in sink.summary["events"])
    assert sum(e.startswith("start") for e in sink.summary["events"]) == 2
    assert read_video_info(tmp_path / "s.mp4") == (7, 160, 120)


def test_car_txt_agrees_with_the_rendered_car(egl, sequence, tmp_path):
    """car.txt (T_world_car, footprint centre) projected with trajectory.txt lands on the car drawn
    in the video: the car pixels are where the frame differs from the camera image."""
    import cv2

    from ar_demo.evaluate import read_tum
    from lite_vo.geometry import inverse_se3, transform_points
    from lite_vo.io import open_sequence
    out = tmp_path / "ar.mp4"
    run_ar(sequence, out, poses="gt", cfg=_cfg(async_world=False, render_thread=False))
    t_car, T_car = read_tum(tmp_path / "car.txt")
    t_cam, T_cam = read_tum(tmp_path / "trajectory.txt")
    cam_at = {round(float(t), 6): T for t, T in zip(t_cam, T_cam)}
    seq = open_sequence(sequence)
    index = {round(float(t), 6): i for i, t in enumerate(seq.timestamps)}
    intr = seq.camera.intrinsics
    cap = cv2.VideoCapture(str(out))
    video = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        video.append(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY).astype(np.int16))
    checked = 0
    for t, Tc in zip(t_car, T_car):
        i = index[round(float(t), 6)]
        p = transform_points(inverse_se3(cam_at[round(float(t), 6)]), Tc[:3, 3][None])[0]
        u, v = intr.fx * p[0] / p[2] + intr.cx, intr.fy * p[1] / p[2] + intr.cy
        if not (p[2] > 0 and 5 <= u < W - 5 and 5 <= v < H - 5):
            continue
        fr = seq.frame(i)
        cam = fr.image if fr.color is None else cv2.cvtColor(fr.color, cv2.COLOR_BGR2GRAY)
        car = np.abs(video[i] - cam.astype(np.int16)) > 40
        car = cv2.morphologyEx(car.astype(np.uint8), cv2.MORPH_OPEN, np.ones((2, 2), np.uint8)).astype(bool)
        vs, us = np.nonzero(car)
        assert len(us) >= 20, f"frame {i}: no car drawn where car.txt says it is ({u:.1f}, {v:.1f})"
        assert us.min() - 2 <= u <= us.max() + 2 and vs.min() - 2 <= v <= vs.max() + 2, \
            f"frame {i}: footprint centre ({u:.1f}, {v:.1f}) outside the drawn car {us.min()}..{us.max()} x {vs.min()}..{vs.max()}"
        # the footprint centre is the middle of the car: near the centre of its drawn pixels
        size = max(us.max() - us.min(), vs.max() - vs.min())
        assert np.hypot(u - us.mean(), v - vs.mean()) < 0.35 * size, f"frame {i}: off the car's middle"
        checked += 1
    seq.close()
    assert checked >= N // 2, f"only {checked} frames with the car in view"


def _hand_fed_sink(tmp_path, **cfg):
    """An ARSink with a started world fed by hand (a box on a floor seen from 1 m)."""
    import lite_vo
    from ar_demo.sink import ARSink
    from lite_vo.session import FrameEvent, PublishedMap, SessionInfo
    from lite_vo.system import FrameResult

    intr, T, idepth = _box_scene()
    sink = ARSink(_cfg(start_after_monocular_s=0.0, ground_min_support=50, **cfg), tmp_path / "s.mp4", fps=10,
                  metric=True)
    sink.on_start(SessionInfo("hand", "hand", 5, lite_vo.load_profile("phone"), "phone", intr, intr))
    image = np.full((120, 160), 100.0, np.float32)

    def feed(i):
        sink.on_map(PublishedMap(i, i * 0.1, T, intr, image, np.nan_to_num(idepth), np.full(idepth.shape, 1e-4),
                                 np.isfinite(idepth)))
        sink.on_frame(FrameEvent(FrameResult(i, i * 0.1, T, False, {}, event="init" if i == 0 else ""), image))
    return sink, feed


def _world_step_threads(monkeypatch) -> set:
    """The names of the threads that call ``ARWorld.step`` from now on (filled as they do)."""
    import threading

    from ar_demo.world import ARWorld
    threads = set()
    step = ARWorld.step

    def spy(self, dt, T):
        threads.add(threading.current_thread().name)
        return step(self, dt, T)
    monkeypatch.setattr(ARWorld, "step", spy)
    return threads


def test_world_runs_in_its_own_thread_and_its_errors_reach_the_caller(egl, tmp_path, monkeypatch):
    """The AR world (pybullet hand-over, simulation) runs in the "ar-world" thread, not the caller's;
    an error there is raised on the caller's thread (at on_finish, naming the world thread) and the
    video is still closed."""
    from ar_demo.world import ARWorld
    from lite_vo.session import RunEnd
    threads = _world_step_threads(monkeypatch)
    sink, feed = _hand_fed_sink(tmp_path)
    for i in range(4):
        feed(i)
    sink.flush()
    assert sink.world.started and threads == {"ar-world"}
    assert len(sink.times["frame"]) == 4 and len(sink.times["world_frame"]) == 4

    def boom(self, dt, T):
        raise ValueError("simulated failure")
    monkeypatch.setattr(ARWorld, "step", boom)
    feed(4)
    with pytest.raises(RuntimeError, match="AR world thread: simulated failure"):
        sink.on_finish(RunEnd("ok", {}, {}, [], False))
    assert read_video_info(tmp_path / "s.mp4")[0] == 4          # the frames before the error were written


def test_world_thread_off_runs_on_the_callers_thread(egl, tmp_path, monkeypatch):
    import threading

    from lite_vo.session import RunEnd
    threads = _world_step_threads(monkeypatch)
    sink, feed = _hand_fed_sink(tmp_path, world_thread=False)
    for i in range(3):
        feed(i)
    assert sink.world.started and threads == {threading.current_thread().name}
    sink.on_finish(RunEnd("ok", {}, {}, [], False))
    assert read_video_info(tmp_path / "s.mp4")[0] == 3
