"""Physics of the AR demo: pybullet (DIRECT mode, own client id), the world as a static concave
triangle mesh, the ``pybullet_data`` racecar and a simple autopilot.

**Physics frame.** pybullet works in a frame ``P`` with ``z`` up (the estimated ground normal),
the ground plane at ``z = 0`` and gravity ``(0, 0, -9.81)``. Points map as
``p_phys = s * R_phys_world @ (p_world - origin_world)``: a similarity, so the racecar keeps its
native size and dynamics (about 0.47 m long) and the *scene* is scaled around it; equivalently the
car is scaled to the scene. ``s`` comes from the car length wanted in world units: a fixed metric
length for metric runs, else a fraction of the median scene depth (monocular scale is arbitrary).
The frame is fixed once (first world model) so the simulation never jumps.

**World swap.** :meth:`PhysicsWorld.set_world_mesh` adds the new static body first and then removes
the old one (and its collision shape) between two simulation steps: the car keeps its state.

Ownership: a :class:`PhysicsWorld` is used by one thread only (the pipeline's main loop).
Imports: numpy, pybullet, pybullet_data, lite_vo (errors, geometry).
"""
from __future__ import annotations

import ctypes
import os
import sys
from contextlib import contextmanager

import math
from dataclasses import dataclass, field

import numpy as np

from lite_vo.errors import MissingExtraError
from lite_vo.geometry import make_pose, rotmat_from_quat_xyzw

GRAVITY = 9.81            # physical constant of the simulated world (m/s^2)
WHEELS = (2, 3, 5, 7)     # racecar.urdf joint indices of the driven wheels
STEERING = (4, 6)         # racecar.urdf joint indices of the steering hinges


