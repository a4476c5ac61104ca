"""Thin helpers around pybullet (DIRECT mode): client, planar joint chains, contacts, modes.

Every function takes the physics client id explicitly, so several simulations can run in one
process. Planar bodies are built as joint chains on a fixed base: prismatic x, prismatic y
and (optionally) revolute z, the last link carrying the collision shape and all the mass.
Their coordinates are exact generalised coordinates (no drift out of the plane), their joint
velocities the exact twist, and a torque on each joint is exactly the applied world-frame
force (fx, fy) and moment tau about the link origin.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np
import pybullet as pb
from numpy.typing import NDArray

from .errors import BulletError

__all__ = [
    "BulletClient",
    "Contact",
    "PlanarChain",
    "contacts_between",
    "convex_margin",
    "create_planar_chain",
    "distribute_to_vertices",
    "mode_onehot",
    "set_material",
]

FloatArray = NDArray[np.float64]

SEPARATED, STICKING, SLIDING_POS, SLIDING_NEG = 0, 1, 2, 3


class BulletClient:
    """A pybullet DIRECT client configured for stiff, Coulomb-like contact.

    Friction: pyramid (two independent directions) by default, implicit cone (isotropic
    Coulomb) with `cone_friction=True` (used for push: the pyramid resists the rotation of a
    sliding body for free). No restitution, 'contactSlop' 0: pybullet otherwise
    leaves a steady 10 um penetration in resting contacts, which makes a squeezed body look
    jammed (negative gaps on both jaws) to a rigid time-stepping model.
    physics_dt: s. gravity: world-frame gravity vector (m/s^2). solver_iterations: constraint
    solver iterations per step. Use as a context manager (disconnects on exit).
    """

    def __init__(
        self,
        physics_dt: float,
        gravity: Sequence[float],
        solver_iterations: int = 100,
        cone_friction: bool = False,
    ) -> None:
        cid = pb.connect(pb.DIRECT)
        if cid < 0:
            msg = "pybullet.connect(DIRECT) failed (returned a negative client id)"
            raise BulletError(msg)
        self.id: int = cid
        pb.resetSimulation(physicsClientId=cid)
        pb.setTimeStep(physics_dt, physicsClientId=cid)
        pb.setGravity(*[float(g) for g in gravity], physicsClientId=cid)
        pb.setPhysicsEngineParameter(
            numSolverIterations=solver_iterations,
            numSubSteps=0,
            erp=0.2,
            contactERP=0.2,
            frictionERP=0.2,
            restitutionVelocityThreshold=10.0,
            enableConeFriction=1 if cone_friction else 0,
            deterministicOverlappingPairs=1,
            contactSlop=0.0,
            physicsClientId=cid,
        )

    def step(self) -> None:
        """Advance one physics step."""
        pb.stepSimulation(physicsClientId=self.id)

    def close(self) -> None:
        """Disconnect (idempotent)."""
        if self.id >= 0:
            try:
                pb.disconnect(physicsClientId=self.id)
            finally:
                self.id = -1

    def __enter__(self) -> BulletClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def set_material(
    cid: int,
    body: int,
    link: int,
    lateral_friction: float,
    collision_margin: float | None = None,
) -> None:
    """Coulomb friction only: lateral friction set, no rolling/spinning friction, no bounce.

    pybullet combines the friction of two bodies as the product of their coefficients: bodies
    get 1.0 and obstacles get the target coefficient. collision_margin (m): convex meshes get
    a 1 mm margin by default that inflates them (contact 1 mm before the true outline
    touches); pass 0.0 for exact geometry.
    """
    if collision_margin is not None:
        pb.changeDynamics(body, link, collisionMargin=collision_margin, physicsClientId=cid)
    pb.changeDynamics(
        body,
        link,
        lateralFriction=lateral_friction,
        rollingFriction=0.0,
        spinningFriction=0.0,
        restitution=0.0,
        linearDamping=0.0,
        angularDamping=0.0,
        frictionAnchor=0,
        physicsClientId=cid,
    )


@dataclass(frozen=True)
class PlanarChain:
    """A body on a prismatic-x / prismatic-y [/ revolute-z] chain; `link` carries the shape."""

    body: int
    joints: tuple[int, ...]
    link: int

    def state(self, cid: int) -> tuple[FloatArray, FloatArray]:
        """Generalised positions (x, y[, yaw]) and velocities (vx, vy[, omega])."""
        st = pb.getJointStates(self.body, list(self.joints), physicsClientId=cid)
        q = np.array([s[0] for s in st], dtype=np.float64)
        v = np.array([s[1] for s in st], dtype=np.float64)
        return q, v

    def reset(
        self, cid: int, q: Sequence[float] | FloatArray, v: Sequence[float] | FloatArray
    ) -> None:
        """Set positions and velocities."""
        for j, qj, vj in zip(self.joints, q, v, strict=True):
            pb.resetJointState(self.body, j, float(qj), float(vj), physicsClientId=cid)

    def free(self, cid: int) -> None:
        """Disable the default velocity motors (free joints, no joint damping)."""
        for j in self.joints:
            pb.setJointMotorControl2(
                self.body,
                j,
                pb.VELOCITY_CONTROL,
                targetVelocity=0.0,
                force=0.0,
                physicsClientId=cid,
            )
            pb.changeDynamics(self.body, j, jointDamping=0.0, physicsClientId=cid)

    def apply(self, cid: int, generalised_force: Sequence[float] | FloatArray) -> None:
        """Apply joint forces for the next step: (fx, fy[, tau]) N, N, N m, world frame."""
        pb.setJointMotorControlArray(
            self.body,
            list(self.joints),
            pb.TORQUE_CONTROL,
            forces=[float(f) for f in generalised_force],
            physicsClientId=cid,
        )


def create_planar_chain(
    cid: int,
    collision_shape: int,
    mass: float,
    inertia_z: float | None,
    *,
    base_position: Sequence[float] = (0.0, 0.0, 0.0),
    axes: Sequence[Sequence[float]] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    rotation_axis: Sequence[float] | None = None,
) -> PlanarChain:
    """Fixed base at `base_position`, prismatic joints along `axes`, optional revolute joint.

    The intermediate links are massless; the last link holds `mass` (kg) and, with a
    revolute joint, the moment of inertia `inertia_z` (kg m^2) about the rotation axis through
    the link origin (the centre of mass). Without a revolute joint the body cannot rotate.
    """
    n_prismatic = len(axes)
    types = [pb.JOINT_PRISMATIC] * n_prismatic
    joint_axes = [list(a) for a in axes]
    if rotation_axis is not None:
        types.append(pb.JOINT_REVOLUTE)
        joint_axes.append(list(rotation_axis))
    n = len(types)
    masses = [0.0] * (n - 1) + [float(mass)]
    shapes = [-1] * (n - 1) + [collision_shape]
    body = pb.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=-1,
        baseVisualShapeIndex=-1,
        basePosition=list(base_position),
        linkMasses=masses,
        linkCollisionShapeIndices=shapes,
        linkVisualShapeIndices=[-1] * n,
        linkPositions=[[0.0, 0.0, 0.0]] * n,
        linkOrientations=[[0.0, 0.0, 0.0, 1.0]] * n,
        linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n,
        linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n,
        linkParentIndices=list(range(n)),
        linkJointTypes=types,
        linkJointAxis=joint_axes,
        physicsClientId=cid,
    )
    if body < 0:
        msg = "pybullet.createMultiBody failed for a planar chain"
        raise BulletError(msg)
    link = n - 1
    if inertia_z is not None:
        # Only the component about the rotation axis acts; the others are kept positive.
        pb.changeDynamics(
            body,
            link,
            localInertiaDiagonal=[inertia_z, inertia_z, inertia_z],
            physicsClientId=cid,
        )
    chain = PlanarChain(body, tuple(range(n)), link)
    chain.free(cid)
    for j in range(n):
        pb.changeDynamics(
            body,
            j,
            linearDamping=0.0,
            angularDamping=0.0,
            jointDamping=0.0,
            physicsClientId=cid,
        )
    return chain


@dataclass(frozen=True)
class Contact:
    """One pybullet contact point (world frame).

    normal_on_b points from B into A; position_on_a/b are the witness points; normal_force
    (N) acts on A along normal_on_b; friction1/2 (N) along lateral directions dir1/dir2.
    """

    body_b: int
    link_b: int
    position_on_a: FloatArray
    position_on_b: FloatArray
    normal_on_b: FloatArray
    distance: float
    normal_force: float
    friction1: float
    dir1: FloatArray
    friction2: float
    dir2: FloatArray


def contacts_between(
    cid: int, body_a: int, link_a: int, body_b: int | None = None, link_b: int | None = None
) -> list[Contact]:
    """Contact points of (body_a, link_a) with body_b (any body if None) after the last step."""
    kwargs: dict[str, Any] = {"bodyA": body_a, "linkIndexA": link_a, "physicsClientId": cid}
    if body_b is not None:
        kwargs["bodyB"] = body_b
    if link_b is not None:
        kwargs["linkIndexB"] = link_b
    out = []
    for cp in pb.getContactPoints(**kwargs) or ():
        out.append(
            Contact(
                body_b=int(cp[2]),
                link_b=int(cp[4]),
                position_on_a=np.asarray(cp[5], dtype=np.float64),
                position_on_b=np.asarray(cp[6], dtype=np.float64),
                normal_on_b=np.asarray(cp[7], dtype=np.float64),
                distance=float(cp[8]),
                normal_force=float(cp[9]),
                friction1=float(cp[10]),
                dir1=np.asarray(cp[11], dtype=np.float64),
                friction2=float(cp[12]),
                dir2=np.asarray(cp[13], dtype=np.float64),
            )
        )
    return out


def mode_onehot(normal_force: float, vt: float, force_threshold: float, slip: float) -> FloatArray:
    """One-hot (separated, sticking, sliding_pos, sliding_neg) from normal force and vt.

    normal_force (N) > force_threshold means contact; then |vt| (m/s, tangential relative
    velocity of the body along t = (n_y, -n_x)) <= slip means sticking, else the sign of vt.
    """
    out = np.zeros(4, dtype=np.float64)
    if not normal_force > force_threshold:
        out[SEPARATED] = 1.0
    elif abs(vt) <= slip:
        out[STICKING] = 1.0
    elif vt > 0.0:
        out[SLIDING_POS] = 1.0
    else:
        out[SLIDING_NEG] = 1.0
    return out


def distribute_to_vertices(
    vertices: FloatArray, points: FloatArray, forces: FloatArray, snap: float = 0.05
) -> tuple[FloatArray, FloatArray]:
    """Attribute contact normal forces on a polygon outline to its vertices.

    vertices: (n, 2) world-frame outline (closed implicitly); points: (k, 2) contact points on
    it; forces: (k,) normal forces (N). A point at fraction s along edge (v_i, v_i+1) gives
    (1 - s) of its force to v_i and s to v_i+1 (same resultant and moment on a flat face);
    s within `snap` of an end goes wholly to that vertex. Returns the per-vertex forces (n,)
    and each point's distance from the outline (k,) (m).
    """
    n = len(vertices)
    out = np.zeros(n)
    dist = np.zeros(len(points))
    a = vertices
    b = np.roll(vertices, -1, axis=0)
    ab = b - a
    len2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    for k, (p, f) in enumerate(zip(points, forces, strict=True)):
        s = np.clip(np.einsum("ij,ij->i", p - a, ab) / len2, 0.0, 1.0)
        d = np.linalg.norm(a + s[:, None] * ab - p, axis=1)
        e = int(np.argmin(d))
        dist[k] = d[e]
        se = float(s[e])
        if se < snap:
            se = 0.0
        elif se > 1.0 - snap:
            se = 1.0
        out[e] += (1.0 - se) * f
        out[(e + 1) % n] += se * f
    return out, dist


def convex_margin(cid: int, collision_shape: int, lowest_y: float) -> float:
    """Collision margin (m) by which pybullet inflates a convex mesh shape, measured.

    pybullet gives convex meshes a margin (1 mm in 3.2.x) that inflates them outward, and
    `changeDynamics(collisionMargin=...)` does not reach multibody links. The simulations
    compensate by moving the obstacles by the margin (exact for flat obstacles and disks).
    lowest_y: the smallest vertex y of the shape in its own frame (m).
    """
    gap = 0.01
    probe = pb.createMultiBody(0.0, collision_shape, -1, [0.0, 0.0, 0.0], physicsClientId=cid)
    box_shape = pb.createCollisionShape(
        pb.GEOM_BOX, halfExtents=[1.0, 0.05, 1.0], physicsClientId=cid
    )
    box = pb.createMultiBody(
        0.0, box_shape, -1, [0.0, lowest_y - gap - 0.05, 0.0], physicsClientId=cid
    )
    try:
        pts = pb.getClosestPoints(probe, box, 0.1, physicsClientId=cid)
        if not pts:
            msg = "cannot measure the convex collision margin (no closest points)"
            raise BulletError(msg)
        return gap - min(float(cp[8]) for cp in pts)
    finally:
        pb.removeBody(box, physicsClientId=cid)
        pb.removeBody(probe, physicsClientId=cid)
