"""`push` scenario (MIT MCube set-up): a cylindrical pusher pushes a polygon prism on a table.

Horizontal table seen from above, gravity -z. The object is a free rigid body (a prism of
the outline from `shapes.load_outline`, `thickness` high) resting on a plane with friction
`mu_surface`; its lateral friction is 1, so the object-support coefficient is `mu_surface`
and the object-pusher coefficient `mu_pusher`. The pusher is a vertical cylinder on a
fixed-base prismatic-x / prismatic-y chain (joints `pusher_x`, `pusher_y`: the axis
position), driven kinematically (stiff position control with a large force limit) along a
straight line at constant speed, then held still. The measured pusher wrench is the total
contact force the object exerts on the pusher (as an F/T sensor in the tip would see it;
tau = 0 about the pusher axis), from pybullet's contact points.

The pybullet convex-mesh margin inflates the object; the simulation measures it and shrinks
the pusher cylinder and lifts the object by it, so the true outline touches exactly when its
distance to the pusher axis equals `pusher_radius`.

Truth: one potential contact `pusher`; n is the contact normal from the pusher into the
object, t = (n_y, -n_x), vt = t . (velocity of the object's material point at the contact -
pusher velocity). Friction pairs: `pusher` (and `support_pair` if set, with `mu_surface`).
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from dbcslam_core.scenario import Body, FrictionSpec, NoiseSpec, Scenario, SurfaceSpec

from .base import Simulation, Truth
from .bullet import (
    PlanarChain,
    contacts_between,
    convex_margin,
    create_planar_chain,
    mode_onehot,
    set_material,
)
from .errors import BulletError, ParamError
from .params import PushParams
from .shapes import Outline, load_outline

__all__ = ["PushSimulation", "push_path"]

_PUSHER_MASS = 1.0  # kg, irrelevant (kinematic): the motor force limit is large
_PUSHER_FORCE = 1.0e3  # N
_PUSHER_HALF_HEIGHT = 0.015  # m


def push_path(
    vertices: np.ndarray,
    *,
    side: int,
    side_position: float,
    angle: float,
    pusher_radius: float,
    approach: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start point (m), unit direction and touching point of the pusher axis.

    vertices: (n, 2) counter-clockwise outline (world frame); side i runs from vertex i to
    vertex i+1; the contact point is at `side_position` along it; the direction is the side's
    inward normal rotated by `angle` (rad, counter-clockwise); the pusher axis touches at the
    contact point plus `pusher_radius` along the outward normal and starts `approach` (m)
    before it.
    """
    n = len(vertices)
    if not 0 <= side < n:
        msg = f"parameter 'side' = {side} is out of range; valid: 0 .. {n - 1} for this outline"
        raise ParamError(msg)
    a, b = vertices[side], vertices[(side + 1) % n]
    e = b - a
    outward = np.array([e[1], -e[0]]) / float(np.linalg.norm(e))
    contact = a + side_position * e
    c, s = math.cos(angle), math.sin(angle)
    inward = -outward
    direction = np.array([c * inward[0] - s * inward[1], s * inward[0] + c * inward[1]])
    touch = contact + pusher_radius * outward
    return touch - approach * direction, direction, touch


