"""Run inside Blender (``blender --background --python tests/blender_addon_session.py -- ARGS``) by
tests/test_blender_addon.py: install the add-on's zip as a person would, put an armature in the scene
(one built here, standing on the floor, or a BVH imported with Blender's importer), drive the panel's
operators against a running server, and write what Blender then holds as JSON: the actions, their
keys and records, the markers, every bone's head per frame and each refusal's one line.

Arguments: the add-on's zip, the server's address, the output folder, and ``built`` or a BVH's path."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import addon_utils
import bpy

FPS = 24  # not the model's 20: the clip must come at the scene's rate

# A person 1.7 m tall in Blender's axes (Z up, facing -Y), named as Blender's Rigify metarig names
# its bones, feet on z = 0: (name, parent, head, tail)
BUILT = [
    ("spine", None, (0, 0, 0.95), (0, 0, 1.05)),
    ("spine.001", "spine", (0, 0, 1.05), (0, 0, 1.2)),
    ("spine.002", "spine.001", (0, 0, 1.2), (0, 0, 1.35)),
    ("spine.003", "spine.002", (0, 0, 1.35), (0, 0, 1.45)),
    ("spine.004", "spine.003", (0, 0, 1.45), (0, 0, 1.55)),
    ("spine.005", "spine.004", (0, 0, 1.55), (0, 0, 1.6)),
    ("spine.006", "spine.005", (0, 0, 1.6), (0, 0, 1.75)),
    *[
        bone
        for side, x in (("L", 1), ("R", -1))
        for bone in (
            (f"thigh.{side}", "spine", (0.1 * x, 0, 0.95), (0.1 * x, 0, 0.52)),
            (f"shin.{side}", f"thigh.{side}", (0.1 * x, 0, 0.52), (0.1 * x, 0.02, 0.09)),
            (f"foot.{side}", f"shin.{side}", (0.1 * x, 0.02, 0.09), (0.1 * x, -0.12, 0.02)),
            (f"toe.{side}", f"foot.{side}", (0.1 * x, -0.12, 0.02), (0.1 * x, -0.18, 0.02)),
            (f"shoulder.{side}", "spine.003", (0.03 * x, -0.02, 1.42), (0.17 * x, 0, 1.42)),
            (f"upper_arm.{side}", f"shoulder.{side}", (0.18 * x, 0, 1.42), (0.45 * x, 0, 1.42)),
            (f"forearm.{side}", f"upper_arm.{side}", (0.45 * x, 0, 1.42), (0.7 * x, 0, 1.42)),
            (f"hand.{side}", f"forearm.{side}", (0.7 * x, 0, 1.42), (0.8 * x, 0, 1.42)),
        )
    ],
]


def install(addon: str) -> None:
    """The zip installed and enabled as Preferences > Add-ons > Install… does it."""
    bpy.ops.preferences.addon_install(filepath=addon, overwrite=True)
    addon_utils.modules_refresh()
    bpy.ops.preferences.addon_enable(module="m2d2m_blender")
    assert hasattr(bpy.types.Scene, "m2d2m"), "the add-on did not register"


def built_armature(name: str, bones: list) -> bpy.types.Object:
    armature = bpy.data.objects.new(name, bpy.data.armatures.new(name))
    bpy.context.scene.collection.objects.link(armature)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    for bone_name, parent, head, tail in bones:
        bone = armature.data.edit_bones.new(bone_name)
        bone.head, bone.tail = head, tail
        if parent is not None:
            bone.parent = armature.data.edit_bones[parent]
    bpy.ops.object.mode_set(mode="OBJECT")
    return armature


def scene_armature(source: str) -> bpy.types.Object:
    """The person built here (``built``; it had an action of its own) or the BVH at ``source``."""
    if source == "built":
        armature = built_armature("Person", BUILT)
        previous = bpy.data.actions.new("hand-made")  # the action the user had: it must stay
        armature.animation_data_create().action = previous
        armature.pose.bones["spine"].keyframe_insert("location", frame=1)
        return armature
    import io_anim_bvh.import_bvh as importer

    # Blender 3.4's BVH importer opens its file in mode "rU", which Python 3.11 removed (Debian
    # builds it with a newer Python than Blender's own): the same read, without the dropped "U"
    importer.open = lambda path, mode="r", *args, **kwargs: open(path, mode.replace("U", ""), *args, **kwargs)
    bpy.ops.import_anim.bvh(filepath=source, update_scene_fps=False, update_scene_duration=False)
    return next(o for o in bpy.data.objects if o.type == "ARMATURE")


def operator(name: str) -> str:
    """Run ``bpy.ops.m2d2m.<name>`` as a button does (an undo step after it): "" when it
    finished, else the one line it reported."""
    try:
        result = getattr(bpy.ops.m2d2m, name)("EXEC_DEFAULT", True)
    except RuntimeError as error:  # an operator's ERROR report reaches a script as this
        return str(error).strip()
    return "" if result == {"FINISHED"} else f"{name}: {result}"


def heads(armature: bpy.types.Object, first: int, end: int) -> list[dict[str, list[float]]]:
    """Every pose bone's head, armature space, at each scene frame from ``first`` to ``end``."""
    frames = []
    for frame in range(first, end):
        bpy.context.scene.frame_set(frame)
        frames.append({bone.name: list(bone.head) for bone in armature.pose.bones})
    return frames


