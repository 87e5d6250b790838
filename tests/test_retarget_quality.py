"""How well HumanML3D's walk lands on every rig the tests know (bench/retarget_quality.py; the
table in docs/generation.md, "How well it lands"): ankles on the rig's own floor where ours stand,
no more sliding than ours scaled by the legs, bones pointing as ours (feet and head of a
character standing at rest: turning from its rest as ours turn from theirs, so toes stand on the
floor too and X Bot's head is not tipped), hips at the rig's height."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bench.retarget_quality import XBOT, landing, our_clip, rigs
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.joint_map import joint_map_for
from m2d2m.motion.rigs.retarget import OUR_REST_AIMS, Rig, read_rig, retarget

RIGS = rigs()
# A known gap, measured in the bench's table: Biped hangs its thighs from its first spine joint,
# which points where our spine1 → spine2 points, so its hip line follows our spine's bend (8.8°
# from ours, median) and its ankles stray further in stance than on the other rigs.
HIPS_ON_THE_SPINE = {"3ds max biped"}


@pytest.fixture(scope="module")
def ours():
    return our_clip()


@pytest.mark.parametrize(("name", "rig", "joint_map"), RIGS, ids=[name for name, _, _ in RIGS])
def test_our_walk_lands_on_the_rig(name, rig, joint_map, ours):
    row = landing(ours, rig, joint_map)
    ankles_max = 3.5 if name in HIPS_ON_THE_SPINE else 3.0  # cm: ours stray 1.8 in stance, 2.4 scaled to the rigs
    assert abs(row.ankles[0]) < 1.0 and row.ankles[1] < ankles_max  # cm from where its rest pose stands them
    if row.toes is not None:  # cm; ours stray 3.4 in stance, more on a longer, steeper foot (X Bot's)
        assert abs(row.toes[0]) < 2.0 and row.toes[1] < 6.0
    assert row.slide < 1.2 * row.our_slide + 1.0  # cm/s in stance
    assert row.bone_max < 1e-3 and (row.from_rest_max or 0.0) < 1e-3  # None: aimed as ours (CMU's)
    assert row.hips == pytest.approx(row.our_hips, abs=0.05)


@pytest.mark.parametrize("name", sorted(HIPS_ON_THE_SPINE))
def test_the_known_gaps_are_still_there(name, ours):
    """Each known gap is measured, so that whoever closes it moves its rig into the test above."""
    _, rig, joint_map = next(found for found in RIGS if found[0] == name)
    assert landing(ours, rig, joint_map).ankles[1] > 3.0


def _lean(bones: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """Degrees each bone (..., 3) leans ahead of upright, along ``forward`` (..., 3)."""
    return np.degrees(np.arctan2(np.sum(bones * forward, axis=-1), bones[..., 1]))


def test_x_bots_head_leans_as_its_rest_plus_our_change(ours):
    """X Bot's neck→head stands 10° ahead of upright at rest, HumanML3D's 62°: on it, our head
    leans its rest's lean plus our change, instead of ours (which tipped it 52° further ahead)."""
    clip = read_rig(XBOT)
    rig = Rig.from_bvh(clip)
    neck, head = (rig.names.index(f"mixamorig:{name}") for name in ("Neck", "Head"))
    moved = retarget(ours, rig, joint_map_for(clip)).positions()
    across = ours[:, 1] - ours[:, 2]  # left hip minus right: forward is left × up
    forward = np.cross(across, [0.0, 1.0, 0.0])
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    rest = rig.rest_positions()
    rest_lean = _lean(rest[head] - rest[neck], np.array([0.0, 0.0, 1.0]))
    our_rest = _lean(np.array(OUR_REST_AIMS["neck", "head"]), np.array([0.0, 0.0, 1.0]))
    assert rest_lean == pytest.approx(10.0, abs=1.0) and our_rest == pytest.approx(62.0)
    theirs = _lean(moved[:, head] - moved[:, neck], forward)
    expected = rest_lean + _lean(ours[:, 15] - ours[:, 12], forward) - our_rest
    assert np.median(np.abs(theirs - expected)) < 3.0


def test_only_a_character_standing_at_rest_turns_its_feet_and_head_from_its_rest(ours):
    """Mixamo's names on the synthetic T-pose (toes on the floor, head up) turn feet and head from
    rest; the same rig hanging from its root (a BVH's rest pose) and one whose toes rest level with
    its ankles, above the floor, and whose head joint lies straight ahead of its neck (our own
    skeleton's rest, as `m2d2m export` writes it) aim them as ours, so ours goes back unchanged."""
    name, standing, joint_map = RIGS[0]
    assert name == "mixamo"
    feet_and_head = {T2M.joint_names.index(joint) for joint in ("left_foot", "right_foot", "head")}
    assert retarget(ours, standing, joint_map).from_rest == feet_and_head
    hanging = replace(standing, offsets=standing.offsets - np.eye(len(standing.names), 1).dot([[0.0, 1.5, 0.0]]))
    assert retarget(ours, hanging, joint_map).from_rest == set()
    offsets = standing.offsets.copy()
    for toe in ("mixamorig:LeftToeBase", "mixamorig:RightToeBase"):
        offsets[standing.names.index(toe), 1] = 0.0  # level with the ankle
    head = standing.names.index("mixamorig:Head")
    offsets[head] = [0.0, 0.0, np.linalg.norm(offsets[head])]  # straight ahead of the neck
    assert retarget(ours, replace(standing, offsets=offsets), joint_map).from_rest == set()