class PushSimulation(Simulation):
    """Pusher pushing a polygon prism on a frictional support (see module docstring)."""

    name = "push"
    params_type = PushParams
    cone_friction = True

    def __init__(self, params: PushParams | None = None) -> None:
        super().__init__(params if params is not None else PushParams())
        self.params: PushParams
        p = self.params
        self.outline: Outline = load_outline(
            p.shape, thickness=p.thickness, mass=p.mass, inertia=p.inertia
        )
        self.start, self.direction, self.touch = push_path(
            self.outline.vertices,
            side=p.side,
            side_position=p.side_position,
            angle=p.angle,
            pusher_radius=p.pusher_radius,
            approach=p.approach,
        )
        self.margin = 0.0
        self._object = -1
        self._plane = -1
        self._pusher: PlanarChain | None = None

    @property
    def contacts(self) -> tuple[str, ...]:
        return ("pusher",)

    @property
    def pairs(self) -> tuple[str, ...]:
        sp = self.params.support_pair
        return ("pusher",) if sp is None else ("pusher", sp)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return ("pusher_x", "pusher_y")

    def scenario(self) -> Scenario:
        p = self.params
        cands = tuple(p.friction_candidates)
        prior = tuple(p.friction_prior)
        verts = tuple((float(x), float(y)) for x, y in self.outline.vertices)
        return Scenario(
            kind="push",
            dt=1.0 / p.rate,
            gravity=p.gravity,
            body=Body(
                mass=self.outline.mass,
                inertia=self.outline.inertia,
                shape="polygon",
                vertices=verts,
            ),
            contacts=self.contacts,
            friction=FrictionSpec(
                self.pairs, tuple(cands for _ in self.pairs), tuple(prior for _ in self.pairs)
            ),
            noise=NoiseSpec(position=p.noise.position, yaw=p.noise.yaw, joint=p.noise.joint),
            pusher_radius=p.pusher_radius,
            surface=SurfaceSpec(p.support_pair, ()),
        )

    @property
    def move_time(self) -> float:
        """Time (s) the pusher moves: (approach + travel) / speed."""
        p = self.params
        return (p.approach + p.travel) / p.speed

    def pusher_target(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Pusher axis target position (m) and velocity (m/s) at time t (s)."""
        p = self.params
        if t < self.move_time:
            return self.start + p.speed * t * self.direction, p.speed * self.direction
        return self.start + (p.approach + p.travel) * self.direction, np.zeros(2)

    def _gravity(self) -> tuple[float, float, float]:
        return (0.0, 0.0, -self.params.gravity)

    def _build(self, cid: int) -> None:
        p = self.params
        o = self.outline
        h = p.thickness / 2.0
        plane_shape = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=cid)
        self._plane = pb.createMultiBody(
            0.0, plane_shape, -1, [0.0, 0.0, 0.0], physicsClientId=cid
        )
        set_material(cid, self._plane, -1, p.mu_surface)

        prism = [[float(x), float(y), z] for z in (-h, h) for x, y in o.vertices]
        shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=prism, physicsClientId=cid)
        if shape < 0:
            msg = f"pybullet could not create the prism of shape {p.shape!r}"
            raise BulletError(msg)
        self.margin = convex_margin(cid, shape, float(np.min(o.vertices[:, 1])))
        if self.margin >= p.pusher_radius:
            msg = (
                f"pusher_radius {p.pusher_radius} m must exceed pybullet's collision margin "
                f"{self.margin} m"
            )
            raise ParamError(msg)
        z0 = h + self.margin
        obj = pb.createMultiBody(o.mass, shape, -1, [0.0, 0.0, z0], physicsClientId=cid)
        if obj < 0:
            msg = "pybullet could not create the pushed object"
            raise BulletError(msg)
        i_xy = 0.5 * o.inertia + o.mass * p.thickness**2 / 12.0
        pb.changeDynamics(
            obj, -1, localInertiaDiagonal=[i_xy, i_xy, o.inertia], physicsClientId=cid
        )
        set_material(cid, obj, -1, 1.0)
        self._object = obj

        cyl = pb.createCollisionShape(
            pb.GEOM_CYLINDER,
            radius=p.pusher_radius - self.margin,
            height=2.0 * _PUSHER_HALF_HEIGHT,
            physicsClientId=cid,
        )
        pusher = create_planar_chain(cid, cyl, _PUSHER_MASS, None, base_position=(0.0, 0.0, z0))
        set_material(cid, pusher.body, pusher.link, p.mu_pusher)
        for link in (-1, *pusher.joints):
            pb.setCollisionFilterPair(pusher.body, self._plane, link, -1, 0, physicsClientId=cid)
        pusher.reset(cid, self.start, (0.0, 0.0))
        self._pusher = pusher

    def _apply(self, cid: int, t: float) -> None:
        assert self._pusher is not None
        pos, vel = self.pusher_target(t)
        pb.setJointMotorControlArray(
            self._pusher.body,
            list(self._pusher.joints),
            pb.POSITION_CONTROL,
            targetPositions=[float(pos[0]), float(pos[1])],
            targetVelocities=[float(vel[0]), float(vel[1])],
            forces=[_PUSHER_FORCE, _PUSHER_FORCE],
            positionGains=[0.2, 0.2],
            velocityGains=[1.0, 1.0],
            physicsClientId=cid,
        )

    def _measure(self, cid: int, t: float) -> Truth:
        assert self._pusher is not None
        p = self.params
        pos, orn = pb.getBasePositionAndOrientation(self._object, physicsClientId=cid)
        lin, ang = pb.getBaseVelocity(self._object, physicsClientId=cid)
        yaw = float(pb.getEulerFromQuaternion(orn)[2])
        com = np.array(pos[:2])
        v_com = np.array(lin[:2])
        omega = float(ang[2])
        qp, vp = self._pusher.state(cid)

        cps = contacts_between(cid, self._object, -1, self._pusher.body, self._pusher.link)
        fn = 0.0
        force_on_pusher = np.zeros(3)
        normal = np.zeros(2)
        point = np.zeros(2)
        for cp in cps:
            fn += cp.normal_force
            # forces on A (object) are along normal_on_b and the friction directions
            f_obj = cp.normal_force * cp.normal_on_b + cp.friction1 * cp.dir1
            f_obj = f_obj + cp.friction2 * cp.dir2
            force_on_pusher -= f_obj
            normal += cp.normal_force * cp.normal_on_b[:2]
            point += cp.normal_force * cp.position_on_a[:2]
        vt = 0.0
        if fn > 0.0:
            n = normal / max(float(np.linalg.norm(normal)), 1e-300)
            r = point / fn - com
            v_point = v_com + omega * np.array([-r[1], r[0]])
            tangent = np.array([n[1], -n[0]])
            vt = float(tangent @ (v_point - vp))
        modes = mode_onehot(fn, vt, p.contact_force_threshold, p.slip_threshold)
        friction = [p.mu_pusher] if p.support_pair is None else [p.mu_pusher, p.mu_surface]
        return Truth(
            pose=np.array([com[0], com[1], yaw]),
            twist=np.array([v_com[0], v_com[1], omega]),
            joints=qp.copy(),
            pusher_wrench=np.array([force_on_pusher[0], force_on_pusher[1], 0.0]),
            modes=modes[None, :],
            friction=np.array(friction),
            normal_forces=np.array([fn]),
        )
