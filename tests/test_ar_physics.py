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
        # drive straight at the box centre, full throttle, no autopilot
        start = np.array([box_front - 0.9, centre[1]])
        w.spawn_car(start, 0.0)
        xs, ys = [], []
        for _ in range(150):                              # 5 s
            w.drive(cfg.drive_speed, 0.0)
            w.step(1 / 30, autopilot=False)
            p = w.car_state().T_phys_base[:3, 3]
            xs.append(p[0])
            ys.append(p[1])
        front_of_car = np.array(xs) + 0.85 * w.car_length   # base origin is at the rear axle
        assert max(xs) > start[0] + 0.3, "the car did not drive"
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
    cfg = ARConfig()
    rng = np.random.default_rng(2)
    T = look_at([0.0, 0.1, 1.0], [2.2, 0.0, 0.0])
    depth, _ = raycast_depth(T, INTR.K, 320, 240, boxes=[BOX])
    idepth = idepth_from_depth(depth, rng, 0.9)
    var = np.full(idepth.shape, 1e-4)
    ground = GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0)
    b = AsyncWorldModelBuilder(cfg, ground)
    try:
        b.submit(idepth, var, INTR, T, frame_id=3)
        b.wait_idle(10)
        m = b.poll()
        assert m is not None and m.frame_id == 3 and b.poll() is None
        ref = build_world_model(idepth, var, INTR, T, ground, cfg)
        np.testing.assert_allclose(m.mesh.vertices_world, ref.mesh.vertices_world)
    finally:
        b.close()
