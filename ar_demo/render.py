"""Off-screen rendering of the AR demo with moderngl (EGL; Mesa's llvmpipe when there is no GPU).

One frame: the rectified camera image as background, the collision mesh drawn into the depth
buffer only (real geometry occludes virtual objects), then the car's visual meshes lit, all with
the estimated pose and the real intrinsics.

**Projection.** OpenCV camera coordinates (x right, y down, z forward) go straight to clip space:
``x_c = 2 fx/W x + (2 (cx + 0.5)/W - 1) z``, ``y_c = 2 fy/H y + (2 (cy + 0.5)/H - 1) z``,
``z_c = (f + n)/(f - n) z - 2 f n/(f - n)``, ``w_c = z``. Pixel ``u`` (centre at integer ``u``)
lands on window coordinate ``u + 0.5``, and image row 0 on framebuffer row 0, so the framebuffer
read back (bottom-up in GL terms) is the image in its usual row order, with no flip.

Ownership: an :class:`ARRenderer` holds a GL context and must be used by the thread that made it.
Imports: numpy, moderngl, trimesh (car meshes), lite_vo (camera, errors, geometry).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import LiteVOError, MissingExtraError
from lite_vo.geometry import inverse_se3, transform_points


class RenderUnavailable(LiteVOError):
    """No off-screen OpenGL context (EGL) could be created."""


def create_context():
    """A standalone moderngl context on EGL (raises :class:`RenderUnavailable`)."""
    try:
        import moderngl
    except ImportError as err:  # pragma: no cover
        raise MissingExtraError("the AR demo needs the [ar] extra: pip install 'lite-vo[ar]'") from err
    try:
        return moderngl.create_standalone_context(backend="egl")
    except Exception as err:
        raise RenderUnavailable(f"no off-screen OpenGL (EGL) context: {err}") from None


def projection_from_intrinsics(intr: PinholeIntrinsics, near: float, far: float) -> np.ndarray:
    """4x4 matrix from OpenCV camera coordinates to GL clip space (see the module docstring)."""
    W, H = intr.width, intr.height
    P = np.zeros((4, 4))
    P[0, 0] = 2 * intr.fx / W
    P[0, 2] = 2 * (intr.cx + 0.5) / W - 1
    P[1, 1] = 2 * intr.fy / H
    P[1, 2] = 2 * (intr.cy + 0.5) / H - 1
    P[2, 2] = (far + near) / (far - near)
    P[2, 3] = -2 * far * near / (far - near)
    P[3, 2] = 1.0
    return P


@dataclass
class MeshPart:
    """A rigid triangle soup (flat shaded): vertices (N, 3) in its own frame, one normal per vertex."""
    vertices: np.ndarray
    normals: np.ndarray
    color: tuple
    link: int = -1                  # physics link it is attached to (-1 = base)
    T_link_part: np.ndarray | None = None


def flat_part(vertices, faces, color, link=-1, T_link_part=None) -> MeshPart:
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces).reshape(-1)]
    tri = v.reshape(-1, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(ln > 0, n / np.where(ln > 0, ln, 1), 0.0)
    return MeshPart(v, np.repeat(n, 3, axis=0), tuple(color), link,
                    np.eye(4) if T_link_part is None else np.asarray(T_link_part, dtype=np.float64))


def car_parts_from_visual_shapes(visual_shapes, tyre_color=(0.12, 0.12, 0.12)) -> list[MeshPart]:
    """Car meshes from ``pybullet.getVisualShapeData`` rows (mesh files loaded with trimesh; boxes made).

    The local visual frames are relative to the URDF link frames (checked on the racecar: the wheel
    meshes sit at the link origin, their collision cylinders at the inertial frame)."""
    import trimesh
    from .physics import pose_matrix
    parts = []
    cache: dict[str, trimesh.Trimesh] = {}
    for vs in visual_shapes:
        link, geom, dims, fname, pos, orn, rgba = vs[1], vs[2], vs[3], vs[4], vs[5], vs[6], vs[7]
        if geom == 5:  # mesh
            path = fname.decode() if isinstance(fname, bytes) else str(fname)
            if path not in cache:
                cache[path] = trimesh.load(path, force="mesh", process=False)
            m = cache[path]
            verts, faces = np.asarray(m.vertices) * np.asarray(dims), np.asarray(m.faces)
        elif geom == 3:  # box, dims = full extents
            m = trimesh.creation.box(extents=dims)
            verts, faces = np.asarray(m.vertices), np.asarray(m.faces)
        else:
            continue
        color = tuple(rgba[:3])
        if min(color) > 0.95:               # white wheels read as tyres
            color = tyre_color
        parts.append(flat_part(verts, faces, color, link, pose_matrix(pos, orn)))
    return parts


_VS_LIT = """
#version 330
uniform mat4 mvp;
uniform mat3 normal_mat;
in vec3 in_pos;
in vec3 in_normal;
out vec3 v_normal;
void main() {
    gl_Position = mvp * vec4(in_pos, 1.0);
    v_normal = normal_mat * in_normal;
}
"""
_FS_LIT = """
#version 330
uniform vec3 color;
uniform vec3 light_dir;
uniform float ambient;
in vec3 v_normal;
out vec4 f_color;
void main() {
    float l = length(v_normal) > 0.0 ? abs(dot(normalize(v_normal), light_dir)) : 0.5;
    f_color = vec4(color * (ambient + (1.0 - ambient) * l), 1.0);
}
"""
_VS_PLAIN = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;
void main() { gl_Position = mvp * vec4(in_pos, 1.0); }
"""
_FS_PLAIN = """
#version 330
uniform vec3 color;
out vec4 f_color;
void main() { f_color = vec4(color, 1.0); }
"""
_VS_BG = """
#version 330
in vec2 in_pos;
out vec2 v_uv;
void main() { v_uv = (in_pos + 1.0) * 0.5; gl_Position = vec4(in_pos, 0.0, 1.0); }
"""
_FS_BG = """
#version 330
uniform sampler2D tex;
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = vec4(texture(tex, v_uv).rgb, 1.0); }
"""


