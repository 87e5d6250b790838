"""m2d2m in Blender: type actions in a panel of the 3D view's sidebar, get the clip from `m2d2m
serve` on the selected armature as a new action, and edit it at the playhead (docs/generation.md,
"In Blender"). Python's standard library only; the modules that use ``bpy`` are imported when
Blender registers the add-on, so the rest is importable (and tested) outside Blender."""

bl_info = {
    "name": "m2d2m",
    "description": "Multi-action text to motion on the selected armature, from an m2d2m serve server",
    "author": "m2d2m",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "3D View > Sidebar (N) > m2d2m",
    "category": "Animation",
}


def register() -> None:
    import bpy

    from . import operators, panel

    for cls in (*operators.CLASSES, *panel.CLASSES):
        bpy.utils.register_class(cls)
    bpy.types.Scene.m2d2m = bpy.props.PointerProperty(type=panel.M2D2MSettings)


def unregister() -> None:
    import bpy

    from . import operators, panel

    del bpy.types.Scene.m2d2m
    for cls in reversed((*operators.CLASSES, *panel.CLASSES)):
        bpy.utils.unregister_class(cls)
