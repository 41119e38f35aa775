"""Renders into Blender: float image datablocks (kept in the .blend: packed when the file is saved)
and the World's panorama background."""

import bpy

from . import export

IMAGE_TAG = "thurston_image"  # on the images this add-on made (reused; a user's image is left alone)


def store_image(name: str, passes: dict):
    """Write a render's colour and alpha into a linear float image datablock. Only an image this
    add-on created is reused; a user's image with the same name is left alone (a new name is taken)."""
    color = passes["color"]
    h, w = color.shape[:2]
    image = next((im for im in bpy.data.images if im.get(IMAGE_TAG) == name), None)
    if image is None:
        image = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
        image[IMAGE_TAG] = name
        image.use_fake_user = True  # kept in the .blend while no editor shows it
        image.alpha_mode = "PREMUL"  # the colour is premultiplied by the alpha
    elif tuple(image.size) != (w, h):
        image.scale(w, h)
    image.colorspace_settings.name = "Linear Rec.709" if "Linear Rec.709" in _colorspaces(image) else "Linear"
    image.pixels.foreach_set(export.combined(passes)[::-1].ravel())  # Blender's rows are bottom-up
    image.update()
    return image


def _colorspaces(image):
    return {item.identifier for item in image.colorspace_settings.bl_rna.properties["name"].enum_items}


def show_image(context, image):
    screen = getattr(context, "screen", None)
    for area in screen.areas if screen else []:
        if area.type == "IMAGE_EDITOR":
            area.spaces.active.image = image
            area.tag_redraw()


def set_world_panorama(bscene, image):
    """Environment Texture with the panorama in the World's node tree. Nodes are created only if
    missing; the user's other nodes stay."""
    world = bscene.world
    if world is None:
        world = bpy.data.worlds.new("World")
        bscene.world = world
    if bpy.app.version < (5, 0, 0):  # Blender 5 always uses world nodes
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    output = next((n for n in nodes if n.type == "OUTPUT_WORLD" and n.is_active_output), None) or next(
        (n for n in nodes if n.type == "OUTPUT_WORLD"), None
    )
    if output is None:
        output = nodes.new("ShaderNodeOutputWorld")
    surface = output.inputs["Surface"]
    background = surface.links[0].from_node if surface.is_linked else None
    if background is None or background.type != "BACKGROUND":
        background = next((n for n in nodes if n.type == "BACKGROUND"), None) or nodes.new("ShaderNodeBackground")
        links.new(background.outputs["Background"], surface)
    env = nodes.get("Thurston Panorama")
    if env is None:
        env = nodes.new("ShaderNodeTexEnvironment")
        env.name = env.label = "Thurston Panorama"
        env.location = (background.location.x - 300, background.location.y)
    env.image = image
    links.new(env.outputs["Color"], background.inputs["Color"])
    return env


@bpy.app.handlers.persistent
def pack_images(*_):
    """Before a save: pack the add-on's images whose pixels the file does not hold yet (never packed,
    or rendered again since), so that the reopened file shows them and its World's panorama still
    works (they have no file of their own). An image packed and unchanged is left alone: Blender's
    pack() on it unpacks it (5.0), and a file saved twice would reopen without it."""
    for image in bpy.data.images:
        if image.get(IMAGE_TAG) and image.has_data and (image.packed_file is None or image.is_dirty):
            image.pack()


def register():
    bpy.app.handlers.save_pre.append(pack_images)


def unregister():
    bpy.app.handlers.save_pre.remove(pack_images)
