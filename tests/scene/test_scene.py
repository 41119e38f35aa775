"""Scene description: mesh files (OBJ, PLY, STL, GLB), TOML scene files, errors, the default scene,
and the object numbering seen end to end through the tracer's object pass."""

import math
import textwrap

import numpy as np
import pytest
import trimesh
from support.presets import presets
from trimesh.visual.material import PBRMaterial

from thurston_addon import render, spaces
from thurston_addon.scenes import (
    Camera,
    Scene,
    SceneError,
    default_scene,
    load_mesh_file,
    load_scene_file,
    load_scenes,
    primitive,
)


@pytest.fixture(scope="module")
def torus():
    return spaces.load("torus")


def write(path, text):
    path.write_text(textwrap.dedent(text).lstrip())
    return path


def box_at(centre, size=0.08):
    m = trimesh.creation.box(extents=[size] * 3)
    m.apply_translation(centre)
    return m


def trace_objects(space, scene, targets, origin=(0.0, 0.0, 0.0), max_distance=0.45):
    """Trace from `origin` towards each chart target (torus: straight lines); the distance limit
    keeps the rays inside the cube, so that a miss does not come round the torus."""
    g = space.geometry
    p = np.tile(np.asarray(origin, float), (len(targets), 1))
    X = g.to_model(p)
    D = g.normalize_tangent(X, g.tangent_to_model(p, np.asarray(targets, float) - p))
    out = render.make_tracer(space, scene).trace(X, D, max_distance, 20, shade=False)
    return out


# --- OBJ ---------------------------------------------------------------------------------------------
OBJ = """
    # two objects, materials from a library, a quad, negative indices
    mtllib colours.mtl
    o A
    v 0.1 -0.05 -0.05
    v 0.1 0.05 -0.05
    v 0.1 0.05 0.05
    v 0.1 -0.05 0.05
    usemtl red
    f 1 2 3 4
    o B
    v -0.1 -0.05 -0.05
    v -0.1 0.05 -0.05
    v -0.1 0.0 0.05
    usemtl glow
    f -3/1/1 -2/2/2 -1/3/3
"""
MTL = """
    newmtl red
    Kd 0.9 0.1 0.2
    newmtl glow
    Kd 0.1 0.2 0.3
    Ke 1.0 0.5 0.25
"""


