"""AR rendering: OpenCV -> GL projection, car pixels where the projection says, depth-only occluder."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("moderngl", reason="the AR demo needs the [ar] extra (moderngl)")
pytest.importorskip("pybullet", reason="the AR demo needs the [ar] extra (pybullet)")

from ar_demo.config import ARConfig
from ar_demo.physics import PhysicsFrame, PhysicsWorld
from ar_demo.render import (ARRenderer, RenderUnavailable, car_objects, create_context, flat_part,
                            load_racecar_parts, project_points, projection_from_intrinsics)
from lite_vo.camera import PinholeIntrinsics
from naive_ar import look_at

INTR = PinholeIntrinsics(300.0, 310.0, 161.3, 118.7, 320, 240)


@pytest.fixture(scope="module")
def renderer():
    try:
        ctx = create_context()
    except RenderUnavailable as err:
        pytest.skip(f"EGL off-screen OpenGL is unavailable here ({err}); AR rendering tests skipped")
    r = ARRenderer(ctx)
    yield r
    r.release()


@pytest.fixture(scope="module")
def car_scene():
    """A racecar resting on a flat height field (physics frame = world, z up), and its parts."""
    w = PhysicsWorld(ARConfig(), PhysicsFrame(np.eye(3), np.zeros(3), 1.0))
    w.set_height_field(np.zeros((41, 41)), 0.25)          # floor 10 m x 10 m around the origin
    w.spawn_car([1.5, 0.2], 0.7)
    for _ in range(30):
        w.step(1 / 30, autopilot=False)
    objs = car_objects(load_racecar_parts(), w.link_poses_phys(), w.frame.S_world_phys)
    w.close()
    return objs


def test_projection_matrix_matches_pinhole():
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), rng.uniform(0.5, 5, 50)])
    P = projection_from_intrinsics(INTR, 0.1, 10.0)
    clip = np.column_stack([pts, np.ones(50)]) @ P.T
    ndc = clip[:, :3] / clip[:, 3:]
    # window coordinate (ndc + 1) / 2 * size is the pixel centre + 0.5
    u = (ndc[:, 0] + 1) / 2 * INTR.width - 0.5
    v = (ndc[:, 1] + 1) / 2 * INTR.height - 0.5
    np.testing.assert_allclose(np.column_stack([u, v]), INTR.project(pts), atol=1e-9)
    z_near = np.array([0, 0, 0.1, 1.0]) @ P.T
    z_far = np.array([0, 0, 10.0, 1.0]) @ P.T
    assert z_near[2] / z_near[3] == pytest.approx(-1) and z_far[2] / z_far[3] == pytest.approx(1)


def test_background_is_copied_without_flip(renderer):
    bg = np.zeros((240, 320, 3), np.uint8)
    bg[..., 0] = np.arange(240)[:, None]          # rows
    bg[..., 1] = np.arange(320)[None, :] * 255 // 319
    bg[10:20, 30:40, 2] = 255
    out = renderer.render(INTR, np.eye(4), 0.1, 10, background=bg)
    np.testing.assert_array_equal(out, bg)


def test_car_pixels_where_projection_says(renderer, car_scene):
    T = look_at([0.0, 0.0, 0.9], [1.5, 0.2, 0.0])
    img = renderer.render(INTR, T, 0.05, 50, background=None, objects=car_scene)
    mask = img.max(axis=2) > 0
    assert mask.sum() > 200
    verts = np.concatenate([(np.column_stack([p.vertices, np.ones(len(p.vertices))]) @ M.T)[:, :3]
                            for p, M in car_scene])
    uv, z = project_points(INTR, T, verts)
    assert np.all(z > 0)
    ys, xs = np.nonzero(mask)
    # bounding boxes of rendered pixels and projected vertices agree to about a pixel
    assert abs(xs.min() - uv[:, 0].min()) < 1.5 and abs(xs.max() - uv[:, 0].max()) < 1.5
    assert abs(ys.min() - uv[:, 1].min()) < 1.5 and abs(ys.max() - uv[:, 1].max()) < 1.5
    # a point on the chassis top (blue) lands on a blue pixel
    chassis, M = next((p, M) for p, M in car_scene if p.link == 0)
    top = chassis.vertices[np.argmax(chassis.vertices[:, 2])]
    c = np.array([0.08, 0.0, top[2]])             # on the chassis' top plate (behind the laser), part frame
    uv1, _ = project_points(INTR, T, (M @ np.append(c, 1.0))[None, :3])
    u, v = uv1[0]
    px = img[int(round(v)), int(round(u))]
    assert px[2] > 2 * max(px[0], px[1], 10), f"expected the blue chassis at ({u:.1f}, {v:.1f}), got {px}"


def test_occluder_hides_car_and_writes_no_colour(renderer, car_scene):
    T = look_at([0.0, 0.0, 0.9], [1.5, 0.2, 0.0])
    bg = np.full((240, 320, 3), 77, np.uint8)
    visible = renderer.render(INTR, T, 0.05, 50, background=bg, objects=car_scene)
    assert (visible != 77).any(axis=2).sum() > 200
    # a wall between the camera and the car: depth only, the background stays untouched
    wall = np.array([[0.8, -2, -1], [0.8, 2, -1], [0.8, -2, 3], [0.8, 2, 3]], float)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    hidden = renderer.render(INTR, T, 0.05, 50, background=bg, occluder=(wall, faces), objects=car_scene)
    np.testing.assert_array_equal(hidden, bg)
    # the same wall behind the car occludes nothing
    behind = wall + [2.0, 0, 0]
    again = renderer.render(INTR, T, 0.05, 50, background=bg, occluder=(behind, faces), objects=car_scene)
    np.testing.assert_array_equal(again, visible)


def test_shaded_mesh_and_lines_draw(renderer):
    T = look_at([0.0, 0.0, 2.0], [2.0, 0.0, 0.0])
    tri = np.array([[2, -1, 0], [2, 1, 0], [3, 0, 0.5]], float)
    img = renderer.render(INTR, T, 0.05, 50, shaded_meshes=[("t", tri, np.array([[0, 1, 2]]), (0, 1, 0))],
                          lines=[(np.array([[1.5, -0.5, 0], [1.5, 0.5, 0]]), (1, 0, 0))])
    assert (img[..., 1] > 50).sum() > 50 and (img[..., 0] > 200).sum() > 5


def test_flat_part_normals():
    p = flat_part(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]), (1, 0, 0))
    np.testing.assert_allclose(p.normals, [[0, 0, 1]] * 3)
