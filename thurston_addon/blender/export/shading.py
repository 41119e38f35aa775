"""A Blender material's node tree -> one Principled-style material of the scene model: the shader
reaching the Material Output's Surface is read by walking the links back from that output (never
an unconnected node), through reroutes, muted nodes and node groups. Diffuse, Glossy, Metallic,
Principled and Emission shaders, Mix Shader and Add Shader with constant factors become a weighted
blend of the parameters the tracer has (see docs/blender.md, "Shader nodes"); Image Textures on a
colour through a UV map, Generated or Object coordinates and a Mapping node become the material's
texture and a UV transform. Any other node feeding a colour (procedural textures, ColorRamp, an
Image Texture through other coordinates or projections) is baked by Cycles (bake.py) where the
object has a UV map. What the tracer cannot show is said, once per material, in a note naming the
material and what the image shows instead."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ... import scenes

# The Principled BSDF's inputs that become the material's scattering (scenes.Material's names).
SCATTERING_INPUTS = {"roughness": "Roughness", "metallic": "Metallic", "specular": "Specular IOR Level", "ior": "IOR"}
# Principled inputs the tracer does not model, with the value at which they change nothing, and
# what the image shows instead.
PRINCIPLED_UNMODELLED = (
    ("Transmission Weight", 0.0, "transmission: opaque, only the part Cycles does not transmit"),
    ("Alpha", 1.0, "alpha: opaque"),
    ("Coat Weight", 0.0, "coat: left out"),
    ("Sheen Weight", 0.0, "sheen: left out"),
    ("Subsurface Weight", 0.0, "subsurface scattering: diffuse"),
    ("Anisotropic", 0.0, "anisotropy: isotropic"),
    ("Thin Film Thickness", 0.0, "thin film: left out"),
)
# Shaders the tracer cannot show: what the image shows where they are.
UNSUPPORTED_SHADERS = {
    "BSDF_GLASS": "only its reflection is shown (no transmission)",
    "BSDF_REFRACTION": "black is shown (no refraction)",
    "BSDF_TRANSPARENT": "black is shown (nothing is seen through)",
    "BSDF_TRANSLUCENT": "black is shown (no translucency)",
    "HOLDOUT": "black is shown (no holdout)",
    "SUBSURFACE_SCATTERING": "a diffuse surface of its colour is shown",
    "BSDF_SHEEN": "black is shown (no sheen)",
    "BSDF_TOON": "a diffuse surface of its colour is shown",
    "BSDF_HAIR": "a diffuse surface of its colour is shown (no hair scattering)",
    "BSDF_HAIR_PRINCIPLED": "a diffuse surface of the hair's colour is shown (no hair scattering)",
    "BSDF_RAY_PORTAL": "black is shown (no ray portal)",
    "EEVEE_SPECULAR": "a diffuse surface of its base colour is shown",
}


@dataclass
class Texture:
    """An Image Texture on a colour (or a baked colour): its image, the coordinates it reads (None:
    the active render UV map; a UV map's name; "GENERATED" or "OBJECT") and the affine map (2x4: of
    (x, y, z, 1) to the xy the image is read at; UVs have z = 0) that Mapping nodes apply."""

    image: object
    source: str | None = None
    affine: np.ndarray = field(default_factory=lambda: np.eye(2, 4))
    pixels: np.ndarray | None = None  # a baked colour's linear pixels (then image is None)
    loop_uvs: np.ndarray | None = None  # the UVs it was baked on per mesh corner, where not a UV map's

    @property
    def key(self) -> int:
        """What tells textures apart: the image, or the baked pixels."""
        return id(self.image if self.image is not None else self.pixels)

    def same_coordinates(self, other: Texture) -> bool:
        return self.source == other.source and np.allclose(self.affine, other.affine)


@dataclass
class Lobe:
    """One shader's share of the surface: its weight (the mix factors' product) and its
    Principled-style parameters; reflects False for a shader that only emits."""

    weight: float
    reflects: bool = True
    color: np.ndarray = field(default_factory=lambda: np.zeros(3))
    color_texture: Texture | None = None
    metallic: float = 0.0
    roughness: float = 0.5
    specular: float = 0.0
    ior: float = 1.5
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    emission_texture: Texture | None = None


@dataclass
class Surface:
    """What the export makes of a material: scenes.Material's arguments, the textures (for their
    coordinates) and the notes."""

    color: np.ndarray
    emission: np.ndarray
    color_texture: Texture | None = None
    emission_texture: Texture | None = None
    scattering: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def texture(self) -> Texture | None:
        """The texture whose coordinates the material's triangles get (the base colour's first)."""
        return self.color_texture or self.emission_texture


class Walk:
    """Reads one material's tree from its output, gathering notes."""

    def __init__(self, mat, bake=None):
        self.mat = mat
        self.bake = bake  # bake.Baker bound to this material's slot (socket -> pixels, UV map), or None
        self.notes: list[str] = []

    def note(self, text: str):
        if text not in self.notes:
            self.notes.append(text)

    # --- following links --------------------------------------------------------------------------
    def source(self, socket, groups=()):
        """(node, output socket, groups) feeding an input socket, through reroutes, muted nodes and
        node groups (groups: the group nodes entered); where nothing does (or a muted link),
        (None, the socket whose own value counts, groups)."""
        for _ in range(256):
            if not socket.is_linked:
                break
            link = socket.links[0]
            if link.is_muted or not link.is_valid:
                break
            node, out = link.from_node, link.from_socket
            if node.type == "REROUTE":
                socket = node.inputs[0]
                continue
            if node.mute:
                through = [lk.from_socket for lk in node.internal_links if lk.to_socket == out]
                if not through:
                    break
                socket = through[0]
                continue
            if node.type == "GROUP" and node.node_tree is not None:
                output = next(
                    (n for n in node.node_tree.nodes if n.type == "GROUP_OUTPUT" and n.is_active_output), None
                )
                inner = output and next((s for s in output.inputs if s.identifier == out.identifier), None)
                if inner is None:
                    break
                socket, groups = inner, (*groups, node)
                continue
            if node.type == "GROUP_INPUT" and groups:
                outer = next((s for s in groups[-1].inputs if s.identifier == out.identifier), None)
                if outer is None:
                    break
                socket, groups = outer, groups[:-1]
                continue
            return node, out, groups
        return None, socket, groups

    def linked(self, socket, groups):
        """Whether a socket is fed by a node (through reroutes, muted nodes and groups)."""
        return self.source(socket, groups)[0] is not None

    def value(self, socket, groups, what: str) -> float:
        """A float input: its constant, or a Value node's; other links: the socket's own value, noted."""
        node, out, _ = self.source(socket, groups)
        if node is None or node.type == "VALUE":
            return float(out.default_value)
        self.note(f"{what} comes from a {_kind(node)}: its own value {socket.default_value:.3g} is used")
        return float(socket.default_value)

    def color(self, socket, groups, what: str) -> tuple[np.ndarray, Texture | None]:
        """A colour input: (constant, None), or (white, texture) for an Image Texture's colour read
        flat through coordinates the tracer has, or for a colour Cycles bakes (any other node);
        where it cannot bake: the socket's own value, noted."""
        node, out, inner = self.source(socket, groups)
        if node is None or node.type == "RGB":
            return np.array(out.default_value[:3], float), None
        if node.type == "TEX_IMAGE" and out.name == "Color":
            if node.image is None:  # Cycles: an Image Texture without an image is black
                return np.zeros(3), None
            texture = Texture(node.image)
            unread = self.coordinates(node, inner, texture)
            if node.projection != "FLAT":
                unread.append(f"{_named(node)} uses {node.projection.title()} projection: projected flat")
            if node.extension != "REPEAT":
                unread.append(f"{_named(node)} has {node.extension.title()} extension: repeated")
            if not unread:
                return np.ones(3), texture
            baked, why = self.baked(socket, groups, what, _named(node))
            if baked is not None:
                return np.ones(3), baked
            for text in unread:
                self.note(text + (f" ({why.lstrip('; :')})" if why else ""))
            return np.ones(3), texture
        baked, why = self.baked(socket, groups, what, f"a {_kind(node)}")
        if baked is not None:
            return np.ones(3), baked
        own = np.array(socket.default_value[:3], float)
        self.note(
            f"{what} comes from a {_kind(node)} (procedural colours are not rendered{why}): "
            f"its own colour ({', '.join(f'{c:.3g}' for c in own)}) is shown"
        )
        return own, None

    def baked(self, socket, groups, what: str, source: str) -> tuple[Texture | None, str]:
        """The colour reaching `socket` as Cycles bakes it (bake.py), noted; (None, why not, as the
        note says it) where it cannot: no baker, the socket inside a node group, or what
        bake.Unavailable says."""
        from . import bake

        if self.bake is None:
            return None, ""
        if groups:
            return None, ": not baked inside a node group"
        try:
            baked = self.bake(socket)
        except bake.Unavailable as exc:
            return None, f"; not baked: {exc}"
        side = baked.pixels.shape[0]
        on = (
            f"UV map {baked.uv_map!r}"
            if baked.uv_map
            else "a Smart UV Project of a temporary copy (the object has no UV map)"
        )
        self.note(f"{what} comes from {source}: baked by Cycles to a {side}x{side} image on {on}")
        return Texture(None, pixels=baked.pixels, loop_uvs=baked.loop_uvs), ""

    def coordinates(self, tex_node, groups, texture: Texture) -> list[str]:
        """The coordinates an Image Texture reads: UV maps, Generated, Object, through Mapping nodes;
        returns what the tracer cannot read (as notes: what it reads instead)."""
        socket = tex_node.inputs["Vector"]
        unread = []
        affine = np.eye(4)
        while True:
            node, out, groups = self.source(socket, groups)
            if node is None:
                break
            if node.type == "MAPPING":
                affine = affine @ _mapping(node, groups, self)
                socket = node.inputs["Vector"]
                continue
            if node.type == "UVMAP":
                texture.source = node.uv_map or None
            elif node.type == "TEX_COORD" and out.name == "UV":
                pass
            elif node.type == "TEX_COORD" and out.name == "Generated":
                texture.source = "GENERATED"
            elif node.type == "TEX_COORD" and out.name == "Object" and node.object is None:
                texture.source = "OBJECT"
            else:
                what = f"{out.name} coordinates" if node.type == "TEX_COORD" else f"a {_kind(node)}"
                unread.append(f"{_named(tex_node)} reads {what}: the UV map is used")
            break
        texture.affine = affine[:2]
        return unread

    # --- shaders ------------------------------------------------------------------------------------
    def shader(self, socket, groups, weight: float, depth: int = 0) -> list[Lobe]:
        """The lobes of the shader feeding a shader socket, weighted."""
        node, _, groups = self.source(socket, groups)
        if node is None or weight <= 0 or depth > 64:
            return []
        t, inp = node.type, node.inputs
        if t == "MIX_SHADER":
            f = float(np.clip(self.value(inp[0], groups, f"the Factor of {_named(node)}"), 0, 1))
            return self.shader(inp[1], groups, weight * (1 - f), depth + 1) + self.shader(
                inp[2], groups, weight * f, depth + 1
            )
        if t == "ADD_SHADER":
            return self.shader(inp[0], groups, weight, depth + 1) + self.shader(inp[1], groups, weight, depth + 1)
        if t == "BSDF_PRINCIPLED":
            return [self.principled(node, groups, weight)]
        if t == "BSDF_DIFFUSE":
            color, texture = self.color(inp["Color"], groups, f"the Color of {_named(node)}")
            self.normal(node, groups)
            return [Lobe(weight, color=color, color_texture=texture, roughness=1.0)]
        if t in ("BSDF_GLOSSY", "BSDF_ANISOTROPIC"):
            color, texture = self.color(inp["Color"], groups, f"the Color of {_named(node)}")
            rough = self.value(inp["Roughness"], groups, f"the Roughness of {_named(node)}")
            self.normal(node, groups)
            if "Anisotropy" in inp and self.value(inp["Anisotropy"], groups, "anisotropy") != 0:
                self.note(f"{_named(node)} is anisotropic: rendered isotropic")
            return [Lobe(weight, color=color, color_texture=texture, metallic=1.0, roughness=_unit(rough))]
        if t == "BSDF_METALLIC":
            color, texture = self.color(inp["Base Color"], groups, f"the Base Color of {_named(node)}")
            rough = self.value(inp["Roughness"], groups, f"the Roughness of {_named(node)}")
            edge = np.array(inp["Edge Tint"].default_value[:3], float)
            if getattr(node, "fresnel_type", "F82") != "F82" or not np.allclose(edge, 1):
                self.note(f"the Edge Tint of {_named(node)} is not rendered: its edge reflects white")
            self.normal(node, groups)
            return [Lobe(weight, color=color, color_texture=texture, metallic=1.0, roughness=_unit(rough))]
        if t == "EMISSION":
            color, texture = self.color(inp["Color"], groups, f"the Color of {_named(node)}")
            strength = self.value(inp["Strength"], groups, f"the Strength of {_named(node)}")
            return [Lobe(weight, reflects=False, emission=color * strength, emission_texture=texture)]
        shows = UNSUPPORTED_SHADERS.get(t, "black is shown")
        self.note(f"{_named(node)} is not rendered by Thurston: {shows}")
        if t == "BSDF_GLASS":
            ior = self.value(inp["IOR"], groups, f"the IOR of {_named(node)}")
            rough = self.value(inp["Roughness"], groups, f"the Roughness of {_named(node)}")
            return [Lobe(weight, roughness=_unit(rough), specular=0.5, ior=max(ior, 1e-5))]
        if t == "BSDF_HAIR_PRINCIPLED":
            return [Lobe(weight, color=hair_colour(node), roughness=1.0)]
        if shows.startswith("a diffuse"):
            key = next((k for k in ("Color", "Base Color") if k in inp), None)
            color = np.array(inp[key].default_value[:3], float) if key else np.full(3, 0.8)
            return [Lobe(weight, color=color, roughness=1.0)]
        return [Lobe(weight)]  # black

    def normal(self, node, groups):
        for name in ("Normal", "Coat Normal"):
            if name in node.inputs and self.linked(node.inputs[name], groups):
                src = self.source(node.inputs[name], groups)[0]
                self.note(
                    f"the {_kind(src)} on the {name} of {_named(node)} is not rendered: the mesh's normals are used"
                )

    def principled(self, node, groups, weight) -> Lobe:
        inp, name = node.inputs, _named(node)
        color, texture = self.color(inp["Base Color"], groups, f"the Base Color of {name}")
        emission, emission_texture = np.zeros(3), None
        em = inp.get("Emission Color") or inp.get("Emission")
        if em is not None:
            emission, emission_texture = self.color(em, groups, f"the Emission Color of {name}")
            strength = inp.get("Emission Strength")
            emission = emission * (
                self.value(strength, groups, f"the Emission Strength of {name}") if strength else 1.0
            )
        scattering = {
            key: clamped(key, self.value(inp[socket], groups, f"the {socket} of {name}"))
            for key, socket in SCATTERING_INPUTS.items()
            if socket in inp
        }
        for socket, neutral, shows in PRINCIPLED_UNMODELLED:
            value = self.value(inp[socket], groups, f"the {socket} of {name}") if socket in inp else neutral
            if value != neutral:
                self.note(f"{name} has {shows}")
            if socket == "Transmission Weight":  # the share Cycles transmits is not seen: the rest is
                color = color * (1 - float(np.clip(value, 0, 1)))
        self.normal(node, groups)
        return Lobe(
            weight,
            color=color,
            color_texture=texture,
            emission=emission,
            emission_texture=emission_texture,
            **scattering,
        )

    # --- the material -------------------------------------------------------------------------------
    def surface(self, viewport_color) -> Surface:
        tree = self.mat.node_tree
        output = tree.get_output_node("CYCLES") if tree is not None else None
        if output is None:
            if tree is not None:
                self.note("it has no Material Output: its viewport colour is shown")
            return Surface(np.array(viewport_color[:3], float), np.zeros(3), notes=self.notes)
        for name in ("Volume", "Displacement"):
            if name in output.inputs and self.linked(output.inputs[name], ()):
                self.note(f"its {name.lower()} is not rendered (the surface alone is)")
        if not self.linked(output.inputs["Surface"], ()):
            return Surface(np.zeros(3), np.zeros(3), notes=self.notes)  # Cycles: black
        return self.blend(self.shader(output.inputs["Surface"], (), 1.0))

    def blend(self, lobes: list[Lobe]) -> Surface:
        """The lobes as one Principled material: emission adds; the base colour is the weighted sum
        of the reflecting lobes' colours, metallic their weighted mean, the specular layer (level,
        IOR, roughness) the weighted mean of theirs (see docs/blender.md for what is exact)."""
        emission = sum((lobe.weight * lobe.emission for lobe in lobes), np.zeros(3))
        reflecting = [lobe for lobe in lobes if lobe.reflects]
        W = sum(lobe.weight for lobe in reflecting)
        color = sum((lobe.weight * lobe.color for lobe in reflecting), np.zeros(3))
        color_texture = self.one_texture([lobe.color_texture for lobe in reflecting if lobe.weight > 0], "colour")
        emission_texture = self.one_texture([lobe.emission_texture for lobe in lobes if lobe.weight > 0], "emission")
        if (
            color_texture is not None
            and emission_texture is not None
            and not color_texture.same_coordinates(emission_texture)
        ):
            self.note("its colour and emission textures read different coordinates: the colour's are used for both")
        scattering = {}
        if W > 0:
            w = np.array([lobe.weight for lobe in reflecting]) / W
            glossy = np.array([lobe.weight * (lobe.metallic + lobe.specular) for lobe in reflecting])
            scattering["metallic"] = float(w @ [lobe.metallic for lobe in reflecting])
            scattering["specular"] = float(w @ [lobe.specular for lobe in reflecting])
            layered = np.array([lobe.weight * lobe.specular for lobe in reflecting])
            if layered.sum() > 0:
                scattering["ior"] = float(layered @ [lobe.ior for lobe in reflecting] / layered.sum())
            if glossy.sum() > 0:
                scattering["roughness"] = float(glossy @ [lobe.roughness for lobe in reflecting] / glossy.sum())
            elif len(reflecting) == 1:
                scattering["roughness"] = reflecting[0].roughness
        return Surface(color, emission, color_texture, emission_texture, scattering, self.notes)

    def one_texture(self, textures, what) -> Texture | None:
        found = [t for t in textures if t is not None]
        if len({t.key for t in found}) > 1:
            shown = "the baked colour" if found[0].image is None else repr(found[0].image.name)
            self.note(f"it mixes {len(found)} {what} textures: only {shown} is shown")
        return found[0] if found else None


