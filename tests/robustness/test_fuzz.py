"""Fuzz: a few hundred malformed inputs made from valid ones with a fixed seed (truncations, byte
flips, values of the wrong type, huge numbers, NaN, keys left out or added) through the loaders,
in-process: TOML scenes, TOML spaces (flat and curved: Nil, S2xR's shells), OBJ with MTL and its
texture, PLY, STL, glTF/GLB (embedded, and with external buffers and a texture image) and .npy
rays. Each either
loads validly (a scene or mesh file then compiles into a tracer, rays come back finite and inside
the domain) or raises the project's error type with a message naming the file; never another
exception. A scene or space file's message also never shows Python's or Qhull's own words."""

import base64
import io
import json
import random
import re
import struct
import warnings

import numpy as np
import pytest
import trimesh
from support.outputs import INTERNALS

from thurston_addon import cli, render, scenes, spaces

SEED = 20261211
TOML_VALUES = [
    "5",
    '"x"',
    "[1]",
    "{ a = 1 }",
    "true",
    "-1",
    "0",
    "1e300",
    "-1e300",
    "nan",
    "inf",
    "[[]]",
    '""',
    "[1, 2]",
    "[1e39, 0, 0]",
    "[nan, 0, 0]",
    "[1e200, 0, 0]",
    "1e-320",
    '"sqrt(-1)"',
    '"1/0"',
    '"2**9999"',
    "[-1, -1, -1]",
    "[0, 0, 0]",
    "3000000000",
    "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
]
MESH_TOKENS = ["nan", "inf", "1e39", "-1", "0", "1e400", "99999999999999999999", "x", "1/2/3", "-99999", "1e-320"]

SCENE = """\
[[object]]
primitive = "sphere"
center = [0.2, 0.1, 0.0]
radius = 0.1
subdivisions = 2
color = [0.9, 0.3, 0.2]

[[object]]
primitive = "box"
center = [-0.2, 0.0, 0.1]
size = [0.1, 0.2, 0.1]
emission = [0.5, 0.5, 0.5]
transforms = [[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], [[1, 0, 0, 0.1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]]

[[object]]
primitive = "torus"
radius = 0.15
tube = 0.03

[[light]]
position = [0.0, 0.0, 0.3]
power = 0.5
color = [1, 1, 1]

[[light]]
type = "spot"
position = [0.1, 0.0, 0.3]
direction = [0, 0, -1]
spot_size = 40
spot_blend = 0.2

[[light]]
type = "area"
position = [0.0, 0.2, 0.4]
direction = [0, 0, -1]
size = [0.1, 0.05]
shape = "disc"
emission = [2, 2, 2]

[camera]
position = [0.0, -0.3, 0.0]
forward = [0, 1, 0]
up = [0, 0, 1]
fov = 70
shift = [0.1, 0]
clip_start = 0.01
clip_end = 5
"""

OBJ = """\
mtllib m.mtl
o first
v 0.1 0.0 0.0
v 0.2 0.0 0.0
v 0.1 0.1 0.0
v 0.1 0.0 0.1
vt 0 0
vt 1 0
vt 0 1
vn 0 0 1
vn 0 1 0
usemtl red
f 1/1/1 2/2/1 3/3/1
usemtl glow
f 1//2 2//2 4//2
o second
v -0.1 0.0 0.0
v -0.2 0.0 0.0
v -0.1 -0.1 0.0 0.5
f -1 -2 -3
f 5 6 7 1
"""

MTL = """\
newmtl red
Kd 0.8 0.1 0.1
newmtl glow
Kd 0.2
Ke 1 1 0.5
"""


def mutate_text(rng: random.Random, text: str, toml: bool = True) -> bytes:
    """One of: truncation, a flipped byte, a line dropped or doubled; in TOML also a value
    replaced or a key added."""
    lines = text.splitlines()
    kind = rng.choice([0, 1, 2, 3, 4, 5] if toml else [0, 1, 3, 4])
    if kind == 0:
        return text.encode()[: rng.randrange(len(text))]
    if kind == 1:
        data = bytearray(text.encode())
        for _ in range(rng.randint(1, 3)):
            data[rng.randrange(len(data))] ^= rng.randint(1, 255)
        return bytes(data)
    i = rng.randrange(len(lines))
    if kind == 2:
        assigned = [k for k, line in enumerate(lines) if " = " in line]
        i = rng.choice(assigned)
        lines[i] = lines[i].split(" = ")[0] + " = " + rng.choice(TOML_VALUES)
    elif kind == 3:
        del lines[i]
    elif kind == 4:
        lines.insert(i, lines[i])
    else:
        tables = [k for k, line in enumerate(lines) if line.startswith("[")]
        lines.insert(
            rng.choice(tables) + 1, rng.choice(["bogus = 1", "colour = [1, 0, 0]", "radus = 0.1", "matrx = 1"])
        )
    return ("\n".join(lines) + "\n").encode()


