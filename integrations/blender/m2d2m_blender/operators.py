"""The add-on's operators: fetch the server's models, add and remove actions, Generate, and the
two edits at the playhead ("Regenerate this action", "Fill to here"). Each reports a refusal in
one line in Blender's status bar (``self.report({'ERROR'}, ...)``) and changes nothing then; each
change is one undo step."""

from __future__ import annotations

from typing import Any

import bpy

from . import catalog
from .armature import Rig, clip_spans, mark, new_action, record_of, rig_of, set_record, write_keys
from .bvh import BvhError, read_bvh, rest_bvh
from .client import Client, ServerError, generation_request
from .timeline import action_at, fill_seconds, replaced_frames


def settings_of(context: bpy.types.Context) -> Any:
    return context.scene.m2d2m


def scene_fps(scene: bpy.types.Scene) -> float:
    """The scene's frame rate (29.97 is 30 over 1.001), the rate the clip is asked at."""
    return scene.render.fps / scene.render.fps_base


def client_of(context: bpy.types.Context) -> Client:
    settings = settings_of(context)
    return Client(settings.server, settings.token)


def armature_of(context: bpy.types.Context) -> bpy.types.Object:
    armature = context.active_object
    if armature is None or armature.type != "ARMATURE":
        raise ValueError("select the armature to animate (it is the active object)")
    return armature


def send_rig(client: Client, armature: bpy.types.Object) -> tuple[Rig, str]:
    """The armature's rest pose uploaded as its rig: the rig's bones and the server's id for it."""
    rig = rig_of(armature)
    return rig, client.upload_rig(rest_bvh(rig.bones))["id"]


def progress_of(context: bpy.types.Context) -> Any:
    """The window manager's progress (the cursor's counter) for a call that samples."""
    manager = context.window_manager
    manager.progress_begin(0, 100)
    return lambda fraction: manager.progress_update(int(100 * fraction))


class Reporting:
    """An operator whose ``run`` may refuse in one sentence: reported as an error, nothing done."""

    def execute(self, context: bpy.types.Context) -> set[str]:
        try:
            return self.run(context)
        except (ServerError, BvhError, ValueError) as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        finally:
            context.window_manager.progress_end()

    def run(self, context: bpy.types.Context) -> set[str]:
        raise NotImplementedError


class M2D2M_OT_refresh(Reporting, bpy.types.Operator):
    """Fetch the server's models and their methods"""

    bl_idname = "m2d2m.refresh"
    bl_label = "Fetch models"

    def run(self, context: bpy.types.Context) -> set[str]:
        models = client_of(context).models()
        catalog.keep(models)
        settings = settings_of(context)
        if models and settings.model not in {model["name"] for model in models}:
            settings.model = models[0]["name"]
        self.report({"INFO"}, f"m2d2m: {len(models)} models on {client_of(context).server}")
        return {"FINISHED"}


class M2D2M_OT_action_add(bpy.types.Operator):
    """Add an action to the list"""

    bl_idname = "m2d2m.action_add"
    bl_label = "Add action"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        settings = settings_of(context)
        settings.actions.add()
        settings.active_action = len(settings.actions) - 1
        return {"FINISHED"}


class M2D2M_OT_action_remove(bpy.types.Operator):
    """Remove the chosen action from the list"""

    bl_idname = "m2d2m.action_remove"
    bl_label = "Remove action"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        settings = settings_of(context)
        if 0 <= settings.active_action < len(settings.actions):
            settings.actions.remove(settings.active_action)
            settings.active_action = min(settings.active_action, len(settings.actions) - 1)
        return {"FINISHED"}


class M2D2M_OT_generate(Reporting, bpy.types.Operator):
    """Generate the actions on the selected armature, as a new action at the scene's frame rate"""

    bl_idname = "m2d2m.generate"
    bl_label = "Generate"
    bl_options = {"REGISTER", "UNDO"}

    def run(self, context: bpy.types.Context) -> set[str]:
        settings, scene = settings_of(context), context.scene
        armature = armature_of(context)
        fps = scene_fps(scene)
        request = generation_request(
            settings.model,
            "" if settings.method == catalog.DEFAULT_METHOD else settings.method,
            [(item.text, item.seconds) for item in settings.actions],
            settings.prompt,
            settings.prompt_seconds,
            settings.seed,
            fps,
            settings.root,
            settings.plant_feet,
        )
        client = client_of(context)
        rig, rig_id = send_rig(client, armature)
        result = client.generate(request, progress_of(context))
        clip = read_bvh(client.bvh_on_rig(result["id"], rig_id))
        old = record_of(armature.animation_data.action if armature.animation_data else None)
        action = new_action(armature, "m2d2m: " + " / ".join(action["text"] for action in result["actions"]))
        start = scene.frame_start
        frames = write_keys(armature, action, clip, rig, start, range(len(clip.frames)))
        scene.frame_end = start + frames - 1
        record = {
            "server": client.server,
            "generation": result["id"],
            "model": result["model"],
            "seed": result["seed"],
            "fps": fps,
            "root": settings.root,
            "plant_feet": settings.plant_feet,
            "start": start,
            "frames": frames,
            "actions": result["actions"],
        }
        set_record(action, record)
        mark(scene, clip_spans(old) if old else [], clip_spans(record))
        said = f"m2d2m: {frames} frames at {fps:g} fps, {len(result['actions'])} actions on {armature.name}"
        self._tell(result, rig.left_out, said)
        return {"FINISHED"}

    def _tell(self, result: dict[str, Any], left_out: list[str], said: str) -> None:
        """The result in one line, with what the model did not know of the actions (its notices:
        words it never read) and the bones not keyed, as a warning."""
        notes = list(result.get("notices") or [])
        if left_out:
            notes.append(f"bones outside the rig's tree not keyed: {', '.join(left_out[:5])}")
        self.report({"WARNING"} if notes else {"INFO"}, "; ".join([said, *notes]))


