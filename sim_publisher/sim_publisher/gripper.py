"""`gripper` scenario (paper Fig. 4): a triangle between two closing parallel jaws.

Horizontal table seen from above (gravity -z, irrelevant in the plane). The triangular prism
rides on a prismatic-x / prismatic-y / revolute-z chain (z, roll and pitch fixed: a
frictionless support). Its lateral friction is 1, the jaws' is `jaw_mu`, so the pair's
coefficient is `jaw_mu`. The jaws are two prismatic-y links of one fixed-base body: the lower
jaw's face (normal +y) is at y = joint `lower_jaw`, the upper jaw's face (normal -y) at
y = joint `upper_jaw`. Each jaw is position controlled towards a target closing at
`jaw_speed` with at most `jaw_force`, so the jaws stop on the object and squeeze it (joint
damping removes the common drift two equally saturated jaws would otherwise keep). A
time-varying force and moment at the centroid (the known input u) make the triangle rattle
between the jaws before the grasp is secure. pybullet inflates the prism by a collision
margin; the jaw faces are retracted by the measured margin, so a vertex touches a jaw exactly
when it reaches the jaw's joint position.

Truth: potential contacts `v{i}_{jaw}` (vertex i of the outline, jaw in lower, upper; jaw
major order, as `dbcslam_core.scenario.Scenario.default_contacts`); the normal force of each
pybullet contact point is split between the two vertices of the outline edge it lies on, by
its position along the edge (a vertex contact goes wholly to its vertex); n = (0, 1),
t = (1, 0) for the lower jaw and n = (0, -1), t = (-1, 0) for the upper jaw; the tangential
relative velocity is the vertex velocity along t (jaws move along y only). One friction pair
`jaws`.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from dbcslam_core.scenario import Body, FrictionSpec, NoiseSpec, Scenario

from .base import Simulation, Truth, interpolate_keyframes
from .bullet import (
    PlanarChain,
    contacts_between,
    convex_margin,
    create_planar_chain,
    distribute_to_vertices,
    mode_onehot,
    set_material,
)
from .errors import BulletError
from .params import GripperParams

__all__ = ["GripperSimulation"]

JAWS: tuple[str, ...] = ("lower", "upper")
_JAW_HALF_LENGTH = 0.25  # m, along x
_JAW_HALF_THICKNESS = 0.01  # m, along y
_JAW_MASS = 0.5  # kg
_JAW_DAMPING = 20.0  # N s/m: damps the common drift of two force-limited jaws after the grasp
_POSITION_GAIN = 0.1
_VELOCITY_GAIN = 1.0


class GripperSimulation(Simulation):
    """Triangle between position-controlled parallel jaws (see module docstring)."""

    name = "gripper"
    params_type = GripperParams

    def __init__(self, params: GripperParams | None = None) -> None:
        super().__init__(params if params is not None else GripperParams())
        self.params: GripperParams
        self._chain: PlanarChain | None = None
        self._jaw_body = -1
        self._verts = np.asarray(self.params.vertices, dtype=np.float64)
        self.margin = 0.0
        """Measured pybullet collision margin of the prism (m)."""
        self.unmatched_contacts = 0
        """Contact points farther than margin + 1 mm from the outline (should stay 0)."""

    @property
    def contacts(self) -> tuple[str, ...]:
        n = len(self.params.vertices)
        return tuple(f"v{i}_{jaw}" for jaw in JAWS for i in range(n))

    @property
    def pairs(self) -> tuple[str, ...]:
        return ("jaws",)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return ("lower_jaw", "upper_jaw")

    def scenario(self) -> Scenario:
        p = self.params
        cands = tuple(p.friction_candidates)
        return Scenario(
            kind="gripper",
            dt=1.0 / p.rate,
            gravity=p.gravity,
            body=Body(mass=p.mass, inertia=p.body_inertia, shape="polygon", vertices=p.vertices),
            contacts=self.contacts,
            friction=FrictionSpec(self.pairs, (cands,), (tuple(p.friction_prior),)),
            noise=NoiseSpec(position=p.noise.position, yaw=p.noise.yaw, joint=p.noise.joint),
        )

    def _gravity(self) -> tuple[float, float, float]:
        return (0.0, 0.0, -self.params.gravity)

    def _build(self, cid: int) -> None:
        p = self.params
        h = p.thickness / 2.0
        prism = [[x, y, z] for z in (-h, h) for x, y in p.vertices]
        shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=prism, physicsClientId=cid)
        if shape < 0:
            msg = f"pybullet could not create the prism of vertices {list(p.vertices)}"
            raise BulletError(msg)
        # pybullet inflates the prism by a margin: retract the jaw faces by it so that the
        # true outline touches a face exactly when a vertex reaches the joint position.
        self.margin = convex_margin(cid, shape, min(y for _, y in p.vertices))
        chain = create_planar_chain(
            cid, shape, p.mass, p.body_inertia, rotation_axis=(0.0, 0.0, 1.0)
        )
        set_material(cid, chain.body, chain.link, 1.0)
        chain.reset(cid, p.start, p.start_twist)
        self._chain = chain

        half = [_JAW_HALF_LENGTH, _JAW_HALF_THICKNESS, 2.0 * h]
        jaw_shapes = [
            pb.createCollisionShape(
                pb.GEOM_BOX,
                halfExtents=half,
                collisionFramePosition=[0.0, sign * (_JAW_HALF_THICKNESS + self.margin), 0.0],
                physicsClientId=cid,
            )
            for sign in (-1.0, 1.0)
        ]
        body = pb.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=-1,
            baseVisualShapeIndex=-1,
            basePosition=[0.0, 0.0, 0.0],
            linkMasses=[_JAW_MASS, _JAW_MASS],
            linkCollisionShapeIndices=jaw_shapes,
            linkVisualShapeIndices=[-1, -1],
            linkPositions=[[0.0, 0.0, 0.0]] * 2,
            linkOrientations=[[0.0, 0.0, 0.0, 1.0]] * 2,
            linkInertialFramePositions=[[0.0, 0.0, 0.0]] * 2,
            linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * 2,
            linkParentIndices=[0, 0],
            linkJointTypes=[pb.JOINT_PRISMATIC] * 2,
            linkJointAxis=[[0.0, 1.0, 0.0]] * 2,
            physicsClientId=cid,
        )
        if body < 0:
            msg = "pybullet could not create the jaws"
            raise BulletError(msg)
        self._jaw_body = body
        for j, start in enumerate((p.lower_start, p.upper_start)):
            set_material(cid, body, j, p.jaw_mu)
            pb.changeDynamics(body, j, jointDamping=_JAW_DAMPING, physicsClientId=cid)
            pb.resetJointState(body, j, start, 0.0, physicsClientId=cid)

    def jaw_targets(self, t: float) -> tuple[tuple[float, float], tuple[float, float]]:
        """Jaw (target position m, target velocity m/s) of (lower, upper) at time t (s)."""
        p = self.params
        out = []
        for start, target in ((p.lower_start, p.lower_target), (p.upper_start, p.upper_target)):
            direction = math.copysign(1.0, target - start)
            travel = abs(target - start)
            moved = p.jaw_speed * t
            if moved < travel:
                out.append((start + direction * moved, direction * p.jaw_speed))
            else:
                out.append((target, 0.0))
        return out[0], out[1]

    def input_wrench(self, t: float) -> np.ndarray:
        return interpolate_keyframes(self.params.wrench, t)

    def _apply(self, cid: int, t: float) -> None:
        assert self._chain is not None
        p = self.params
        for j, (pos, vel) in enumerate(self.jaw_targets(t)):
            pb.setJointMotorControl2(
                self._jaw_body,
                j,
                pb.POSITION_CONTROL,
                targetPosition=pos,
                targetVelocity=vel,
                positionGain=_POSITION_GAIN,
                velocityGain=_VELOCITY_GAIN,
                force=p.jaw_force,
                physicsClientId=cid,
            )
        self._chain.apply(cid, self.input_wrench(t))

    def _measure(self, cid: int, t: float) -> Truth:
        assert self._chain is not None
        p = self.params
        q, v = self._chain.state(cid)
        c, s = math.cos(q[2]), math.sin(q[2])
        rot = np.array([[c, -s], [s, c]])
        rel = self._verts @ rot.T  # vertex offsets from the centroid, world frame
        world = q[:2] + rel
        vel = v[:2] + v[2] * np.stack([-rel[:, 1], rel[:, 0]], axis=1)
        n_v = len(self._verts)
        fn = np.zeros(2 * n_v)
        for j in range(2):
            cps = contacts_between(cid, self._chain.body, self._chain.link, self._jaw_body, j)
            if not cps:
                continue
            points = np.array([cp.position_on_a[:2] for cp in cps])
            forces = np.array([cp.normal_force for cp in cps])
            per_vertex, dist = distribute_to_vertices(world, points, forces)
            self.unmatched_contacts += int(np.count_nonzero(dist > self.margin + 1e-3))
            fn[j * n_v : (j + 1) * n_v] = per_vertex
        modes = np.zeros((2 * n_v, 4))
        for j, tangent_x in enumerate((1.0, -1.0)):
            for i in range(n_v):
                vt = tangent_x * float(vel[i, 0])
                modes[j * n_v + i] = mode_onehot(
                    fn[j * n_v + i], vt, p.contact_force_threshold, p.slip_threshold
                )
        jaw_states = pb.getJointStates(self._jaw_body, [0, 1], physicsClientId=cid)
        return Truth(
            pose=q.copy(),
            twist=v.copy(),
            joints=np.array([jaw_states[0][0], jaw_states[1][0]]),
            pusher_wrench=np.zeros(3),
            modes=modes,
            friction=np.array([p.jaw_mu]),
            normal_forces=fn,
        )
