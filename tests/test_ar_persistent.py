"""The persistent AR world: fusion over keyframes, walls block the car, in-view spawn, ICL check."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import shared_sequence

pytest.importorskip("pybullet")

from ar_demo.config import ARConfig  # noqa: E402
from ar_demo.ground import GroundPlane  # noqa: E402
from ar_demo.heightfield import FLOOR, OBSTACLE, UNKNOWN, FieldSpec, WorldFusion, fuse_points  # noqa: E402
from ar_demo.physics import PhysicsFrame, PhysicsWorld, racecar_length  # noqa: E402
from ar_demo.video import look_at  # noqa: E402
from lite_vo.camera import PinholeIntrinsics  # noqa: E402
from lite_vo.keyframes import Keyframe  # noqa: E402

CAM = PinholeIntrinsics(160.0, 160.0, 159.5, 119.5, 320, 240)
GROUND = GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0, "given")


def _floor_keyframe(i, target):
    T = look_at([0.0, 0.0, 1.5], target, [0, 0, 1])
    d = GROUND.idepth_grid(T, CAM).astype(np.float32)
    d[d <= 0] = np.nan
    d[::2] = np.nan                                       # semi-dense
    return Keyframe.make(i, i / 30, T, CAM, np.full((240, 320), 100, np.uint8), d,
                         np.where(np.isfinite(d), 1e-6, np.nan))


def _fusion(cfg):
    L = racecar_length()
    frame = PhysicsFrame(np.eye(3), np.zeros(3), L / 0.3)           # a 0.3 m car
    spec = FieldSpec(cfg.field_cells, cfg.field_cell * L, cfg.wall_height * L, -cfg.floor_band * L)
    return WorldFusion(cfg, GROUND, frame, spec, L), frame


def _started_world(cfg):
    """An ARWorld started on one floor keyframe looking along +x from 1.5 m, up = +z: (world, keyframe)."""
    from types import SimpleNamespace

    from ar_demo.world import ARWorld
    w = ARWorld(cfg, CAM, metric=True)
    kf = _floor_keyframe(0, [2.0, 0.0, 0.0])
    published = SimpleNamespace(frame_index=0, timestamp=0.0, idepth=kf.idepth, idepth_var=kf.idepth_var,
                                camera=kf.camera, T_world_cam=kf.T_world_cam)
    w.gravity.update(np.array([[0.0, 0.0, 9.81]]), np.eye(3), np.array([0.0]))   # up = +z
    assert w.start(published, [kf])
    return w, kf


def test_fusion_keeps_a_surface_seen_once_after_the_camera_turns_away():
    cfg = ARConfig()
    fusion, frame = _fusion(cfg)
    a = _floor_keyframe(0, [2.0, 0.0, 0.0])               # looks at the floor in +x
    b = _floor_keyframe(1, [-2.0, 0.0, 0.0])              # then turns round to -x
    only_a = fusion.fuse([a])
    both = fusion.fuse([a, b])
    seen_a = frame.to_phys(np.array([[2.0, 0.0, 0.0]]))[0, :2]
    seen_b = frame.to_phys(np.array([[-2.0, 0.0, 0.0]]))[0, :2]
    assert only_a.at(seen_a)[0] == FLOOR and only_a.at(seen_b)[0] == UNKNOWN
    assert both.at(seen_a)[0] == FLOOR and both.at(seen_b)[0] == FLOOR
    assert np.all(both.state[only_a.state == FLOOR] == FLOOR)
    assert only_a.at(frame.to_phys(np.array([[0.0, 3.0, 0.0]]))[0, :2])[0] == UNKNOWN   # never seen: not floor


def test_wall_blocks_the_car_and_the_world_body_is_updated_in_place():
    pb = pytest.importorskip("pybullet")
    cfg = ARConfig()
    L = racecar_length()
    spec = FieldSpec(60, cfg.field_cell * L, cfg.wall_height * L, -cfg.floor_band * L)
    X, Y = spec.centres()
    pts = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    wall_x = 2.0 * L
    wall = np.stack([np.full(40, wall_x), np.linspace(-3 * L, 3 * L, 40), np.full(40, 0.6 * L)], 1)
    field = fuse_points(np.concatenate([np.repeat(pts, 3, 0), np.repeat(wall, 10, 0)]), spec, cfg, L)
    assert field.at(np.array([[wall_x, 0.0]]))[0] == OBSTACLE
    ph = PhysicsWorld(cfg, PhysicsFrame(np.eye(3), np.zeros(3), 1.0))
    try:
        for _ in range(5):
            ph.set_height_field(field.heights(), spec.cell)
        bodies = pb.getNumBodies(physicsClientId=ph.client)
        ph.spawn_car([0.0, 0.0], 0.0)                     # heading +x, at the wall
        xs = []
        for _ in range(150):
            ph.step(1 / 30, target_xy=np.array([5.0 * L, 0.0]))
            xs.append(ph.car_state().T_phys_base[0, 3] + ph.footprint_offset()[0])
        assert pb.getNumBodies(physicsClientId=ph.client) == bodies + 1     # the field body + the car
        assert ph.field_updates == 5
        assert max(xs) < wall_x                           # never through the wall
        assert max(xs) > 0.5 * L                          # it did drive towards it
    finally:
        ph.close()


def test_car_spawns_on_seen_floor_in_view():
    w, kf = _started_world(ARConfig(async_world=False))
    try:
        assert w.has_car
        T = kf.T_world_cam
        p = w.car_position_world()
        assert w.in_view(T, p, margin=0.05)
        assert abs(p[2]) < 0.05                           # on the floor
        assert w.field.at(w.physics.frame.to_phys(p[None])[:, :2])[0] == FLOOR
        assert abs(w.car_length_world - 0.3) < 1e-9
        tilt = math.degrees(math.acos(np.clip(w.car_pose_world()[2, 2], -1, 1)))
        assert tilt < 10
    finally:
        w.close()


def test_icl_car_lives_in_the_room(tmp_path):
    """The issue-15 check on ICL living room 211 (all 211 frames, VO poses, world built synchronously:
    deterministic; the default-interval run of ``python tools/bench_ar_world.py`` -> benchmarks/ar_world.md).

    Issue-15 targets: footprint centre in view >= 70 % of the frames from spawn, on a real surface
    >= 90 % where in view, hidden <= 5 %, tilt <= 20 deg in >= 90 %. The car's path is chaotic (small
    changes of the VO or of the world updates send it elsewhere), so the benchmark judges the targets on
    the median over five world rebuild intervals (K = 3..7), and this single run (K = 5) keeps a margin
    below the targets for the in-view share and the upright share: over K = 3..7 the runs range 64-76 %
    in view and 79-100 % upright (54-86 % and 89-100 % on earlier VO draws; a car that tipped over lies on
    its side for half a second before it respawns). The VO's last bits differ with the host CPU (OpenCV
    picks its SIMD paths at run time), and so does the car's path: with the same code, K = 5 was on a
    surface in 100 % of its in-view frames on one host of this kind and in 89.2 % on another (2026-11-27;
    that host's median over K = 3..7: 94.8 %), so the single run keeps a margin there too; hidden is held
    to the target (0 % on both hosts)."""
    seq = shared_sequence("icl_livingroom_211")
    from ar_demo.evaluate import evaluate_ar_run
    from ar_demo.render import create_context
    try:
        create_context().release()
    except Exception as err:                              # noqa: BLE001
        pytest.skip(f"no off-screen OpenGL: {err}")
    from ar_demo.run import run_ar
    run_ar(seq, tmp_path / "ar.mp4", cfg=ARConfig(async_world=False))
    r = evaluate_ar_run(seq, tmp_path)
    assert r["frames_from_spawn"] >= 190                  # spawned within the first 21 frames
    assert r["in_view"] >= 0.60
    assert r["on_surface_in_view"] >= 0.85                # target 90 % on the median over K (see above)
    assert r["hidden_in_view"] <= 0.05
    assert r["upright_20deg"] >= 0.85


@pytest.mark.parametrize("stuck_s", [1.0, 0.0])
def test_a_car_that_cannot_move_respawns_as_stuck(stuck_s):
    """With the motors off (drive_speed 0) the car makes no progress: after respawn_stuck_s it
    respawns on seen floor in view (reason "stuck"); with respawn_stuck_s = 0 it never does."""
    w, kf = _started_world(ARConfig(async_world=False, drive_speed=0.0, respawn_stuck_s=stuck_s))
    try:
        spawns = w.spawns
        for _ in range(27):                                # 0.9 s: not stuck long enough yet
            w.step(1 / 30, kf.T_world_cam)
        assert w.spawns == spawns
        for _ in range(33):                                # 2 s in all
            w.step(1 / 30, kf.T_world_cam)
        assert w.in_view(kf.T_world_cam, w.car_position_world())
        if stuck_s > 0:
            assert w.respawn_reasons.get("stuck", 0) >= 1 and w.spawns > spawns
        else:
            assert "stuck" not in w.respawn_reasons and w.spawns == spawns
    finally:
        w.close()


@pytest.mark.parametrize("floor_in_view", [True, False])
def test_a_tipped_car_respawns_or_is_righted_where_it_lies(floor_in_view):
    """A car lying on its roof for respawn_tilt_s respawns on seen floor in view; when the view has no
    floor to offer (camera looking up), it is put back on its wheels where it lies."""
    w, kf = _started_world(ARConfig(async_world=False, drive_speed=0.0, respawn_stuck_s=0.0,
                                    respawn_out_of_view_s=0.0, respawn_hidden_s=0.0))
    T_view = kf.T_world_cam if floor_in_view else look_at([0.0, 0.0, 1.5], [2.0, 0.0, 6.0], [0, 0, 1])
    try:
        for _ in range(15):                                # settle on the floor
            w.step(1 / 30, kf.T_world_cam)
        ph = w.physics
        pb = ph._pb
        pos, _ = pb.getBasePositionAndOrientation(ph.car, physicsClientId=ph.client)
        pb.resetBasePositionAndOrientation(ph.car, [pos[0], pos[1], pos[2] + 0.4 * ph.car_length],
                                           pb.getQuaternionFromEuler([math.pi, 0, 0]), physicsClientId=ph.client)
        xy_before = ph.car_centre_xy()
        spawns = w.spawns

        def tilt():
            return math.degrees(math.acos(np.clip(ph.car_state().T_phys_base[2, 2], -1, 1)))

        for _ in range(10):                                # 1/3 s on its roof: not yet
            w.step(1 / 30, T_view)
        assert tilt() > 60 and w.spawns == spawns
        for _ in range(30):
            w.step(1 / 30, T_view)
        assert w.spawns == spawns + 1 and tilt() < 20
        if floor_in_view:
            assert w.respawn_reasons.get("tipped over") == 1
            assert w.in_view(T_view, w.car_position_world())
        else:
            assert w.respawn_reasons.get("tipped over, righted in place") == 1
            assert np.hypot(*(ph.car_centre_xy() - xy_before)) < 0.5 * ph.car_length
    finally:
        w.close()