def test_obj_objects_order_colours_quads_negative_indices(tmp_path, torus):
    write(tmp_path / "colours.mtl", MTL)
    path = write(tmp_path / "two.obj", OBJ)
    objs = load_mesh_file(path)
    assert [o.name for o in objs] == ["A", "B"]
    a, b = objs
    np.testing.assert_allclose(a.color, [0.9, 0.1, 0.2])
    np.testing.assert_allclose(a.emission, [0, 0, 0])
    np.testing.assert_allclose(b.color, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(b.emission, [1.0, 0.5, 0.25])
    # the quad is fanned into two triangles covering the square; B keeps its own three vertices
    assert a.triangles.shape == (2, 3) and len(a.vertices) == 4
    area = sum(0.5 * np.linalg.norm(np.cross(*(a.vertices[t[1:]] - a.vertices[t[0]]))) for t in a.triangles)
    assert area == pytest.approx(0.01)
    assert b.triangles.shape == (1, 3)
    np.testing.assert_allclose(
        np.sort(b.vertices[b.triangles[0]], axis=0),
        np.sort([[-0.1, -0.05, -0.05], [-0.1, 0.05, -0.05], [-0.1, 0.0, 0.05]], axis=0),
    )
    # end to end: the ray towards +x meets A (0), towards -x meets B (1), both at depth 0.1
    out = trace_objects(torus, Scene(objects=objs), [[1, 0.01, 0.0], [-1, 0.0, 0.0]])
    assert list(out["object"]) == [0, 1]
    np.testing.assert_allclose(out["depth"], [math.hypot(0.1, 0.001), 0.1], rtol=1e-6)


def test_obj_missing_mtl_warns_and_uses_default(tmp_path):
    path = write(
        tmp_path / "one.obj",
        """
        mtllib nowhere.mtl
        v 0 0 0
        v 1 0 0
        v 0 1 0
        usemtl x
        f 1 2 3
    """,
    )
    with pytest.warns(UserWarning, match="nowhere.mtl"):
        (obj,) = load_mesh_file(path)
    np.testing.assert_allclose(obj.color, [0.8, 0.8, 0.8])
    assert obj.name == "one"


# --- PLY, STL, GLB ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".ply", ".stl"])
def test_ply_stl(tmp_path, suffix, torus):
    mesh = box_at([0.0, 0.2, 0.0], 0.1)
    path = tmp_path / f"box{suffix}"
    mesh.export(path)
    (obj,) = load_mesh_file(path)
    assert len(obj.triangles) == 12
    np.testing.assert_allclose(obj.vertices.min(axis=0), [-0.05, 0.15, -0.05], atol=1e-6)
    np.testing.assert_allclose(obj.vertices.max(axis=0), [0.05, 0.25, 0.05], atol=1e-6)
    out = trace_objects(torus, Scene(objects=[obj]), [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    assert list(out["object"]) == [0, -1]
    assert out["depth"][0] == pytest.approx(0.15, abs=1e-6)


def glb_scene(tmp_path, names):
    sc = trimesh.Scene()
    for i, n in enumerate(names):
        m = box_at([0.0, 0.0, 0.1 + 0.15 * i])
        m.visual = trimesh.visual.TextureVisuals(
            material=PBRMaterial(baseColorFactor=[0.2 * (i + 1), 0.5, 0.9, 1.0], emissiveFactor=[0.0, 0.25 * i, 0.0])
        )
        sc.add_geometry(m, node_name=n, geom_name=n + "_mesh")
    path = tmp_path / "nodes.glb"
    sc.export(path)
    return path


def test_glb_nodes_materials(tmp_path):
    objs = load_mesh_file(glb_scene(tmp_path, ["first", "second"]))
    by_name = {o.name: o for o in objs}
    assert set(by_name) == {"first", "second"}
    # trimesh stores the factors as 8-bit colours
    np.testing.assert_allclose(by_name["first"].color, [0.2, 0.5, 0.9], atol=1 / 255)
    np.testing.assert_allclose(by_name["second"].color, [0.4, 0.5, 0.9], atol=1 / 255)
    np.testing.assert_allclose(by_name["second"].emission, [0.0, 0.25, 0.0], atol=1 / 255)
    np.testing.assert_allclose(by_name["second"].vertices.mean(axis=0), [0, 0, 0.25], atol=1e-6)


def test_glb_nodes_in_file_order(tmp_path):
    objs = load_mesh_file(glb_scene(tmp_path, ["zeta", "alpha", "mid"]))
    assert [o.name for o in objs] == ["zeta", "alpha", "mid"]


def test_objects_numbered_files_in_order_then_file_order(tmp_path, torus):
    """load_scenes: files in order, inside a file in its order; the tracer's object pass agrees."""
    write(tmp_path / "colours.mtl", MTL)
    obj_path = write(tmp_path / "two.obj", OBJ)  # A at x = +0.1, B at x = -0.1
    box_at([0.0, 0.2, 0.0], 0.1).export(tmp_path / "box.ply")  # C towards +y
    box_at([0.0, -0.3, 0.0], 0.1).export(tmp_path / "box2.stl")  # D towards -y
    scene = load_scenes([tmp_path / "box.ply", obj_path, tmp_path / "box2.stl"])
    assert [o.name for o in scene.objects] == ["box.ply", "A", "B", "box2.stl"]
    out = trace_objects(torus, scene, [[0, 1, 0], [1, 0.01, 0], [-1, 0, 0], [0, -1, 0]])
    assert list(out["object"]) == [0, 1, 2, 3]
    # and through render(): three pixels looking left, ahead, right at three objects in order
    for k, x in enumerate((-0.2, 0.0, 0.2)):
        box_at([x, 0.3, 0.0], 0.08).export(tmp_path / f"p{k}.stl")
    scene = load_scenes([tmp_path / f"p{k}.stl" for k in range(3)])
    # pixel j looks along (sx, 1, 0) with sx = (2 (j + 1/2) / 3 - 1) tan(fov / 2): -0.667, 0, 0.667 at fov 90
    cam = Camera(np.zeros(3), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), 90.0)
    res = render.render(torus, scene, render.Settings(width=3, height=1, quality="draft", shading="object"), camera=cam)
    assert res.passes["object"].tolist() == [[0, 1, 2]]


# --- TOML scene files ---------------------------------------------------------------------------------------
def test_toml_scene_files_primitives_lights_camera(tmp_path, monkeypatch, torus):
    (tmp_path / "meshes").mkdir()
    write(tmp_path / "meshes" / "colours.mtl", MTL)
    write(tmp_path / "meshes" / "two.obj", OBJ)
    path = write(
        tmp_path / "scene.toml",
        """
        [[object]]
        file = "meshes/two.obj"
        [[object]]
        primitive = "sphere"
        name = "ball"
        center = [0.0, 0.3, 0.0]
        radius = 0.1
        subdivisions = 4
        color = [0.1, 0.9, 0.1]
        emission = [0.5, 0.0, 0.0]
        [[object]]
        primitive = "box"
        center = [0.0, -0.3, 0.0]
        size = [0.1, 0.2, 0.3]
        [[object]]
        primitive = "torus"
        center = [0.0, 0.0, 0.3]
        radius = 0.1
        tube = 0.02
        [[light]]
        position = [0.0, 0.0, 0.2]
        color = [1.0, 0.5, 0.5]
        power = 2.5
        [camera]
        position = [0.1, 0.0, 0.0]
        forward = [1.0, 0.0, 0.0]
        up = [0.0, 1.0, 0.0]
        fov = 70
    """,
    )
    other = tmp_path / "elsewhere"
    other.mkdir()
    monkeypatch.chdir(other)  # relative paths resolve against the scene file, not the working directory
    scene = load_scene_file(path)
    assert [o.name for o in scene.objects] == ["A", "B", "ball", "box", "torus"]
    ball, box, ring = scene.objects[2:]
    np.testing.assert_allclose(np.linalg.norm(ball.vertices - [0, 0.3, 0], axis=1), 0.1, rtol=1e-9)
    np.testing.assert_allclose(ball.color, [0.1, 0.9, 0.1])
    np.testing.assert_allclose(ball.emission, [0.5, 0, 0])
    np.testing.assert_allclose(box.vertices.min(axis=0), [-0.05, -0.4, -0.15], atol=1e-12)
    np.testing.assert_allclose(box.vertices.max(axis=0), [0.05, -0.2, 0.15], atol=1e-12)
    rxy = np.hypot(ring.vertices[:, 0], ring.vertices[:, 1])
    assert rxy.min() == pytest.approx(0.08, abs=2e-3) and rxy.max() == pytest.approx(0.12, abs=1e-9)
    (light,) = scene.lights
    np.testing.assert_allclose(light.position, [0, 0, 0.2])
    np.testing.assert_allclose(light.color, [1, 0.5, 0.5])
    assert light.power == 2.5
    cam = scene.camera
    np.testing.assert_allclose(cam.position, [0.1, 0, 0])
    np.testing.assert_allclose(cam.forward, [1, 0, 0])
    np.testing.assert_allclose(cam.up, [0, 1, 0])
    assert cam.fov == 70
    # end to end: objects 0..4 along known rays (the ball at depth 0.2: its vertices are on the sphere)
    out = trace_objects(torus, scene, [[1, 0.01, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0.1, 0, 0.3]])
    assert list(out["object"]) == [0, 1, 2, 3, 4]
    assert 0.2 - 1e-9 <= out["depth"][2] < 0.2 + 2e-3
    assert out["depth"][3] == pytest.approx(0.2, abs=1e-6)
    # color override applies to every object of a file
    path2 = write(
        tmp_path / "tinted.toml",
        """
        [[object]]
        file = "meshes/two.obj"
        color = [0.3, 0.3, 0.3]
    """,
    )
    tinted = load_scene_file(path2)
    assert [o.name for o in tinted.objects] == ["A", "B"]
    for o in tinted.objects:
        np.testing.assert_allclose(o.color, [0.3, 0.3, 0.3])
    np.testing.assert_allclose(tinted.objects[1].emission, [1.0, 0.5, 0.25])


def test_primitive_direct():
    s = primitive({"primitive": "sphere", "radius": 0.2, "center": [0.1, 0, 0]}, "here")
    np.testing.assert_allclose(np.linalg.norm(s.vertices - [0.1, 0, 0], axis=1), 0.2, rtol=1e-9)
    with pytest.raises(SceneError, match="here.*cone"):
        primitive({"primitive": "cone"}, "here")


# --- errors -------------------------------------------------------------------------------------------------
def test_missing_file(tmp_path):
    missing = tmp_path / "nope.obj"
    with pytest.raises(SceneError, match="nope.obj"):
        load_mesh_file(missing)
    with pytest.raises(SceneError, match="nope.obj"):
        load_scenes([missing])
    with pytest.raises(SceneError, match="nope.toml"):
        load_scene_file(tmp_path / "nope.toml")
    path = write(
        tmp_path / "ref.toml",
        """
        [[object]]
        file = "gone.ply"
    """,
    )
    with pytest.raises(SceneError, match="gone.ply"):
        load_scene_file(path)


def test_unsupported_suffix(tmp_path):
    path = tmp_path / "model.fbx"
    path.write_text("whatever")
    with pytest.raises(SceneError, match=r"model\.fbx.*\.fbx"):
        load_mesh_file(path)


@pytest.mark.parametrize(
    "body, pattern",
    [
        ("v 0 0 0\nv nan 1 0\nv 0 1 0\nf 1 2 3\n", r"bad\.obj.*NaN"),
        ("v 0 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 9\n", r"bad\.obj.*vertex that does not exist"),
        ("v 0 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 0\n", r"bad\.obj.*vertex that does not exist"),
        ("v 0 0 0\nv 1 x 0\nv 0 1 0\nf 1 2 3\n", r"bad\.obj:2: cannot parse 'v': its values must be numbers"),
        ("v 0 0 0\nv 1 1 0\nv 0 1 0\nf 1 two 3\n", r"bad\.obj:4: cannot parse"),
        ("v 0 0 0\nv 1 1 0\n", r"bad\.obj.*no triangles"),
    ],
)
def test_bad_obj(tmp_path, body, pattern):
    path = tmp_path / "bad.obj"
    path.write_text(body)
    with pytest.raises(SceneError, match=pattern):
        load_mesh_file(path)


@pytest.mark.parametrize(
    "body, pattern",
    [
        ('[[object]]\nname = "x"\n', "object 0.*needs 'file' or 'primitive'"),
        ('[[object]]\nprimitive = "cone"\n', "object 0.*unknown primitive 'cone'"),
        ('[[object]]\nprimitive = "sphere"\ncenter = [0, 1]\n', "object 0.*center.*expected 3 numbers"),
        ('[[light]]\nposition = [0, "a", 0]\n', "light 0.*position"),
        ("[[light]]\nposition = [0, 0, inf]\n", "light 0.*not finite"),
        ("[camera]\nposition = [0, 0]\n", "camera.position"),
        ("[[object]\n", "cannot read scene file"),
        # values of the wrong type
        ('[[light]]\nposition = [0, 0, 0]\npower = "bright"\n', "light 0.*power"),
        ('[camera]\nfov = "wide"\n', "camera.*fov"),
        ('[[object]]\nprimitive = "sphere"\nradius = "big"\n', "object 0.*radius"),
        ('[[object]]\nprimitive = "sphere"\nsubdivisions = "many"\n', "object 0.*subdivisions"),
        ("[[object]]\nfile = 3\n", "object 0.*file"),
        ("object = 5\n", "object"),
        ("[[light]]\nposition = [0, 0, 0]\npower = -5\n", "light 0.*power must be >= 0"),
        ("[[light]]\nposition = [0, 0, 0]\n[[light]]\nposition = [0, 0, 0]\npower = -0.5\n", "light 1.*power"),
        # negative or zero sizes (before: accepted, the meshes turned inside out or empty)
        ('[[object]]\nprimitive = "sphere"\nradius = -0.1\n', r"object 0: radius must be positive, got -0\.1"),
        ('[[object]]\nprimitive = "sphere"\nradius = 0\n', "object 0: radius must be positive, got 0"),
        ('[[object]]\nprimitive = "torus"\ntube = -0.01\n', "object 0: tube must be positive"),
        (
            '[[object]]\nprimitive = "box"\nsize = [0.1, -0.1, 0.1]\n',
            r"object 0: size must be positive, got \[0\.1, -0\.1",
        ),
        ('[[light]]\ntype = "area"\nposition = [0, 0, 0]\nsize = [0.1, -0.1]\n', "light 0: .*positive size"),
        ("[camera]\nclip_start = -1\n", "camera: clip_start must be >= 0"),
        ("[camera]\nclip_start = 2\nclip_end = 1\n", "camera: .*less than clip_end"),
        ("[camera]\nfov = 0\n", "camera: fov must be between 0 and 180"),
    ],
)
def test_bad_toml(tmp_path, body, pattern):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(SceneError, match=pattern) as info:
        load_scene_file(path)
    assert "bad.toml" in str(info.value)


def test_nan_vertex_in_binary_mesh(tmp_path):
    mesh = box_at([0, 0, 0])
    V = np.array(mesh.vertices)
    V[3, 1] = np.nan
    trimesh.Trimesh(V, mesh.faces, process=False).export(tmp_path / "nan.ply")
    with pytest.raises(SceneError, match=r"nan\.ply.*NaN"):
        load_mesh_file(tmp_path / "nan.ply")


def test_degenerate_triangles_skipped_with_warning(tmp_path, torus):
    path = write(
        tmp_path / "degenerate.obj",
        """
        v 0.2 -0.05 -0.05
        v 0.2 0.05 -0.05
        v 0.2 0.0 0.05
        v 0.2 0.1 0.1
        v 0.2 0.2 0.2
        f 1 2 3
        f 1 1 2
        f 1 4 5
    """,
    )
    with pytest.warns(UserWarning, match="2 degenerate"):
        (obj,) = load_mesh_file(path)
    assert len(obj.triangles) == 1
    out = trace_objects(torus, Scene(objects=[obj]), [[1, 0, 0], [0, 1, 0]])
    assert list(out["object"]) == [0, -1]
    assert out["depth"][0] == pytest.approx(0.2, abs=1e-6)


# --- the default scene --------------------------------------------------------------------------------------
EDGE_CLASSES = {"torus": 3, "poincare": 10, "seifert_weber": 6}  # 12 edges in 3 cycles of 4; 30 in cycles of 3; of 5


@pytest.mark.parametrize("sid", presets(lambda space: isinstance(space, spaces.DirichletSpace)))
def test_default_scene_has_a_tube_along_every_edge(sid):
    space = spaces.load(sid)
    dom = space.domain
    V = dom.vertices
    # Euler: a convex polyhedron has V - E + F = 2
    assert len(dom.edges) == len(V) + len(dom.faces) - 2
    scene = default_scene(space)
    edges = [o for o in scene.objects if o.name.startswith("edges")]
    if sid in EDGE_CLASSES:
        assert len(edges) == EDGE_CLASSES[sid]
    size = np.ptp(V, axis=0).max()
    radius = 0.012 * size
    # the tubes are the connected pieces of the edge objects
    tubes = [
        piece.vertices
        for o in edges
        for piece in trimesh.Trimesh(o.vertices, o.triangles, process=False).split(only_watertight=False)
    ]
    assert len(tubes) == len(dom.edges)
    found = 0
    for a, b, _, _ in dom.edges:
        p, q = V[a], V[b]
        axis = (q - p) / np.linalg.norm(q - p)
        for W in tubes:
            s = (W - p) @ axis
            radial = np.linalg.norm(W - p - s[:, None] * axis, axis=1)
            on_tube = np.isclose(radial, radius, rtol=1e-6) | (radial < 1e-12)  # rims and cap centres
            if (
                on_tube.all()
                and np.sum(radial > 0) >= 10
                and abs(s.min()) < 1e-9
                and abs(s.max() - np.linalg.norm(q - p)) < 1e-9
            ):
                found += 1
                break
    assert found == len(dom.edges)
    # the other objects lie inside the domain, and there is a light
    g = space.geometry
    for o in scene.objects:
        if not o.name.startswith("edges"):
            assert np.all(space.domain.contains(g.to_model(o.vertices)))
    assert len(scene.lights) == 1


def test_default_scene_copies_in_compiled_scene():
    space = spaces.load("poincare")
    scene = default_scene(space)
    own = sum(len(o.triangles) for o in scene.objects)
    compiled = render.compile_scene(space, scene)
    assert len(compiled["triangles"]) > own
    # every triangle belongs to an object; each object keeps at least its own triangles
    counts = np.bincount(compiled["triangle_object"], minlength=len(scene.objects))
    assert np.all(counts >= [len(o.triangles) for o in scene.objects])
    assert len(compiled["light_lifts"]) > 1


@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_default_scene_of_a_coordinate_domain_frames_each_face(sid):
    """As in the paper's Nil and Sol figures: each face framed by tubes just inside its edges, the
    frames of a face and its partner in one colour, one colour per pair."""
    space = spaces.load(sid)
    dom = space.domain
    scene = default_scene(space)
    frames = [o for o in scene.objects if o.name.startswith("edges")]
    assert len(frames) == 3
    assert len({tuple(o.color) for o in frames}) == 3
    radius = 0.012 * np.ptp(dom.vertices, axis=0).max()
    for o in frames:
        tubes = trimesh.Trimesh(o.vertices, o.triangles, process=False).split(only_watertight=False)
        assert len(tubes) == 8  # two faces of four sides
        for tube in tubes:
            W = tube.vertices
            # the axis of each tube lies in a face plane, 2 radii inside one of that face's edges
            centre = W.mean(axis=0)
            homes = []
            for face in dom.faces:
                n, d = face.covector[:3], face.covector[3]
                if abs(centre @ n + d) / np.linalg.norm(n) < 1e-9:
                    ring = dom.vertices[face.vertices]
                    for p, q in zip(ring, np.roll(ring, -1, axis=0)):
                        u = (q - p) / np.linalg.norm(q - p)
                        off = centre - p - ((centre - p) @ u) * u
                        if abs(np.linalg.norm(off) - 2 * radius) < 1e-9:
                            homes.append(face)
            assert len(homes) == 1
            assert np.all(np.abs(np.linalg.norm(W - centre, axis=1)) < 0.5 * space.extent + 2 * radius)
    # the other objects lie inside the domain, and there is a light
    g = space.geometry
    for o in scene.objects:
        if not o.name.startswith("edges"):
            assert np.all(space.domain.contains(g.to_model(o.vertices)))
    assert len(scene.lights) == 1