def mutate_mesh_text(rng: random.Random, text: str) -> bytes:
    """Text meshes: the text mutations, or a number replaced by a bad token."""
    if rng.random() < 0.5:
        return mutate_text(rng, text, toml=False)
    tokens = text.split(" ")
    numbered = [k for k, t in enumerate(tokens) if re.fullmatch(r"-?[\d./]+\n?", t)]
    k = rng.choice(numbered)
    tokens[k] = rng.choice(MESH_TOKENS) + ("\n" if tokens[k].endswith("\n") else "")
    return " ".join(tokens).encode()


def mutate_bytes(rng: random.Random, data: bytes) -> bytes:
    """Binary files: truncation, flipped bytes, or 4 or 8 bytes overwritten with extreme values."""
    kind = rng.randrange(3)
    if kind == 0:
        return data[: rng.randrange(len(data))]
    out = bytearray(data)
    if kind == 1:
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(len(out))] ^= rng.randint(1, 255)
    else:
        value = rng.choice(
            [
                struct.pack("<I", 0xFFFFFFFF),
                struct.pack("<I", 0x7FFFFFFF),
                struct.pack("<f", float("nan")),
                struct.pack("<f", 3e38),
                struct.pack("<d", 1e300),
                struct.pack("<d", float("inf")),
            ]
        )
        at = rng.randrange(max(1, len(out) - len(value)))
        out[at : at + len(value)] = value
    return bytes(out)


def mutate_json(rng: random.Random, tree):
    """A glTF's JSON with one leaf replaced or one key dropped."""
    paths = []

    def walk(node, path):
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, value in items:
            paths.append(path + [key])
            walk(value, path + [key])

    walk(tree, [])
    path = rng.choice(paths)
    parent = tree
    for key in path[:-1]:
        parent = parent[key]
    if isinstance(parent, dict) and rng.random() < 0.3:
        del parent[path[-1]]
    else:
        parent[path[-1]] = rng.choice([-1, 0, 10**12, 2**31, 1.5, "x", None, [], {}, True, 5126, 5125, "data:,"])
    return tree


# --- the seeds -----------------------------------------------------------------------------------------------


def mesh_seeds():
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.1))
    box.apply_translation((0.2, 0, 0))
    out = {}
    for name, kwargs in (
        ("binary.ply", dict(encoding="binary")),
        ("ascii.ply", dict(encoding="ascii")),
        ("binary.stl", {}),
        ("ascii.stl", dict(file_type="stl_ascii")),
        ("mesh.glb", {}),
    ):
        data = box.export(file_type=kwargs.pop("file_type", name.split(".")[1]), **kwargs)
        out[name] = data.encode() if isinstance(data, str) else data
    gltf = trimesh.Scene([box]).export(file_type="gltf")  # {name: bytes}: the JSON and its buffer
    tree = json.loads(gltf["model.gltf"])
    for buffer in tree["buffers"]:  # embedded, so that the case is one file
        buffer["uri"] = "data:application/octet-stream;base64," + base64.b64encode(gltf[buffer["uri"]]).decode()
    out["mesh.gltf"] = json.dumps(tree).encode()
    return out


def texture_png() -> bytes:
    """A 4x4 PNG texture's bytes."""
    import tempfile
    from pathlib import Path

    from thurston_addon import images

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "t.png"
        images.write(path, {"color": np.full((4, 4, 3), 0.5, np.float32)})
        return path.read_bytes()


TEXTURED_OBJ = "mtllib t.mtl\nusemtl painted\nv 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
TEXTURED_MTL = "newmtl painted\nKd 1 1 1\nmap_Kd t.png\n"


