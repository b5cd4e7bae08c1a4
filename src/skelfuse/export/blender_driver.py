"""Run INSIDE Blender's Python (the ``bpy`` wheel's own virtual environment), never imported by skelfuse.

bpy pins numpy < 2 and Python 3.11, so it cannot share our environment: :mod:`skelfuse.export.blender` runs
this file as a script with that environment's interpreter, ``python blender_driver.py REQUEST.json
RESULT.json``. Only the standard library and bpy are used here.

Commands (``request["command"]``):

- ``sample``: import a BVH (``bvh``, ``scale``) or an FBX (``fbx``, ``fps``) and write, for each sampled
  frame index (0 = the file's first frame), every pose bone's head in world coordinates (Blender units,
  metres with the scales skelfuse passes).
- ``bvh_to_fbx``: import a BVH and export its armature and animation with Blender's own FBX exporter
  (baked, every frame keyed, no curve simplification, no leaf bones).
"""

import json
import sys
from typing import Any

import bpy

FIRST_FRAME = 1  # where Blender's importers put a file's first frame


def _empty_scene() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _set_fps(fps: float) -> None:
    scene = bpy.context.scene
    scene.render.fps = max(1, round(fps))
    scene.render.fps_base = scene.render.fps / fps


def _import_bvh(path: str, scale: float) -> None:
    bpy.ops.import_anim.bvh(
        filepath=path,
        global_scale=scale,
        frame_start=FIRST_FRAME,
        use_fps_scale=False,
        update_scene_fps=True,
        update_scene_duration=True,
        rotate_mode="NATIVE",
        axis_forward="-Z",
        axis_up="Y",
    )


def _armature():
    armatures = [obj for obj in bpy.context.scene.objects if obj.type == "ARMATURE"]
    if len(armatures) != 1:
        raise SystemExit(f"expected one armature after the import, found {len(armatures)}")
    return armatures[0]


def _keyed_range(obj) -> tuple:
    if not (obj.animation_data and obj.animation_data.action):
        raise SystemExit("the imported armature carries no animation")
    return tuple(obj.animation_data.action.frame_range)


def _keys_from_frame_zero(obj) -> None:
    """Move the keys so the first is on frame 0: the FBX exporter writes frame F at time F / fps, and importers
    put time 0 on their first frame (Blender's on frame 1, where it puts a BVH's first frame); left on frame 1
    (where the BVH importer puts it, whatever frame_start says) every FBX reader starts one frame late."""
    first = obj.animation_data.action.frame_range[0]
    for curve in obj.animation_data.action.fcurves:
        for key in curve.keyframe_points:
            key.co.x -= first
            key.handle_left.x -= first
            key.handle_right.x -= first


def _sample(frames: list) -> dict:
    obj = _armature()
    scene = bpy.context.scene
    keyed = _keyed_range(obj)
    first = round(keyed[0])  # the FBX importer offsets the keys (anim_offset); the file's frame 0 is the first key
    heads: dict[str, list[Any]] = {bone.name: [] for bone in obj.pose.bones}
    for index in frames:
        scene.frame_set(first + int(index))
        for bone in obj.pose.bones:
            heads[bone.name].append(list(obj.matrix_world @ bone.head))
    return {
        "heads": heads,
        "frame_range": list(keyed) if keyed is not None else None,
        "fps": scene.render.fps / scene.render.fps_base,
        "blender": bpy.app.version_string,
    }


def main() -> None:
    with open(sys.argv[1], encoding="utf-8") as f:
        request = json.load(f)
    command = request["command"]
    _empty_scene()
    if command == "sample":
        if "bvh" in request:
            _import_bvh(request["bvh"], request["scale"])
        else:
            _set_fps(request["fps"])
            bpy.ops.import_scene.fbx(
                filepath=request["fbx"], automatic_bone_orientation=False, ignore_leaf_bones=False, use_anim=True
            )
        result = _sample(request["frames"])
    elif command == "bvh_to_fbx":
        _import_bvh(request["bvh"], request["scale"])
        _keys_from_frame_zero(_armature())
        scene = bpy.context.scene
        start, end = _keyed_range(_armature())
        scene.frame_start, scene.frame_end = round(start), round(end)  # the importer never shortens the scene
        bpy.ops.export_scene.fbx(
            filepath=request["fbx"],
            object_types={"ARMATURE"},
            add_leaf_bones=False,
            bake_anim=True,
            bake_anim_use_all_bones=True,
            bake_anim_use_nla_strips=False,
            bake_anim_use_all_actions=False,
            bake_anim_force_startend_keying=True,
            bake_anim_step=1.0,
            bake_anim_simplify_factor=0.0,
            axis_forward="-Z",
            axis_up="Y",
        )
        result = {"frames": scene.frame_end - scene.frame_start + 1, "blender": bpy.app.version_string}
    else:
        raise SystemExit(f"unknown command {command!r}")
    with open(sys.argv[2], "w", encoding="utf-8") as f:
        json.dump(result, f)


if __name__ == "__main__":
    main()