class ARRenderer:
    """Renders camera image + occluding world mesh + lit objects into RGB uint8 images."""

    def __init__(self, ctx=None, ambient: float = 0.35, occluder_offset: tuple = (1.0, 4.0)):
        import moderngl
        self._mgl = moderngl
        self.ctx = ctx if ctx is not None else create_context()
        self.ambient = float(ambient)
        self.occluder_offset = tuple(occluder_offset)    # glPolygonOffset (factor, units) of the occluder
        self.prog_lit = self.ctx.program(vertex_shader=_VS_LIT, fragment_shader=_FS_LIT)
        self.prog_plain = self.ctx.program(vertex_shader=_VS_PLAIN, fragment_shader=_FS_PLAIN)
        self.prog_bg = self.ctx.program(vertex_shader=_VS_BG, fragment_shader=_FS_BG)
        quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], dtype="f4")
        self._bg_vao = self.ctx.vertex_array(self.prog_bg, [(self.ctx.buffer(quad.tobytes()), "2f", "in_pos")])
        self._fbos: dict[tuple[int, int], object] = {}
        self._textures: dict[tuple[int, int], object] = {}
        self._part_vaos: dict[int, tuple] = {}
        self._mesh_cache: dict[str, tuple] = {}

    # ------------------------------------------------------------------ resources
    def _fbo(self, w, h):
        if (w, h) not in self._fbos:
            self._fbos[(w, h)] = self.ctx.framebuffer(color_attachments=[self.ctx.renderbuffer((w, h), 4)],
                                                      depth_attachment=self.ctx.depth_renderbuffer((w, h)))
        return self._fbos[(w, h)]

    def _part_vao(self, part: MeshPart):
        key = id(part)
        if key not in self._part_vaos:
            data = np.hstack([part.vertices, part.normals]).astype("f4")
            vbo = self.ctx.buffer(data.tobytes())
            vao = self.ctx.vertex_array(self.prog_lit, [(vbo, "3f 3f", "in_pos", "in_normal")])
            self._part_vaos[key] = (vao, vbo, part)    # keep part alive so id() stays unique
        return self._part_vaos[key][0]

    def _mesh_vaos(self, key: str, vertices, faces, shaded: bool):
        """VAOs (plain, lit) of a world mesh, cached under ``key`` until the mesh changes."""
        hit = self._mesh_cache.get(key)
        if hit is not None and hit[0] is vertices and hit[4] is faces:   # cached arrays stay referenced
            return hit[1], hit[2]
        if hit is not None:
            for obj in hit[3]:
                obj.release()
        part = flat_part(vertices, faces, (1, 1, 1))
        vbo_p = self.ctx.buffer(part.vertices.astype("f4").tobytes())
        vao_p = self.ctx.vertex_array(self.prog_plain, [(vbo_p, "3f", "in_pos")])
        vbo_l = self.ctx.buffer(np.hstack([part.vertices, part.normals]).astype("f4").tobytes())
        vao_l = self.ctx.vertex_array(self.prog_lit, [(vbo_l, "3f 3f", "in_pos", "in_normal")])
        self._mesh_cache[key] = (vertices, vao_p, vao_l, (vao_p, vbo_p, vao_l, vbo_l), faces)
        return vao_p, vao_l

    # ------------------------------------------------------------------ drawing
    def render(self, intrinsics: PinholeIntrinsics, T_world_cam: np.ndarray, near: float, far: float,
               background=None, occluder=None, objects=(), shaded_meshes=(), lines=(),
               up_world=(0.0, 0.0, 1.0), clear_color=(0.0, 0.0, 0.0)) -> np.ndarray:
        """RGB uint8 (H, W, 3) image.

        ``background``: uint8 (H, W) or (H, W, 3) image (or None); ``occluder``: (vertices_world,
        faces) drawn into the depth buffer only; ``objects``: (MeshPart, M_world_part) pairs with
        M a 4x4 similarity; ``shaded_meshes``: (key, vertices_world, faces, rgb) drawn lit;
        ``lines``: ((N, 3) world points, rgb) drawn as line segments (pairs).
        """
        mgl = self._mgl
        W, H = intrinsics.width, intrinsics.height
        fbo = self._fbo(W, H)
        fbo.use()
        fbo.clear(*clear_color, 1.0, depth=1.0)
        ctx = self.ctx
        P = projection_from_intrinsics(intrinsics, near, far)
        T_cam_world = np.linalg.inv(np.asarray(T_world_cam, dtype=np.float64))
        VP = P @ T_cam_world
        up = np.asarray(up_world, dtype=np.float64)
        light = T_cam_world[:3, :3] @ (up / np.linalg.norm(up)) + np.array([0.3, 0.0, -0.4])
        light /= np.linalg.norm(light)
        if background is not None:
            img = np.asarray(background)
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=2)
            img = np.ascontiguousarray(img[..., :3].astype(np.uint8))
            if img.shape[:2] != (H, W):
                raise LiteVOError(f"render: background {img.shape[1]}x{img.shape[0]} does not match {W}x{H}")
            tex = self._textures.get((W, H))
            if tex is None:
                tex = self._textures[(W, H)] = ctx.texture((W, H), 3, alignment=1)
            tex.write(img.tobytes(), alignment=1)
            tex.use(0)
            self.prog_bg["tex"].value = 0
            ctx.disable(mgl.DEPTH_TEST)
            self._bg_vao.render(mgl.TRIANGLE_STRIP)
        ctx.enable(mgl.DEPTH_TEST)
        if occluder is not None and len(occluder[1]):
            vao_p, _ = self._mesh_vaos("occluder", occluder[0], occluder[1], False)
            self.prog_plain["mvp"].write(VP.T.astype("f4").tobytes())
            self.prog_plain["color"].value = (0.0, 0.0, 0.0)
            # depth only: blending with (ZERO, ONE) keeps the colour already in the framebuffer
            # and a small depth offset (away from the camera), so wheels touching the mesh do not flicker
            ctx.enable(mgl.BLEND)
            ctx.blend_func = mgl.ZERO, mgl.ONE
            ctx.polygon_offset = self.occluder_offset
            vao_p.render(mgl.TRIANGLES)
            ctx.polygon_offset = 0.0, 0.0
            ctx.disable(mgl.BLEND)
        self.prog_lit["light_dir"].value = tuple(light)
        self.prog_lit["ambient"].value = self.ambient
        for key, verts, faces, rgb in shaded_meshes:
            if not len(faces):
                continue
            _, vao_l = self._mesh_vaos(key, verts, faces, True)
            self.prog_lit["mvp"].write(VP.T.astype("f4").tobytes())
            self.prog_lit["normal_mat"].write(T_cam_world[:3, :3].T.astype("f4").tobytes())
            self.prog_lit["color"].value = tuple(rgb)
            vao_l.render(mgl.TRIANGLES)
        for part, M in objects:
            MV = T_cam_world @ np.asarray(M, dtype=np.float64)
            self.prog_lit["mvp"].write((P @ MV).T.astype("f4").tobytes())
            self.prog_lit["normal_mat"].write(MV[:3, :3].T.astype("f4").tobytes())   # similarity: renormalised
            self.prog_lit["color"].value = tuple(part.color)
            self._part_vao(part).render(mgl.TRIANGLES)
        for pts, rgb in lines:
            pts = np.asarray(pts, dtype="f4")
            vbo = ctx.buffer(pts.tobytes())
            vao = ctx.vertex_array(self.prog_plain, [(vbo, "3f", "in_pos")])
            self.prog_plain["mvp"].write(VP.T.astype("f4").tobytes())
            self.prog_plain["color"].value = tuple(rgb)
            vao.render(mgl.LINES)
            vao.release()
            vbo.release()
        data = fbo.read(components=3, alignment=1)
        return np.frombuffer(data, dtype=np.uint8).reshape(H, W, 3).copy()

    def release(self) -> None:
        try:
            self.ctx.release()
        except Exception:  # pragma: no cover
            pass


def car_objects(parts: list[MeshPart], link_poses_phys: dict[int, np.ndarray], S_world_phys: np.ndarray):
    """(part, M_world_part) pairs for :meth:`ARRenderer.render` from physics link poses."""
    return [(p, S_world_phys @ link_poses_phys[p.link] @ p.T_link_part) for p in parts if p.link in link_poses_phys]


def project_points(intr: PinholeIntrinsics, T_world_cam: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """Pixel coordinates (N, 2) and depth (N,) of world points (numpy reference for tests)."""
    pc = transform_points(inverse_se3(T_world_cam), points_world)
    return intr.project(pc), pc[:, 2]


def load_racecar_parts() -> list[MeshPart]:
    """The racecar's visual meshes (a throw-away DIRECT pybullet client reads the URDF)."""
    from .physics import connect_direct, disconnect_quietly, import_pybullet
    pb, pybullet_data = import_pybullet()
    c = connect_direct(pb)
    try:
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
        car = pb.loadURDF(str(Path("racecar") / "racecar.urdf"), physicsClientId=c)
        return car_parts_from_visual_shapes(pb.getVisualShapeData(car, physicsClientId=c))
    finally:
        disconnect_quietly(pb, c)