@contextmanager
def c_stdout_silenced(fds=(1,)):
    """Silence what C code prints to the file descriptors ``fds`` inside the block (pybullet prints a
    build-time banner to stderr on import and to stdout on ``connect``/``disconnect``, which
    ``--quiet`` and piped output must not see)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(fd) for fd in fds]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in fds:
            os.dup2(devnull, fd)
        yield
    finally:
        try:
            ctypes.CDLL(None).fflush(None)   # what C buffered (stdout is a pipe) goes to /dev/null too
        except (OSError, AttributeError):
            pass
        for fd, keep in zip(fds, saved):
            os.dup2(keep, fd)
            os.close(keep)
        os.close(devnull)


_EXIT_SILENCED: list[bool] = []


def _silence_c_stdout_at_exit() -> None:
    sys.stdout.flush()
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)


def connect_direct(pb) -> int:
    """``pb.connect(pb.DIRECT)`` without pybullet's build-time banner, which it prints on connect and
    again when a client goes away (also at exit: so, once a client was made, descriptor 1 goes to
    /dev/null after Python's own output at exit)."""
    if not _EXIT_SILENCED:
        import atexit
        atexit.register(_silence_c_stdout_at_exit)
        _EXIT_SILENCED.append(True)
    with c_stdout_silenced():
        return pb.connect(pb.DIRECT)


def disconnect_quietly(pb, client: int) -> None:
    """``pb.disconnect`` without the banner (pybullet prints it again when a client goes away)."""
    with c_stdout_silenced():
        pb.disconnect(physicsClientId=client)


def import_pybullet():
    """``(pybullet, pybullet_data)`` (imported without its banner), or a one-line error naming the
    ``[ar]`` extra."""
    try:
        if "pybullet" not in sys.modules:
            with c_stdout_silenced((1, 2)):
                import pybullet  # noqa: F401
        import pybullet
        import pybullet_data
    except ImportError as err:
        raise MissingExtraError("the AR demo needs the [ar] extra: pip install 'lite-vo[ar]'") from err
    return pybullet, pybullet_data


_CAR_LENGTH: list[float] = []


def racecar_length() -> float:
    """Length (physics units) of the pybullet racecar, measured once from its link AABBs."""
    if not _CAR_LENGTH:
        pb, pbd = import_pybullet()
        c = connect_direct(pb)
        try:
            pb.setAdditionalSearchPath(pbd.getDataPath(), physicsClientId=c)
            car = pb.loadURDF("racecar/racecar.urdf", physicsClientId=c)
            lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
            for link in range(-1, pb.getNumJoints(car, physicsClientId=c)):
                a, b = pb.getAABB(car, link, physicsClientId=c)
                lo, hi = np.minimum(lo, a), np.maximum(hi, b)
            _CAR_LENGTH.append(float(hi[0] - lo[0]))
        finally:
            disconnect_quietly(pb, c)
    return _CAR_LENGTH[0]


@dataclass(frozen=True)
class PhysicsFrame:
    """Similarity between the world (VO) frame and the physics frame (z up, ground at z = 0)."""
    R_phys_world: np.ndarray     # (3, 3) rows: x, y, z (= up) axes of P in world coordinates
    origin_world: np.ndarray     # (3,) origin of P (on the ground plane)
    scale: float                 # physics units per world unit

    @classmethod
    def from_ground(cls, normal_world, height, T_world_cam0, scale: float) -> "PhysicsFrame":
        n = np.asarray(normal_world, dtype=np.float64)
        n = n / np.linalg.norm(n)
        T = np.asarray(T_world_cam0, dtype=np.float64)
        fwd = T[:3, 2] - (T[:3, 2] @ n) * n           # camera forward projected onto the plane
        if np.linalg.norm(fwd) < 1e-6:                # looking straight down: use the image up axis
            fwd = -T[:3, 1] - (-T[:3, 1] @ n) * n
        x = fwd / np.linalg.norm(fwd)
        y = np.cross(n, x)
        C = T[:3, 3]
        origin = C - (C @ n - height) * n
        return cls(np.stack([x, y, n]), origin, float(scale))

    def to_phys(self, points_world: np.ndarray) -> np.ndarray:
        return self.scale * (np.asarray(points_world, dtype=np.float64) - self.origin_world) @ self.R_phys_world.T

    def to_world(self, points_phys: np.ndarray) -> np.ndarray:
        return np.asarray(points_phys, dtype=np.float64) @ self.R_phys_world / self.scale + self.origin_world

    @property
    def S_world_phys(self) -> np.ndarray:
        """4x4 similarity matrix mapping physics points into the world."""
        S = np.eye(4)
        S[:3, :3] = self.R_phys_world.T / self.scale
        S[:3, 3] = self.origin_world
        return S


def pose_matrix(pos, quat_xyzw) -> np.ndarray:
    """4x4 pose from a position and a pybullet (xyzw) quaternion."""
    return make_pose(rotmat_from_quat_xyzw(quat_xyzw), pos)


@dataclass
class Autopilot:
    """Drive forward with a gentle wander, steer towards a target (to stay in view), reverse with
    opposite steering when blocked (hardly any progress, or pressed against an obstacle for
    ``blocked_time_s``). All quantities in physics units (car length ``car_length``)."""
    cfg: object
    car_length: float
    mode: str = "drive"
    t_mode: float = 0.0
    t: float = 0.0
    reversals: int = 0
    last_steer: float = 0.0
    contact_s: float = 0.0                           # how long the car has touched an obstacle
    _history: list = field(default_factory=list)     # (t, x, y) of the last blocked_time_s

    def command(self, dt: float, pos_xy, heading: float, forward_speed: float,
                target_xy=None, contact: bool = False) -> tuple[float, float]:
        """(wheel target velocity rad/s, steering angle rad) for the next ``dt`` seconds; ``contact``:
        the car touches an obstacle (a steep contact)."""
        c = self.cfg
        self.t += dt
        self.t_mode += dt
        self.contact_s = self.contact_s + dt if contact else 0.0
        wander = c.wander_amplitude * c.max_steer * math.sin(2 * math.pi * self.t / c.wander_period_s)
        if self.mode == "drive":
            steer = wander
            if target_xy is not None:
                d = np.asarray(target_xy, dtype=np.float64) - np.asarray(pos_xy, dtype=np.float64)
                if np.hypot(*d) > c.target_radius * self.car_length:
                    err = (math.atan2(d[1], d[0]) - heading + math.pi) % (2 * math.pi) - math.pi
                    steer = float(np.clip(c.steer_gain * err, -c.max_steer, c.max_steer))
            # blocked: hardly any progress over the last blocked_time_s (robust to bumping)
            self._history.append((self.t, float(pos_xy[0]), float(pos_xy[1])))
            while self._history and self._history[0][0] < self.t - c.blocked_time_s:
                self._history.pop(0)
            t0, x0, y0 = self._history[0]
            progress = math.hypot(pos_xy[0] - x0, pos_xy[1] - y0)
            window = self.t - t0
            blocked = self.t_mode > c.blocked_grace_s and (
                (window >= 0.9 * c.blocked_time_s and progress < c.blocked_speed * self.car_length * window)
                or self.contact_s >= c.blocked_time_s)
            if blocked:
                self.mode, self.t_mode = "reverse", 0.0
                self._history.clear()
                self.contact_s = 0.0
                self.reversals += 1
                self.last_steer = -math.copysign(c.max_steer, steer if steer else 1.0)
            else:
                self.last_steer = steer
                return c.drive_speed, steer
        # reverse: back up with the opposite steering, then drive again
        if self.t_mode > c.reverse_time_s:
            self.mode, self.t_mode = "drive", 0.0
            self._history.clear()
        return -c.drive_speed, self.last_steer


@dataclass
class CarState:
    T_phys_base: np.ndarray
    speed: float           # forward speed (physics units / s)
    mode: str


@dataclass
class PhysicsWorld:
    """pybullet world: static world mesh, optional ground slab, racecar, autopilot."""
    cfg: object
    frame: PhysicsFrame
    client: int = -1
    world_body: int = -1
    world_shape: int = -1
    field_body: int = -1
    field_shape: int = -1
    field_updates: int = 0
    car: int = -1
    car_length: float = 0.0
    autopilot: Autopilot | None = None
    sim_time: float = 0.0
    world_swaps: int = 0
    collisions: int = 0              # starts of side contacts between the car and the world mesh
    _in_contact: bool = False
    _pb: object = field(default=None, repr=False)

    def __post_init__(self):
        pb, pbd = import_pybullet()
        self._pb = pb
        self._data = pbd.getDataPath()
        self.client = connect_direct(pb)
        pb.setGravity(0, 0, -GRAVITY, physicsClientId=self.client)
        pb.setTimeStep(1.0 / self.cfg.physics_hz, physicsClientId=self.client)
        pb.setAdditionalSearchPath(self._data, physicsClientId=self.client)

    # ------------------------------------------------------------------ world
    def set_height_field(self, heights: np.ndarray, cell: float) -> None:
        """The static world as a height field (``heights[ix, iy]``, physics units; vertex ``(ix, iy)``
        at ``((ix + 0.5 - n/2) cell, (iy + 0.5 - n/2) cell)``). The first call makes the one body,
        later calls replace its shape in place (``replaceHeightfieldIndex``): no body or shape per
        update. The height range must stay the same (see :mod:`ar_demo.heightfield`)."""
        pb, c = self._pb, self.client
        h = np.asarray(heights, dtype=np.float64)
        n0, n1 = h.shape
        kw = dict(shapeType=pb.GEOM_HEIGHTFIELD, meshScale=[cell, cell, 1.0],
                  heightfieldData=np.ascontiguousarray(h.T).ravel().tolist(),
                  numHeightfieldRows=n0, numHeightfieldColumns=n1, physicsClientId=c)
        if self.field_body < 0:
            self.field_shape = pb.createCollisionShape(**kw)
            self.field_body = pb.createMultiBody(0, self.field_shape, physicsClientId=c)
            self._field_range = (float(h.min()), float(h.max()))
            pb.resetBasePositionAndOrientation(self.field_body, [0, 0, 0.5 * sum(self._field_range)], [0, 0, 0, 1],
                                               physicsClientId=c)
        else:
            if (float(h.min()), float(h.max())) != self._field_range:
                raise ValueError("set_height_field: the height range must not change between updates")
            pb.createCollisionShape(replaceHeightfieldIndex=self.field_shape, **kw)
        self.world_body = self.field_body
        self.field_updates += 1

    def set_world_mesh(self, vertices_world: np.ndarray, faces: np.ndarray) -> None:
        """Replace the static world body by the mesh (world coordinates): add new, remove old."""
        pb, c = self._pb, self.client
        faces = np.asarray(faces, dtype=np.int32)
        old_body = self.world_body  # its collision shape cannot be freed in pybullet 3.2
        self.world_body, self.world_shape = -1, -1
        if len(faces):
            verts = self.frame.to_phys(vertices_world)
            shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=verts.tolist(), indices=faces.ravel().tolist(),
                                            flags=pb.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=c)
            body = pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape, physicsClientId=c)
            self.world_body, self.world_shape = body, shape
        if old_body >= 0:
            # pybullet (3.2.x) cannot free a collision shape once a body used it ("it is used" /
            # "TODO: dealloc"), so only the body is removed; a 15x20 mesh shape is ~30 kB.
            pb.removeBody(old_body, physicsClientId=c)
        self.world_swaps += 1

    # ------------------------------------------------------------------ car
    def spawn_car(self, xy_phys, yaw: float) -> None:
        """Load the racecar with its footprint centre above ``xy_phys`` (dropped from ``spawn_height``
        car lengths above the surface below it), heading ``yaw`` about the up axis."""
        pb, c = self._pb, self.client
        if self.car >= 0:
            pb.removeBody(self.car, physicsClientId=c)
        self.car = pb.loadURDF("racecar/racecar.urdf", [0, 0, 0], [0, 0, 0, 1], physicsClientId=c)
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for link in range(-1, pb.getNumJoints(self.car, physicsClientId=c)):
            a, b = pb.getAABB(self.car, link, physicsClientId=c)
            lo, hi = np.minimum(lo, a), np.maximum(hi, b)
        self.car_length = float(hi[0] - lo[0])
        self._footprint = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
        ground = self.ray_down(xy_phys)
        z = (0.0 if ground is None else ground) + self.cfg.spawn_height * self.car_length
        c_, s_ = math.cos(yaw), math.sin(yaw)
        off = self._footprint
        base = (float(xy_phys[0]) - c_ * off[0] + s_ * off[1], float(xy_phys[1]) - s_ * off[0] - c_ * off[1])
        pb.resetBasePositionAndOrientation(self.car, [base[0], base[1], z],
                                           pb.getQuaternionFromEuler([0, 0, yaw]), physicsClientId=c)
        for j in WHEELS:
            pb.setJointMotorControl2(self.car, j, pb.VELOCITY_CONTROL, targetVelocity=0, force=0, physicsClientId=c)
        self.autopilot = Autopilot(self.cfg, self.car_length)

    def car_centre_xy(self) -> np.ndarray:
        """Physics-frame xy of the centre of the car's footprint (the base frame's origin is at its rear)."""
        T = self.car_state().T_phys_base
        return T[:2, 3] + T[:2, :3] @ self._footprint

    def car_state(self) -> CarState:
        pb, c = self._pb, self.client
        pos, quat = pb.getBasePositionAndOrientation(self.car, physicsClientId=c)
        T = pose_matrix(pos, quat)
        lin, _ = pb.getBaseVelocity(self.car, physicsClientId=c)
        speed = float(np.asarray(lin) @ T[:3, 0])
        return CarState(T, speed, self.autopilot.mode if self.autopilot else "idle")

    def drive(self, wheel_velocity: float, steer: float) -> None:
        pb, c = self._pb, self.client
        for j in WHEELS:
            pb.setJointMotorControl2(self.car, j, pb.VELOCITY_CONTROL, targetVelocity=wheel_velocity,
                                     force=self.cfg.drive_force, physicsClientId=c)
        for j in STEERING:
            pb.setJointMotorControl2(self.car, j, pb.POSITION_CONTROL, targetPosition=steer, physicsClientId=c)

    def step(self, dt: float, target_xy=None, autopilot: bool = True) -> None:
        """Advance the simulation by ``dt`` simulated seconds (fixed internal steps); the autopilot
        decides once per call."""
        pb, c = self._pb, self.client
        n = max(1, int(round(dt * self.cfg.physics_hz)))
        if self.car >= 0 and autopilot and self.autopilot is not None:
            st = self.car_state()
            yaw = math.atan2(st.T_phys_base[1, 0], st.T_phys_base[0, 0])
            centre = st.T_phys_base[:2, 3] + st.T_phys_base[:2, :3] @ self._footprint
            vel, steer = self.autopilot.command(n / self.cfg.physics_hz, centre, yaw, st.speed, target_xy,
                                                contact=self._in_contact)
            self.drive(vel, steer)
        for _ in range(n):
            pb.stepSimulation(physicsClientId=c)
        self.sim_time += n / self.cfg.physics_hz
        if self.car >= 0 and self.world_body >= 0:
            side = self.side_contact()
            if side and not self._in_contact:
                self.collisions += 1
            self._in_contact = side

    def side_contact(self) -> bool:
        """The car touches the world mesh with a steep contact normal (an obstacle, not the ground)."""
        pb = self._pb
        for cp in pb.getContactPoints(self.car, self.world_body, physicsClientId=self.client):
            if abs(cp[7][2]) < self.cfg.obstacle_normal_z:
                return True
        return False

    def link_poses_phys(self) -> dict[int, np.ndarray]:
        """URDF link frames (-1 = base) of the car in the physics frame."""
        pb, c = self._pb, self.client
        out = {-1: self.car_state().T_phys_base}
        n = pb.getNumJoints(self.car, physicsClientId=c)
        for link, st in enumerate(pb.getLinkStates(self.car, list(range(n)), computeForwardKinematics=True,
                                                   physicsClientId=c)):
            out[link] = pose_matrix(st[4], st[5])
        return out

    def visual_shapes(self) -> list[tuple]:
        return list(self._pb.getVisualShapeData(self.car, physicsClientId=self.client))

    def footprint_offset(self) -> np.ndarray:
        """Base-frame offset of the car's footprint centre (AABB centre in x, y; lowest point in z)."""
        return self._footprint

    def ray_down(self, xy_phys, z_from: float = 5.0) -> float | None:
        """Height of the first surface below ``xy_phys`` (None if nothing is hit)."""
        pb = self._pb
        hit = pb.rayTest([xy_phys[0], xy_phys[1], z_from], [xy_phys[0], xy_phys[1], -z_from],
                         physicsClientId=self.client)[0]
        return None if hit[0] < 0 else float(hit[3][2])

    def close(self) -> None:
        if self.client >= 0:
            try:
                disconnect_quietly(self._pb, self.client)
            except Exception:  # pragma: no cover - already disconnected
                pass
            self.client = -1

    def __del__(self):  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass
