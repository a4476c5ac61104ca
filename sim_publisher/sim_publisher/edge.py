"""`edge` scenario (paper Fig. 3): a point mass pressed onto an edge with varying friction.

Vertical x-y plane, gravity -y. The point mass is the centre of a small sphere on a
prismatic-x / prismatic-y chain (it cannot rotate, so it is a true point mass); its lateral
friction is 1 so the contact coefficient equals the edge's. The edge is one long static box
whose top face lies at y = edge_y - radius, so the point touches the edge exactly at
y = edge_y. The friction segments (`EdgeParams.segments`, the hidden truth) are realised by
setting the box's coefficient, before every physics step, to the coefficient of the segment
under the point: separate boxes per segment make the sphere hit the next box's corner at
every seam (a spurious normal impulse that throws it off the edge), a single box does not.
A time-varying force (the known input u) drives the body: with the defaults it falls onto
the left smooth segment, slides right, slides to a halt in the rough segment, sticks while
the pushing force ramps up, slides out again and is lifted off the edge near the right end.

Truth: one potential contact `edge`, friction pair `edge`; normal force from pybullet's
contact points; n = (0, 1), t = (1, 0), so sliding_pos is moving +x; true friction is the
coefficient of the segment under the point.
"""

from __future__ import annotations

import numpy as np
import pybullet as pb

from dbcslam_core.scenario import Body, FrictionSpec, NoiseSpec, Scenario

from .base import Simulation, Truth, interpolate_keyframes
from .bullet import PlanarChain, contacts_between, create_planar_chain, mode_onehot, set_material
from .errors import BulletError
from .params import EdgeParams

__all__ = ["EdgeSimulation"]

_BOX_DEPTH = 0.05  # m, half height (y) and half depth (z) of the edge boxes


class EdgeSimulation(Simulation):
    """Point mass on a friction-varying edge (see module docstring)."""

    name = "edge"
    params_type = EdgeParams
    point_body = True

    def __init__(self, params: EdgeParams | None = None) -> None:
        super().__init__(params if params is not None else EdgeParams())
        self.params: EdgeParams
        self._chain: PlanarChain | None = None
        self._edge = -1
        self._mu = 0.0

    @property
    def contacts(self) -> tuple[str, ...]:
        return ("edge",)

    @property
    def pairs(self) -> tuple[str, ...]:
        return ("edge",)

    def scenario(self) -> Scenario:
        p = self.params
        cands = tuple(p.friction_candidates)
        return Scenario(
            kind="edge",
            dt=1.0 / p.rate,
            gravity=p.gravity,
            body=Body(mass=p.mass),
            contacts=self.contacts,
            friction=FrictionSpec(self.pairs, (cands,), (tuple(p.friction_prior),)),
            noise=NoiseSpec(position=p.noise.position, yaw=p.noise.yaw, joint=p.noise.joint),
            edge_y=p.edge_y,
        )

    def _gravity(self) -> tuple[float, float, float]:
        return (0.0, -self.params.gravity, 0.0)

    def _build(self, cid: int) -> None:
        p = self.params
        top = p.edge_y - p.radius
        x0, x1 = p.segments[0][0], p.segments[-1][1]
        shape = pb.createCollisionShape(
            pb.GEOM_BOX,
            halfExtents=[(x1 - x0) / 2.0, _BOX_DEPTH, _BOX_DEPTH],
            physicsClientId=cid,
        )
        edge = pb.createMultiBody(
            0.0, shape, -1, [(x0 + x1) / 2.0, top - _BOX_DEPTH, 0.0], physicsClientId=cid
        )
        if edge < 0:
            msg = f"pybullet could not create the edge box x in [{x0}, {x1}]"
            raise BulletError(msg)
        self._edge = edge
        self._mu = p.mu_at(p.start[0])
        set_material(cid, edge, -1, self._mu)
        sphere = pb.createCollisionShape(pb.GEOM_SPHERE, radius=p.radius, physicsClientId=cid)
        chain = create_planar_chain(cid, sphere, p.mass, None)
        set_material(cid, chain.body, chain.link, 1.0)
        chain.reset(cid, p.start, p.start_velocity)
        self._chain = chain

    def input_wrench(self, t: float) -> np.ndarray:
        f = interpolate_keyframes(self.params.force, t)
        return np.array([f[0], f[1], 0.0])

    def _apply(self, cid: int, t: float) -> None:
        assert self._chain is not None
        x = pb.getJointState(self._chain.body, self._chain.joints[0], physicsClientId=cid)[0]
        mu = self.params.mu_at(float(x))
        if mu != self._mu:
            pb.changeDynamics(self._edge, -1, lateralFriction=mu, physicsClientId=cid)
            self._mu = mu
        force = self.input_wrench(t)[:2]
        if self.params.damping > 0.0:  # hidden viscous damping (not in the recorded wrench)
            _q, v = self._chain.state(cid)
            force = force - self.params.damping * v[:2]
        self._chain.apply(cid, force)

    def _measure(self, cid: int, t: float) -> Truth:
        assert self._chain is not None
        p = self.params
        q, v = self._chain.state(cid)
        fn = sum(
            c.normal_force
            for c in contacts_between(cid, self._chain.body, self._chain.link)
            if c.body_b == self._edge
        )
        # n = (0, 1) -> t = (1, 0): the tangential relative velocity is vx (edge is static)
        modes = mode_onehot(fn, float(v[0]), p.contact_force_threshold, p.slip_threshold)
        return Truth(
            pose=np.array([q[0], q[1], 0.0]),
            twist=np.array([v[0], v[1], 0.0]),
            joints=np.zeros(0),
            pusher_wrench=np.zeros(3),
            modes=modes[None, :],
            friction=np.array([p.mu_at(float(q[0]))]),
            normal_forces=np.array([fn]),
        )