# Cycles' Principled Hair BSDF (kernel/closure/bsdf_principled_hair_*.h): the absorption of
# eumelanin and pheomelanin per unit concentration, and the polynomial in the radial roughness
# relating absorption and the hair's colour (Chiang et al. 2016): colour = exp(-sqrt(sigma) poly)
EUMELANIN, PHEOMELANIN = np.array([0.506, 0.841, 1.653]), np.array([0.343, 0.733, 1.924])
HAIR_ROUGHNESS_POLY = (0.245, 5.574, -10.73, 2.532, -0.215, 5.969)  # highest power first


def hair_colour(node) -> np.ndarray:
    """The colour of a Principled Hair BSDF as Cycles parametrizes it (its own values): Direct
    Coloring's Color; Melanin's and Absorption's absorption turned into the colour that absorption
    gives (the inverse of Cycles' colour to absorption)."""
    inp = node.inputs
    if node.parametrization == "COLOR":
        return np.array(inp["Color"].default_value[:3], float)
    poly = np.polyval(HAIR_ROUGHNESS_POLY, inp["Radial Roughness"].default_value)
    if node.parametrization == "ABSORPTION":
        sigma = np.array(inp["Absorption Coefficient"].default_value[:3], float)
    else:
        quantity = -np.log(max(1.0 - inp["Melanin"].default_value, 1e-4))
        redness = inp["Melanin Redness"].default_value
        sigma = quantity * ((1 - redness) * EUMELANIN + redness * PHEOMELANIN)
        tint = np.clip(np.array(inp["Tint"].default_value[:3], float), 1e-6, None)
        sigma = sigma + (np.log(tint) / poly) ** 2
    return np.exp(-np.sqrt(np.maximum(sigma, 0.0)) * poly)


