"""Gripper scenario: the triangle rattles between the closing jaws, then is grasped."""

from __future__ import annotations

import numpy as np

from sim_publisher.bullet import SEPARATED, SLIDING_NEG, SLIDING_POS, STICKING
from sim_publisher.gripper import GripperSimulation
from sim_publisher.records import SimRun


def _vertices(run: SimRun, pose: np.ndarray) -> np.ndarray:
    """(N, V, 2) world vertices for poses (N, 3)."""
    verts = np.asarray(run.params.vertices)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    x = pose[:, None, 0] + c[:, None] * verts[:, 0] - s[:, None] * verts[:, 1]
    y = pose[:, None, 1] + s[:, None] * verts[:, 0] + c[:, None] * verts[:, 1]
    return np.stack([x, y], axis=-1)


def test_contact_names_are_vertices_times_jaws(gripper_sim: GripperSimulation) -> None:
    assert gripper_sim.contacts == (
        "v0_lower",
        "v1_lower",
        "v2_lower",
        "v0_upper",
        "v1_upper",
        "v2_upper",
    )
    assert gripper_sim.scenario().contacts == gripper_sim.contacts


def test_gripper_ends_grasped_by_both_jaws(gripper_run: SimRun) -> None:
    arr = gripper_run.stack()
    mode = np.argmax(arr["modes"], axis=2)  # (N, C)
    last = mode[-20:]
    lower, upper = last[:, :3], last[:, 3:]
    assert np.all(np.any(lower != SEPARATED, axis=1))
    assert np.all(np.any(upper != SEPARATED, axis=1))
    # secure: every contact that touches sticks, the body is at rest
    assert np.all((last == SEPARATED) | (last == STICKING))
    assert np.ptp(arr["pose"][-20:, 2]) < 1e-3  # no turning
    assert np.ptp(arr["pose"][-20:, 0]) < 1e-4  # no slip along the jaws
    # the jaws stalled on the object, squeezing it: gap = the triangle's height
    gap = arr["joints"][-1, 1] - arr["joints"][-1, 0]
    side = abs(gripper_run.params.vertices[1][0] - gripper_run.params.vertices[0][0])
    assert abs(gap - np.sqrt(3.0) / 2.0 * side) < 5e-4


def test_gripper_rattles_with_sliding_sticking_vertex_and_edge_contacts(
    gripper_run: SimRun, gripper_sim: GripperSimulation
) -> None:
    arr = gripper_run.stack()
    mode = np.argmax(arr["modes"], axis=2)
    grasp = np.flatnonzero(
        np.any(mode[:, :3] != SEPARATED, axis=1) & np.any(mode[:, 3:] != SEPARATED, axis=1)
    )
    assert len(grasp) > 0
    before = mode[: grasp[0]]
    assert np.any((before == SLIDING_POS) | (before == SLIDING_NEG))
    assert np.any(before == STICKING)
    # vertex contacts (one vertex on a jaw) and edge contacts (two) both occur
    n_lower = np.count_nonzero(before[:, :3] != SEPARATED, axis=1)
    assert np.any(n_lower == 1) and np.any(n_lower == 2)
    # both jaws were touched before the grasp (rattling between them)
    assert np.any(before[:, 3:] != SEPARATED)
    assert gripper_sim.unmatched_contacts == 0


def test_gripper_modes_agree_with_geometry(gripper_run: SimRun) -> None:
    arr = gripper_run.stack()
    mode = np.argmax(arr["modes"], axis=2)
    v = _vertices(gripper_run, arr["pose"])  # (N, 3, 2)
    lower, upper = arr["joints"][:, 0], arr["joints"][:, 1]
    gap_lower = v[:, :, 1] - lower[:, None]
    gap_upper = upper[:, None] - v[:, :, 1]
    gaps = np.concatenate([gap_lower, gap_upper], axis=1)  # (N, 6) in contact order
    touching = mode != SEPARATED
    assert np.max(np.abs(gaps[touching])) < 1e-4
    assert np.min(gaps) > -5e-4  # no vertex deep inside a jaw (one-step transients only)
    # sliding direction: vertex x displacement along the jaw tangent (lower +x, upper -x)
    tangent = np.array([1.0] * 3 + [-1.0] * 3)
    dxt = np.concatenate([v[1:, :, 0] - v[:-1, :, 0]] * 2, axis=1) * tangent
    both_pos = (mode[1:] == SLIDING_POS) & (mode[:-1] == SLIDING_POS)
    both_neg = (mode[1:] == SLIDING_NEG) & (mode[:-1] == SLIDING_NEG)
    assert np.count_nonzero(both_pos) + np.count_nonzero(both_neg) > 10
    assert np.all(dxt[both_pos] > 0.0) and np.all(dxt[both_neg] < 0.0)
