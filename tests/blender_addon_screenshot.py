"""Blender's window with the add-on's panel open after a Generate, saved as a PNG: the picture in
docs/generation.md ("In Blender"). Blender draws with OpenGL, so it needs a display; on a machine
without one, Xvfb's, and xdotool to turn the sidebar to the add-on's tab (Debian: apt-get install
xvfb xdotool):

    xvfb-run -s "-screen 0 1600x900x24" blender --factory-startup --window-geometry 0 0 1600 900 \\
        --python tests/blender_addon_screenshot.py -- dist/m2d2m_blender.zip http://127.0.0.1:8000 docs/blender-panel.png

with `m2d2m serve` running at the address given. The person is tests/blender_addon_session.py's."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_addon_session import BUILT, built_armature, install  # noqa: E402

ADDON, SERVER, PICTURE = sys.argv[sys.argv.index("--") + 1 :]
ACTIONS = (("a person walks forward", 2.0), ("a person jumps", 1.0), ("a person waves", 1.5))


def view_3d() -> tuple[bpy.types.Window, bpy.types.Area]:
    window = bpy.context.window_manager.windows[0]
    views = [area for area in window.screen.areas if area.type == "VIEW_3D"]
    return window, max(views, key=lambda area: area.width * area.height)


def generate() -> float:
    """The scene as a person would leave it after one Generate, the sidebar on the add-on's tab."""
    for thing in list(bpy.data.objects):
        bpy.data.objects.remove(thing)
    install(ADDON)
    scene = bpy.context.scene
    scene.render.fps = 24
    armature = built_armature("Person", BUILT)
    armature.select_set(True)
    settings = scene.m2d2m
    settings.server = SERVER
    bpy.ops.m2d2m.refresh()
    for text, seconds in ACTIONS:
        settings.actions.add()
        settings.actions[-1].text, settings.actions[-1].seconds = text, seconds
    bpy.ops.m2d2m.generate()
    scene.frame_set(60)
    settings.edit_text = "a person kicks"
    window = bpy.context.window_manager.windows[0]
    window.workspace = bpy.data.workspaces["Animation"]  # its dope sheet shows the keys and markers
    return 1.0


def frame_the_person() -> float:
    for bone in bpy.context.view_layer.objects.active.data.bones:  # the dope sheet lists the selected bones' keys
        bone.select = True
    window, area = view_3d()
    for sheet in window.screen.areas:
        if sheet.type == "DOPESHEET_EDITOR":
            sheet.spaces.active.show_region_ui = False
    space = area.spaces.active
    space.show_region_ui = True
    space.region_3d.view_location = (0.0, 0.0, 0.9)  # the person's middle, whole in view
    space.region_3d.view_distance = 3.2
    area.tag_redraw()
    return 2.0


def xdotool(*arguments: object) -> None:
    subprocess.run(["xdotool", *map(str, arguments)], check=True)


def close_splash() -> float:
    xdotool("key", "Escape")
    return 1.0


def to_the_tab() -> float:
    """The sidebar on the add-on's tab, as a person gets there: the pointer over the sidebar's tabs
    and Ctrl + wheel down past Item, Tool, View and Animation (Blender 3.4 has no Python for a sidebar's tab)."""
    window, area = view_3d()
    sidebar = next(region for region in area.regions if region.type == "UI")
    x, y = sidebar.x + sidebar.width - 8, window.height - (sidebar.y + sidebar.height) + 30
    xdotool("mousemove", x, y)
    for _ in range(4):
        xdotool("keydown", "ctrl", "click", "5", "keyup", "ctrl")
    return 1.0


def shoot() -> None:
    window, _ = view_3d()
    with bpy.context.temp_override(window=window):
        bpy.ops.screen.screenshot(filepath=str(Path(PICTURE).resolve()))
    bpy.ops.wm.quit_blender()


STEPS = [generate, frame_the_person, close_splash, to_the_tab, shoot]


def step() -> float | None:
    return STEPS.pop(0)() if STEPS else None


bpy.app.timers.register(step, first_interval=2.0)