def external_gltf() -> dict[str, bytes]:
    """A box as .gltf whose buffers are files beside it, and whose material's base colour is an
    image file beside it: {file name: bytes}."""
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.1))
    box.apply_translation((0.2, 0, 0))
    box.visual = trimesh.visual.TextureVisuals(uv=(box.vertices[:, :2] - box.vertices[:, :2].min(axis=0)) * 4)
    files = trimesh.Scene([box]).export(file_type="gltf")
    tree = json.loads(files.pop("model.gltf"))
    tree["images"] = [{"uri": "t.png"}]
    tree["textures"] = [{"source": 0}]
    tree["materials"] = [{"name": "painted", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    for mesh in tree["meshes"]:
        for primitive in mesh["primitives"]:
            primitive["material"] = 0
    return {"model.gltf": json.dumps(tree).encode(), "t.png": texture_png(), **files}


def npy_seed(rows) -> bytes:
    buf = io.BytesIO()
    np.save(buf, rows)
    return buf.getvalue()


VALID_RAYS = np.tile([0.01, 0.02, 0.03, 1.0, 0.3, 0.2], (20, 1))


def ray_cases(rng: random.Random, n: int):
    """(.npy bytes) of rays: byte-level mutations of a valid file and arrays of the wrong kind."""
    valid = VALID_RAYS
    arrays = [
        valid.astype(np.float32),
        valid.astype(np.int64),
        valid[:, :5],
        valid.ravel(),
        valid.reshape(2, 10, 6),
        valid.astype(np.complex128),
        np.asfortranarray(valid),
        np.zeros((0, 6)),
        valid.astype(">f8"),
    ]
    for value, at in (
        (np.nan, (3, 1)),
        (np.inf, (4, 4)),
        (1e200, (5, 0)),
        (1e300, (6, 3)),
        (0.0, (7, slice(3, 6))),
        (-1e308, (8, 2)),
        (5e-324, (9, 5)),
    ):
        a = valid.copy()
        a[at] = value
        arrays.append(a)
    out = [npy_seed(a) for a in arrays]
    while len(out) < n:
        out.append(mutate_bytes(rng, npy_seed(valid)))
    return out


def cases():
    """(name, {file name: bytes}, the file loaded, its kind) for every fuzz case, from SEED."""
    rng = random.Random(SEED)
    out = []
    for k in range(90):
        out.append((f"scene{k}", {"scene.toml": mutate_text(rng, SCENE)}, "scene.toml", "scene"))
    torus = (spaces.PRESET_DIR / "torus.toml").read_text()
    nil = (spaces.PRESET_DIR / "nil.toml").read_text()
    for k in range(60):
        out.append((f"space{k}", {"space.toml": mutate_text(rng, torus if k % 2 else nil)}, "space.toml", "space"))
    for k in range(50):
        files = {"m.obj": OBJ.encode(), "m.mtl": MTL.encode()}
        name = "m.obj" if k % 3 else "m.mtl"
        files[name] = mutate_mesh_text(rng, files[name].decode())
        out.append((f"obj{k}", files, "m.obj", "mesh"))
    for name, data in mesh_seeds().items():
        for k in range(20):
            text = name.startswith("ascii") and k % 2
            mutated = mutate_mesh_text(rng, data.decode()) if text else mutate_bytes(rng, data)
            if name == "mesh.gltf" and k % 2:
                mutated = json.dumps(mutate_json(rng, json.loads(data))).encode()
            out.append((f"{name}{k}", {name: mutated}, name, "mesh"))
    curved = [(spaces.PRESET_DIR / f"{name}.toml").read_text() for name in ("s2xs1", "rp3_rp3")]
    for k in range(24):
        out.append((f"curved{k}", {"space.toml": mutate_text(rng, curved[k % 2])}, "space.toml", "space"))
    textured = {"t.obj": TEXTURED_OBJ.encode(), "t.mtl": TEXTURED_MTL.encode(), "t.png": texture_png()}
    for k in range(20):  # the texture's bytes, or the library naming it
        files = dict(textured)
        files["t.png" if k % 2 else "t.mtl"] = (
            mutate_bytes(rng, files["t.png"]) if k % 2 else mutate_mesh_text(rng, TEXTURED_MTL)
        )
        out.append((f"texture{k}", files, "t.obj", "mesh"))
    external = external_gltf()
    for k in range(24):  # a buffer's bytes, the image's, or the JSON naming them
        files = dict(external)
        name = ("gltf_buffer_0.bin", "t.png", "model.gltf")[k % 3]
        files[name] = (
            json.dumps(mutate_json(rng, json.loads(files[name]))).encode()
            if name == "model.gltf"
            else mutate_bytes(rng, files[name])
        )
        out.append((f"external{k}", files, "model.gltf", "mesh"))
    for k, data in enumerate(ray_cases(rng, 40)):
        out.append((f"rays{k}", {"rays.npy": data}, "rays.npy", "rays"))
    return out


CASES = cases()


def test_the_fuzz_covers_a_few_hundred_cases():
    kinds = [kind for *_, kind in CASES]
    assert len(CASES) >= 300 and min(kinds.count(k) for k in ("scene", "space", "mesh", "rays")) >= 40


@pytest.fixture(scope="module")
def torus():
    return spaces.load("torus")


def test_the_unmutated_seeds_load_validly(tmp_path, torus):
    """What the fuzz mutates loads as it is (a loader refusing everything with the file's name
    would pass the fuzz): the scene file's objects, lights and camera, the OBJ's five triangles (a
    quad split in two), each mesh file's box of 12, the presets' spaces, the rays."""
    (tmp_path / "m.mtl").write_bytes(MTL.encode())
    seeds = {
        "scene.toml": SCENE.encode(),
        "m.obj": OBJ.encode(),
        "rays.npy": npy_seed(VALID_RAYS),
        "torus.toml": (spaces.PRESET_DIR / "torus.toml").read_bytes(),
        "nil.toml": (spaces.PRESET_DIR / "nil.toml").read_bytes(),
        **mesh_seeds(),
        **{name: data for name, data in external_gltf().items()},
        "t.obj": TEXTURED_OBJ.encode(),
        "t.mtl": TEXTURED_MTL.encode(),
    }
    loaded = ["scene.toml", "m.obj", "rays.npy", "torus.toml", "nil.toml", *mesh_seeds(), "model.gltf", "t.obj"]
    for name, data in seeds.items():
        (tmp_path / name).write_bytes(data)
    for name in loaded:
        kind = {"scene.toml": "scene", "rays.npy": "rays", "torus.toml": "space", "nil.toml": "space"}.get(name, "mesh")
        result = load(kind, tmp_path / name, torus)
        check_valid(kind, result, torus)
        if kind == "rays":  # inside the domain already: the rays as they are, directions made unit
            X, V = result
            np.testing.assert_allclose(X[:, :3] / X[:, 3:], VALID_RAYS[:, :3], rtol=1e-15)
            np.testing.assert_allclose(V[:, :3], VALID_RAYS[:, 3:] / np.linalg.norm(VALID_RAYS[0, 3:]), rtol=1e-15)
        elif kind == "mesh":
            triangles = render.make_tracer(torus, result, threads=1).num_triangles
            assert triangles == {"m.obj": 5, "t.obj": 1}.get(name, 12), (name, triangles)
            if name in ("t.obj", "model.gltf"):  # with its texture
                np.testing.assert_allclose(result.objects[0].materials[0].color_texture, 0.5, atol=0.01)
        elif kind == "scene":
            # three primitives and the area light's emitter; the point and the spot light; the camera
            assert len(result.objects) == 4 and len(result.lights) == 2 and result.camera.fov == 70


@pytest.mark.parametrize("start", range(0, len(CASES), 40))
def test_malformed_files_load_validly_or_are_one_clear_error(tmp_path, torus, start):
    """Forty cases per test (the whole fuzz stays within seconds)."""
    outcomes = {"valid": 0, "error": 0, "refused by the compiler": 0}
    for name, contents, loaded, kind in CASES[start : start + 40]:
        folder = tmp_path / name
        folder.mkdir()
        for file, data in contents.items():
            (folder / file).write_bytes(data)
        path = folder / loaded
        error = {
            "scene": scenes.SceneError,
            "mesh": scenes.SceneError,
            "space": spaces.SpaceError,
            "rays": cli.CommandError,
        }[kind]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                result = load(kind, path, torus)
            except error as exc:
                message = str(exc)
                assert any(file in message for file in contents), (name, message)
                if kind in ("scene", "space"):
                    assert not INTERNALS.search(message), (name, message)
                outcomes["error"] += 1
                continue
            check_valid(kind, result, torus)
            outcomes["valid"] += 1
            if kind in ("scene", "mesh"):  # what the loader accepts, the tracer takes, or refuses naming what
                try:
                    render.make_tracer(torus, result, threads=1)
                except (scenes.SceneError, render.RenderError) as exc:
                    assert re.match(r"(object '|light \d)", str(exc)), (name, str(exc))
                    outcomes["refused by the compiler"] += 1
    print(outcomes)


def load(kind, path, torus):
    """A scene, mesh or space file loaded, or rays read and moved into the torus's domain."""
    if kind in ("scene", "mesh"):
        return scenes.load_scene_file(path)
    if kind == "space":
        return spaces.load(path)
    return cli.read_rays(path, torus)


def check_valid(kind, result, torus):
    """What a load that succeeds gives: finite objects within float32's range; a space with a
    domain; rays moved into the torus's domain (its cube), their directions unit (E3: the chart's)."""
    if kind in ("scene", "mesh"):
        for obj in result.objects:
            assert np.all(np.isfinite(obj.vertices)) and np.all(np.abs(obj.vertices) <= scenes.FLOAT32_MAX)
            assert np.all(np.isfinite(obj.color)) and np.all(np.isfinite(obj.emission))
    elif kind == "space":
        assert result.volume > 0 and len(result.domain.faces) >= 2
    else:
        X, V = result
        assert np.all(np.isfinite(X)) and np.all(np.isfinite(V))
        assert torus.domain.contains(X, tol=1e-9).all() and np.all(np.abs(X[:, :3] / X[:, 3:]) <= 0.5 + 1e-9)
        np.testing.assert_allclose(np.linalg.norm(V[:, :3], axis=1), 1.0, rtol=1e-12)