class Editing(Reporting):
    """An edit of the clip on the active armature by the server that made it; the keys it gives anew
    replace the clip's there, every other key is kept."""

    bl_options = {"REGISTER", "UNDO"}

    def run(self, context: bpy.types.Context) -> set[str]:
        settings, scene = settings_of(context), context.scene
        armature = armature_of(context)
        action = armature.animation_data.action if armature.animation_data else None
        record = record_of(action)
        if record is None:
            raise ValueError(f"the armature's action is not an m2d2m clip; Generate one first ({armature.name})")
        request, replaced = self.plan(settings, scene, record)
        request.update(seed=settings.edit_seed, fps=record["fps"], root=record["root"], plant_feet=record["plant_feet"])
        client = Client(record["server"], settings.token)
        rig, rig_id = send_rig(client, armature)
        result = client.edit(record["generation"], request, progress_of(context))
        clip = read_bvh(client.bvh_on_rig(result["id"], rig_id))
        start, frames = record["start"], len(clip.frames)
        if frames < record["frames"]:
            raise ValueError("the edited clip came back shorter than the clip; generate it again")
        if frames != record["frames"]:  # longer: everything after the edit's start moved on
            replaced = range(replaced.start, start + frames)
        write_keys(armature, action, clip, rig, start, range(replaced.start - start, replaced.stop - start))
        scene.frame_end = max(scene.frame_end, start + frames - 1)
        old_spans = clip_spans(record)
        record.update(generation=result["id"], frames=frames, actions=result["actions"])
        set_record(action, record)
        mark(scene, old_spans, clip_spans(record))
        settings.edit_seed += 1  # the next click draws another
        self.report({"INFO"}, f"m2d2m: frames {replaced.start}-{replaced.stop - 1} keyed anew, the rest kept")
        return {"FINISHED"}

    def plan(self, settings: Any, scene: bpy.types.Scene, record: dict[str, Any]) -> tuple[dict[str, Any], range]:
        """The edit's request and the scene frames it gives anew."""
        raise NotImplementedError


class M2D2M_OT_regenerate(Editing, bpy.types.Operator):
    """Sample the action under the playhead again (the edit's text, else its own; the edit's seed), keeping the others"""

    bl_idname = "m2d2m.regenerate"
    bl_label = "Regenerate this action"

    def plan(self, settings: Any, scene: bpy.types.Scene, record: dict[str, Any]) -> tuple[dict[str, Any], range]:
        actions = clip_spans(record)
        index = action_at(actions, scene.frame_current)
        request: dict[str, Any] = {"operation": "regenerate", "action": index + 1}
        if settings.edit_text.strip():
            request["text"] = settings.edit_text.strip()
        start = record["start"]
        span = actions[index]
        return request, replaced_frames(span.first, span.end, record["fps"], start, start + record["frames"])


class M2D2M_OT_fill(Editing, bpy.types.Operator):
    """Continue the clip up to the playhead with the edit's text (the clip's last moments sampled again to join it)"""

    bl_idname = "m2d2m.fill"
    bl_label = "Fill to here"

    def plan(self, settings: Any, scene: bpy.types.Scene, record: dict[str, Any]) -> tuple[dict[str, Any], range]:
        end = record["start"] + record["frames"]
        seconds = fill_seconds(scene.frame_current, end, record["fps"])
        if not settings.edit_text.strip():
            raise ValueError("type what happens up to the playhead in the edit's text")
        request = {"operation": "continue", "actions": [{"text": settings.edit_text.strip(), "seconds": seconds}]}
        return request, replaced_frames(end, end, record["fps"], record["start"], end)


CLASSES = (
    M2D2M_OT_refresh,
    M2D2M_OT_action_add,
    M2D2M_OT_action_remove,
    M2D2M_OT_generate,
    M2D2M_OT_regenerate,
    M2D2M_OT_fill,
)