def clamped(key: str, value: float) -> float:
    """A scattering input as Cycles takes it: roughness and metallic within [0, 1], the specular
    level at least 0, the IOR at least 1e-5 (below 1 it reflects as its inverse does)."""
    ((low, high),) = [bounds for name, bounds, _ in scenes.SCATTERING if name == key]
    return float(np.clip(value, max(low, 1e-5) if key == "ior" else low, high))


def _kind(node) -> str:
    """A node as a note names it: its type's name, and its own name where that differs."""
    label = node.bl_label if hasattr(node, "bl_label") else node.type
    return f"{label} node {node.name!r}" if node.name != label else f"{label} node"


def _named(node) -> str:
    """'the Diffuse BSDF', or 'the Diffuse BSDF 'Mine'' where its name is its own."""
    label = node.bl_label if hasattr(node, "bl_label") else node.type
    return f"the {label}" if node.name == label else f"the {label} {node.name!r}"


def _unit(value: float) -> float:
    return float(np.clip(value, 0.0, 1.0))


def _mapping(node, groups, walk) -> np.ndarray:
    """A Mapping node's map of coordinates as a 4x4 affine map."""
    from mathutils import Euler

    vector_type = node.vector_type
    loc = np.array(node.inputs["Location"].default_value[:], float) if "Location" in node.inputs else np.zeros(3)
    rot = np.array(node.inputs["Rotation"].default_value[:], float)
    scale = np.array(node.inputs["Scale"].default_value[:], float)
    for name in ("Location", "Rotation", "Scale"):
        if name in node.inputs and walk.linked(node.inputs[name], groups):
            walk.note(f"the {name} of {_named(node)} comes from a node: its own value is used")
    R = np.array(Euler(rot.tolist(), "XYZ").to_matrix(), float)
    M = np.eye(4)
    if vector_type == "TEXTURE":  # the inverse of POINT's
        with np.errstate(divide="ignore", invalid="ignore"):
            S_inv = np.diag(np.where(scale != 0, 1 / np.where(scale != 0, scale, 1), 0))
        M[:3, :3] = S_inv @ R.T
        M[:3, 3] = -M[:3, :3] @ loc
    else:
        M[:3, :3] = R @ np.diag(scale)
        if vector_type == "POINT":
            M[:3, 3] = loc
    return M


def surface(mat, viewport_color, bake=None) -> Surface:
    """The material's surface, read from its Material Output (see the module's docstring); `bake`
    bakes colours of one object's slot (bake.Baker with the material and slot), None: noted."""
    return Walk(mat, bake).surface(viewport_color)


def warn_notes(mat, notes: list[str]):
    """One note (a warning, which the render report gathers) naming the material and what its image
    shows instead."""
    if notes:
        warnings.warn(f"material {mat.name!r}: {'; '.join(notes)}", stacklevel=3)
