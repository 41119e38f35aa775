"""What Blender renders and Thurston does not: motion blur, non-square pixels, stereoscopy,
the World's light. Each is said in the render's notes, naming what the image shows instead."""

from __future__ import annotations

import numpy as np

from ... import checks

IGNORED = "ignored"  # a render setting the image does not follow (the message says what it shows)

MOTION_BLUR_NOTE = "Motion Blur is not rendered: each frame shows the scene sharp, as it is at the frame"

# The factory World's grey (0.0509, strength 1) is Blender's default, not a choice to light with:
# a World brighter than this is noted.
WORLD_LEAST = 0.06


def _linked_node(socket):
    while socket.is_linked and not socket.links[0].is_muted:
        node = socket.links[0].from_node
        if node.type != "REROUTE":
            return node
        socket = node.inputs[0]
    return None


def world_light(world) -> str | None:
    """How the World lights the scene in Cycles, where it does more than Blender's default grey:
    its Background's colour times strength (a constant), or the node giving them; None where it
    is black (or as dim as the default), or where its colour is the add-on's own panorama."""
    if world is None:
        return None
    import bpy

    # (Blender 5 always uses the World's nodes, and warns that use_nodes goes)
    tree = world.node_tree if bpy.app.version >= (5, 0, 0) or world.use_nodes else None
    if tree is None:  # (Blender 4: a World without nodes lights with its colour)
        colour = np.array(world.color[:3], float)
        return f"colour {_rgb(colour)}" if checks.LUMINANCE @ colour > WORLD_LEAST else None
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_WORLD"]
    output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    node = None if output is None else _linked_node(output.inputs["Surface"])
    if node is None:
        return None
    if node.type != "BACKGROUND":
        return f"node {node.name!r}"
    strength, colour = (_linked_node(node.inputs[k]) for k in ("Strength", "Color"))
    if strength is not None:
        return f"node {strength.name!r} as its strength"
    if colour is not None:
        if colour.name == "Thurston Panorama":  # Bake Panorama's: this render's own view
            return None
        return f"node {colour.name!r} as its colour"
    value = np.array(node.inputs["Color"].default_value[:3], float) * node.inputs["Strength"].default_value
    return f"colour {_rgb(value)}" if checks.LUMINANCE @ value > WORLD_LEAST else None


def _rgb(c) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in c) + ")"


def settings_notes(bscene) -> list[checks.Note]:
    """Notes on the scene's render settings that the image does not follow."""
    r = bscene.render
    notes = []
    if r.use_motion_blur:
        notes.append(checks.Note(IGNORED, MOTION_BLUR_NOTE))
    if r.pixel_aspect_x != r.pixel_aspect_y:
        notes.append(
            checks.Note(
                IGNORED,
                f"Pixel Aspect {r.pixel_aspect_x:g}:{r.pixel_aspect_y:g} is not rendered: the image has "
                "square pixels, the camera's view fitted to the resolution as at aspect 1:1",
            )
        )
    world = world_light(bscene.world)
    if world is not None:
        notes.append(
            checks.Note(
                IGNORED,
                f"World {bscene.world.name!r} ({world}) lights nothing here and is not shown behind: "
                "only lights and emissive surfaces light the scene, and where rays hit nothing the image "
                "is black (Bake Panorama puts Thurston's view in the World, for Cycles and the viewport)",
            )
        )
    return notes
