"""AR physics: the racecar on a flat mesh, and driven at a box of a reconstructed synthetic scene."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet", reason="the AR demo needs the [ar] extra (pybullet)")

from ar_demo.config import ARConfig
from ar_demo.ground import GroundPlane
from ar_demo.mesh import grid_faces
from ar_demo.physics import PhysicsFrame, PhysicsWorld
from ar_demo.world_model import AsyncWorldModelBuilder, build_world_model
from lite_vo.camera import PinholeIntrinsics
from naive_ar import idepth_from_depth, look_at, raycast_depth

INTR = PinholeIntrinsics(260.0, 260.0, 159.5, 119.5, 320, 240)
BOX = (1.9, -0.45, 0.0, 2.5, 0.35, 0.4)


def _flat_world(cfg, scale=1.0):
    frame = PhysicsFrame(np.eye(3), np.zeros(3), scale)
    w = PhysicsWorld(cfg, frame)
    n = 11
    y, x = np.mgrid[0:n, 0:n]
    verts = np.stack([x.ravel() * 0.4 - 2, y.ravel() * 0.4 - 2, np.zeros(n * n)], 1) / scale
    w.set_world_mesh(verts, grid_faces(n, n))
    return w


def test_own_client_not_default():
    import pybullet as pb
    w = _flat_world(ARConfig())
    try:
        assert w.client >= 0
        assert pb.getNumBodies(physicsClientId=w.client) == 1
    finally:
        w.close()


@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_car_rests_on_flat_mesh(scale):
    w = _flat_world(ARConfig(), scale)
    try:
        w.spawn_car([0.2, -0.1], 0.3)
        zs, xy = [], []
        for _ in range(90):                               # 3 s, motors off
            w.step(1 / 30, autopilot=False)
            st = w.car_state()
            zs.append(st.T_phys_base[2, 3])
            xy.append(st.T_phys_base[:2, 3])
        zs = np.array(zs[30:])                            # after landing
        assert np.all(zs > -0.01), "car sinks into the mesh"
        assert np.all(zs < 0.03), "car flies off"
        assert np.ptp(np.array(xy[30:]), axis=0).max() < 0.02
        assert w.car_state().T_phys_base[2, 2] > 0.999    # upright
    finally:
        w.close()


def _box_physics(cfg, rng):
    """PhysicsWorld on the world model of a semi-dense view of the box; also the box front x and
    the box centre (physics units)."""
    T = look_at([0.0, 0.1, 1.0], [2.2, 0.0, 0.0])
    depth, label = raycast_depth(T, INTR.K, 320, 240, boxes=[BOX])
    idepth = idepth_from_depth(depth, rng, 0.9)
    var = 1e-4 * np.nan_to_num(idepth) ** 2 + 1e-8
    ground = GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0)
    model = build_world_model(idepth, var, INTR, T, ground, cfg)
    frame = PhysicsFrame.from_ground(ground.normal_world, ground.height, T, 1.0)
    w = PhysicsWorld(cfg, frame)
    try:
        w.set_world_mesh(model.mesh.vertices_world, model.mesh.faces)
    except BaseException:
        w.close()
        raise
    box_front = frame.to_phys(np.array([[BOX[0], 0.0, 0.0]]))[0, 0]
    centre = frame.to_phys(np.array([[(BOX[0] + BOX[3]) / 2, (BOX[1] + BOX[4]) / 2, 0.0]]))[0]
    return w, box_front, centre


def test_car_driven_at_box_stops_or_deflects():
    cfg = ARConfig()
    w, box_front, centre = _box_physics(cfg, np.random.default_rng(0))
    try:
        # drive straight at the box centre, full throttle, no autopilot; the rear axle (base origin)
        # starts 0.9 in front of the box (spawn_car places the footprint centre, ahead of the base)
        w.spawn_car([0.0, 0.0], 0.0)
        start = np.array([box_front - 0.9 + w.footprint_offset()[0], centre[1]])
        w.spawn_car(start, 0.0)
        xs, ys = [], []
        for _ in range(150):                              # 5 s
            w.drive(cfg.drive_speed, 0.0)
            w.step(1 / 30, autopilot=False)
            p = w.car_state().T_phys_base[:3, 3]
            xs.append(p[0])
            ys.append(p[1])
        front_of_car = np.array(xs) + 0.85 * w.car_length   # base origin is at the rear axle
        assert max(xs) > xs[0] + 0.3, "the car did not drive"
        passed = front_of_car.max() > box_front + 0.1 and abs(ys[-1] - centre[1]) < 0.3
        assert not passed, f"the car drove through the box (front reached {front_of_car.max():.2f}, box at {box_front:.2f})"
        assert w.collisions >= 1                          # a side contact with the world mesh was seen
    finally:
        w.close()


def test_autopilot_reverses_when_blocked():
    cfg = ARConfig()
    w, box_front, centre = _box_physics(cfg, np.random.default_rng(1))
    try:
        w.spawn_car([box_front - 0.6, centre[1]], 0.0)
        target = centre[:2]                                # keeps steering into the box
        for _ in range(180):
            w.step(1 / 30, target_xy=target)
        assert w.autopilot.reversals >= 1
    finally:
        w.close()


def test_world_swap_keeps_car_state():
    cfg = ARConfig()
    w = _flat_world(cfg)
    try:
        w.spawn_car([0.0, 0.0], 0.0)
        for _ in range(30):
            w.step(1 / 30, autopilot=False)
        before = w.car_state().T_phys_base.copy()
        n = 11
        y, x = np.mgrid[0:n, 0:n]
        verts = np.stack([x.ravel() * 0.4 - 2, y.ravel() * 0.4 - 2, np.full(n * n, 0.001)], 1)
        w.set_world_mesh(verts, grid_faces(n, n))
        import pybullet as pb
        assert pb.getNumBodies(physicsClientId=w.client) == 2      # new world + car, old one removed
        for _ in range(15):
            w.step(1 / 30, autopilot=False)
        after = w.car_state().T_phys_base
        assert np.abs(after[:3, 3] - before[:3, 3]).max() < 0.01
        assert w.collisions == 0                          # resting on flat ground is no collision
    finally:
        w.close()


def test_async_builder_matches_sync():
    """The worker thread builds the same world (occlusion mesh and fused height field) as the
    synchronous build from the same map and keyframes."""
    from types import SimpleNamespace

    from ar_demo.heightfield import FieldSpec, WorldFusion
    from ar_demo.physics import racecar_length
    from ar_demo.world_model import build_world
    from lite_vo.keyframes import Keyframe

    cfg = ARConfig()
    rng = np.random.default_rng(2)
    ground = GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0)
    kfs = []
    for i, eye in enumerate(([0.0, 0.1, 1.0], [0.2, -0.3, 1.1])):
        T = look_at(eye, [2.2, 0.0, 0.0])
        depth, _ = raycast_depth(T, INTR.K, 320, 240, boxes=[BOX])
        idepth = idepth_from_depth(depth, rng, 0.9).astype(np.float32)
        var = np.where(np.isfinite(idepth), 1e-4, np.nan).astype(np.float32)
        kfs.append(Keyframe.make(i, i / 30, T, INTR, np.zeros((240, 320), np.uint8), idepth, var))
    published = SimpleNamespace(frame_index=3, timestamp=0.1, idepth=kfs[-1].idepth, idepth_var=kfs[-1].idepth_var,
                                camera=INTR, T_world_cam=kfs[-1].T_world_cam)
    L = racecar_length()
    frame = PhysicsFrame(np.eye(3), np.zeros(3), L / 0.3)

    def fusion():
        spec = FieldSpec(cfg.field_cells, cfg.field_cell * L, cfg.wall_height * L, -cfg.floor_band * L)
        return WorldFusion(cfg, ground, frame, spec, L)

    b = AsyncWorldModelBuilder(cfg, ground, fusion())
    try:
        b.submit(published, kfs)
        b.wait_idle(30)
        m = b.poll()
        assert m is not None and m.frame_id == 3 and b.poll() is None
        ref = build_world(published, kfs, ground, cfg, fusion())
        np.testing.assert_allclose(m.mesh.vertices_world, ref.mesh.vertices_world)
        np.testing.assert_array_equal(m.field.state, ref.field.state)
        assert (m.field.state != 0).sum() > 50            # the fused field is not empty
    finally:
        b.close()
