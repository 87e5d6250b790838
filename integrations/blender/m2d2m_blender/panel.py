"""The panel in the 3D view's sidebar (N, tab "m2d2m") and the settings it shows, kept on the scene
(saved with the file): the server, model and method, the actions with their seconds (or one
sentence), seed, root and feet, Generate, and the edits at the playhead."""

from __future__ import annotations

from typing import Any

import bpy

from . import catalog
from .client import DEFAULT_SERVER
from .operators import scene_fps

ROOTS = [
    ("keep", "Keep its path", "the root travels as generated"),
    ("in-place", "In place", "the root's path taken out: the body moves on the spot"),
    ("ground", "Grounded", "the path kept, the lowest foot on the floor in every frame"),
]


class M2D2MAction(bpy.types.PropertyGroup):
    """One action of the list: its sentence and seconds."""

    text: bpy.props.StringProperty(
        name="Text", description="the action in one sentence", default="a person walks forward"
    )
    seconds: bpy.props.FloatProperty(
        name="Seconds", description="its length; 0: the model's typical length for it", default=2.0, min=0.0, max=600.0
    )


class M2D2MSettings(bpy.types.PropertyGroup):
    server: bpy.props.StringProperty(name="Server", description="m2d2m serve's address", default=DEFAULT_SERVER)
    token: bpy.props.StringProperty(
        name="Token",
        description="the server's token, for a server on another host (m2d2m serve --token)",
        subtype="PASSWORD",
    )
    model: bpy.props.EnumProperty(name="Model", items=catalog.model_items)
    method: bpy.props.EnumProperty(name="Method", items=catalog.method_items)
    actions: bpy.props.CollectionProperty(type=M2D2MAction)
    active_action: bpy.props.IntProperty(default=0)
    prompt: bpy.props.StringProperty(
        name="Sentence", description="with no action listed: one sentence the server splits by its verbs"
    )
    prompt_seconds: bpy.props.FloatProperty(
        name="Seconds", description="the sentence's length; 0: each action's typical length", default=0.0, min=0.0
    )
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)
    root: bpy.props.EnumProperty(name="Root", items=ROOTS, default="keep")
    plant_feet: bpy.props.BoolProperty(
        name="Plant feet", description="keep the feet from sliding where they touch down", default=True
    )
    edit_text: bpy.props.StringProperty(
        name="Text", description="Regenerate: the action's new text (blank: its own); Fill to here: what happens"
    )
    edit_seed: bpy.props.IntProperty(
        name="Seed", description="the edit's draw (moves on after each edit)", default=1, min=0
    )


class M2D2M_UL_actions(bpy.types.UIList):
    def draw_item(
        self, context: Any, layout: Any, data: Any, item: Any, icon: int, active_data: Any, active_property: str
    ) -> None:
        split = layout.split(factor=0.7, align=True)
        split.prop(item, "text", text="")
        split.prop(item, "seconds", text="")


class M2D2M_PT_panel(bpy.types.Panel):
    bl_label = "m2d2m"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "m2d2m"

    def draw(self, context: bpy.types.Context) -> None:
        settings, layout = context.scene.m2d2m, self.layout
        row = layout.row(align=True)
        row.prop(settings, "server")
        row.operator("m2d2m.refresh", text="", icon="FILE_REFRESH")
        layout.prop(settings, "model")
        layout.prop(settings, "method")
        layout.label(text="Actions")
        row = layout.row()
        row.template_list("M2D2M_UL_actions", "", settings, "actions", settings, "active_action", rows=3)
        buttons = row.column(align=True)
        buttons.operator("m2d2m.action_add", text="", icon="ADD")
        buttons.operator("m2d2m.action_remove", text="", icon="REMOVE")
        if not settings.actions:
            row = layout.row(align=True)
            row.prop(settings, "prompt")
            row.prop(settings, "prompt_seconds", text="s")
        layout.prop(settings, "seed")
        layout.label(text=f"Frame rate: {scene_fps(context.scene):g} fps (the scene's)")
        layout.prop(settings, "root")
        layout.prop(settings, "plant_feet")
        layout.operator("m2d2m.generate", icon="ARMATURE_DATA")
        box = layout.box()
        box.label(text="Edit at the playhead")
        box.prop(settings, "edit_text")
        box.prop(settings, "edit_seed")
        row = box.row(align=True)
        row.operator("m2d2m.regenerate")
        row.operator("m2d2m.fill")


CLASSES = (M2D2MAction, M2D2MSettings, M2D2M_UL_actions, M2D2M_PT_panel)