def state(armature: bpy.types.Object) -> dict:
    from m2d2m_blender.armature import record_of

    scene = bpy.context.scene
    action = armature.animation_data.action
    record = record_of(action)
    end = record["start"] + record["frames"] if record else scene.frame_end + 1
    return {
        "action": action.name,
        "actions": {a.name: {"fake_user": a.use_fake_user, "range": list(a.frame_range)} for a in bpy.data.actions},
        "record": record,
        "keys": {f"{c.data_path}[{c.array_index}]": len(c.keyframe_points) for c in action.fcurves},
        "markers": sorted([marker.name, marker.frame] for marker in scene.timeline_markers),
        "frame_range": [scene.frame_start, scene.frame_end],
        "heads": heads(armature, scene.frame_start, end),
    }


def main() -> None:
    addon, server, out, source = sys.argv[sys.argv.index("--") + 1 :]
    out_dir = Path(out)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    install(addon)
    from m2d2m_blender.armature import record_of, rig_of
    from m2d2m_blender.bvh import rest_bvh

    scene = bpy.context.scene
    scene.render.fps, scene.frame_start = FPS, 1
    armature = scene_armature(source)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.ed.undo_push(message="the armature")
    rig = rig_of(armature)
    (out_dir / "rig.bvh").write_text(rest_bvh(rig.bones))
    settings = scene.m2d2m
    settings.server = server
    report = {"bone_of": rig.bone_of, "refusals": {}}
    report["refusals"]["refresh"] = operator("refresh")
    settings.model = "m2d2m"
    for text, seconds in (("a person walks forward", 2.0), ("a person jumps", 1.0), ("a person waves", 1.5)):
        settings.actions.add()
        settings.actions[-1].text, settings.actions[-1].seconds = text, seconds
    report["refusals"]["generate"] = operator("generate")
    report["generated"] = state(armature)

    scene.frame_set(report["generated"]["record"]["start"] + report["generated"]["record"]["actions"][1]["first"] + 2)
    settings.edit_text = "a person kicks"
    report["refusals"]["regenerate"] = operator("regenerate")
    report["regenerated"] = state(armature)

    end = report["regenerated"]["record"]["start"] + report["regenerated"]["record"]["frames"]
    scene.frame_set(end + FPS - 1)  # one second past the clip's last frame
    settings.edit_text = "a person sits down"
    report["refusals"]["fill"] = operator("fill")
    report["filled"] = state(armature)

    name = armature.name
    bpy.ops.ed.undo()  # Blender's own undo takes the fill back, markers too
    armature, scene = bpy.data.objects[name], bpy.context.scene  # undo made them anew
    settings = scene.m2d2m
    report["undone"] = {
        "record": record_of(armature.animation_data.action),
        "markers": sorted([marker.name, marker.frame] for marker in scene.timeline_markers),
    }

    scene.frame_set(end + 10 * FPS)
    settings.edit_text = ""
    report["refusals"]["fill_without_text"] = operator("fill")
    scene.frame_set(scene.frame_start - 1)
    report["refusals"]["regenerate_nowhere"] = operator("regenerate")

    settings.actions[0].text = "a person zorbles forward"
    report["refusals"]["unknown_words"] = operator("generate")
    settings.actions[0].text = "a person walks forward"

    from m2d2m_blender.catalog import method_items

    report["methods"] = [identifier for identifier, _, _ in method_items(settings)]
    settings.actions.clear()  # no action listed: one sentence, split by the server
    settings.prompt, settings.prompt_seconds, settings.method = (
        "a person walks forward and then jumps",
        4.0,
        "independent",
    )
    report["refusals"]["prompt"] = operator("generate")
    report["prompted"] = record_of(armature.animation_data.action)

    stump = built_armature("Stump", [("root", None, (0, 0, 0), (0, 0, 0.5)), ("tip", "root", (0, 0, 0.5), (0, 0, 1))])
    bpy.context.view_layer.objects.active = stump
    report["refusals"]["unmappable"] = operator("generate")
    bpy.context.view_layer.objects.active = armature
    settings.server = "http://127.0.0.1:9"  # nothing listens there
    before = (armature.animation_data.action.name, len(bpy.data.actions), len(scene.timeline_markers))
    report["refusals"]["no_server"] = operator("generate")
    after = (armature.animation_data.action.name, len(bpy.data.actions), len(scene.timeline_markers))
    report["refused_changes_nothing"] = before == after
    (out_dir / "session.json").write_text(json.dumps(report))


if __name__ == "__main__":  # as Blender runs a --python script
    main()
