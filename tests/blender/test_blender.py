"""The Blender layer in real bpy (5.0.1, background): registration, operators, the THURSTON render
engine, export from the depsgraph, the domain guide, the panorama, errors and background batch
renders. Pixels are compared with independent truths: the core (`thurston render`) fed with mesh
files written here from the Blender data, closed-form distances, and Blender's own conventions."""

import functools
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from support import blender_helpers as bh  # noqa: E402
from support.presets import presets  # noqa: E402

import thurston_addon  # noqa: E402
from thurston_addon import cli, render, spaces  # noqa: E402
from thurston_addon.blender import batch, domain_guide, export, properties  # noqa: E402
from thurston_addon.blender.engine import ThurstonRenderEngine  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CURVED = presets(
    lambda space: not space.geometry.projective
)  # geodesics bend in the chart: traced in chords within a tolerance


def _registered():
    return hasattr(bpy.types.Scene, "thurston")


@pytest.fixture(autouse=True)
def registered(monkeypatch):
    import warnings

    # cli.main replaces warnings.showwarning; put it back after each test
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    if not _registered():
        thurston_addon.register()
    yield


def engine_ids():
    """The render engines Blender accepts: its error message for an unknown engine lists them."""
    with pytest.raises(TypeError) as info:
        bpy.context.scene.render.engine = "NO_SUCH_ENGINE"
    return info.value.args[0]


def cli_render(tmp_path, toml, space, name, size=(bh.W, bh.H), quality="draft", projection="perspective", extra=()):
    out = tmp_path / f"{name}.exr"
    code = cli.main(
        [
            "render",
            "--space",
            space,
            "--scene",
            str(toml),
            "--size",
            f"{size[0]}x{size[1]}",
            "--quality",
            quality,
            "--projection",
            projection,
            "--threads",
            "2",
            "--out",
            str(out),
            *extra,
        ]
    )
    assert code == 0
    return bh.read_exr(out)


def close(a, b, tol=1e-4):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape
    err = np.abs(a - b) / (1 + np.abs(b))
    assert err.max() < tol, f"max relative difference {err.max():.3g} at {np.unravel_index(err.argmax(), err.shape)}"


# --- 1. registration ---------------------------------------------------------------------------------
def test_register_unregister_twice():
    if _registered():
        thurston_addon.unregister()
    try:
        for _ in range(2):
            thurston_addon.register()
            assert _registered()
            assert ThurstonRenderEngine.is_registered
            assert "THURSTON" in engine_ids()
            bpy.context.scene.render.engine = "THURSTON"
            assert hasattr(bpy.ops.thurston, "render_view")
            bpy.context.scene.render.engine = "BLENDER_EEVEE"
            thurston_addon.unregister()
            assert not _registered()
            left = [n for n in dir(bpy.types) if n.startswith("THURSTON_") or n.startswith("Thurston")]
            assert left == []
            assert not ThurstonRenderEngine.is_registered
            assert properties.migrate_space_index not in bpy.app.handlers.load_post
            assert "THURSTON" not in engine_ids()
    finally:
        if not _registered():
            thurston_addon.register()


# --- a small scene used by several tests ---------------------------------------------------------------
def build_scene(space="torus", scale=1.0, rotation=(1.45, 0.08, 0.25)):
    """Boxes of different colours (one emissive) and a point light around a camera at the origin,
    everything well inside the domain (torus, nil: the unit cube; poincare: chart radius < 0.32;
    sol: the prism of test_domain_guide_of_nil_and_sol). Lambert materials (bh.lambert): these
    tests compare exports and render paths, and a glossy surface's bounce gathering emission would
    turn the exports' 1e-7 differences into whole samples flipped at the lamp's edges."""
    sc = bh.fresh_scene(space, scale)
    s = scale
    bh.box("Red", 0.12 * s, (0.04 * s, 0.22 * s, 0.03 * s), color=(0.9, 0.2, 0.1), rotation=(0.3, 0.2, 0.1))
    bh.box(
        "Lamp",
        (0.06 * s, 0.05 * s, 0.08 * s),
        (-0.1 * s, 0.2 * s, -0.05 * s),
        color=(0.1, 0.1, 0.1),
        emission=(0.2, 0.9, 0.4),
        strength=2.0,
    )
    bh.box("Floor", (0.5 * s, 0.5 * s, 0.02 * s), (0, 0.1 * s, -0.15 * s), color=(0.5, 0.5, 0.7))
    bh.point_light((0.05 * s, 0.05 * s, 0.1 * s), energy=3.0, color=(1.0, 0.9, 0.8))
    bh.camera((0, -0.05 * s, 0), rotation, lens=35.0)
    for k, name in enumerate(("Red", "Lamp", "Floor")):
        bpy.data.objects[name].pass_index = 3 + k
        bh.lambert(bpy.data.objects[name].active_material)
    return sc


# --- 2. renders through every path equal the core's render of the same scene as files ------------------
@pytest.mark.parametrize(
    "space,scale",
    [
        ("torus", 1.0),
        ("poincare", 2.0),
        ("nil", 1.0),
        ("sol", 2.0),
        ("genus2xs1", 1.0),
        ("s2xs1", 0.1),
        ("rp3_rp3", 0.1),
        ("sl2", 1.0),
    ],
)
def test_operators_and_f12_match_core(tmp_path, space, scale):
    """Every path renders what the core renders from the same scene written as files. The emissive
    box lights the others by sampled points whose shadow rays can graze edges that the two exports
    (OBJ text, Blender's floats) place 1e-7 apart: rp3_rp3's tiny scene flips 27 of 3888 values,
    by up to 1e-3; a wrong export differs far more."""
    near = functools.partial(close, tol=2e-3)
    sc = build_scene(space, scale)
    toml = bh.write_scene_files(sc, tmp_path, scale)
    truth = cli_render(tmp_path, toml, space, "truth")
    color = bh.rgb(truth)
    assert color.max() > 0.05 and np.ptp(color) > 0.05 and np.isfinite(color).all()  # not a blank image
    assert 0.3 < np.isfinite(truth["Z"]).mean()

    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    near(bh.image_pixels(bpy.data.images["Thurston View"])[..., :3], color)

    chans = bh.f12(sc, tmp_path / "f12.exr")
    near(bh.rgb(chans, "ViewLayer.Combined."), color)
    st = sc.thurston.stats
    assert st.valid and st.chords_per_ray > 0 and st.bound
    if space in CURVED:  # the quality's bound: a fraction of the pixel footprint
        assert "pixel footprint" in st.bound and "chord tolerance" in st.bound

    # preview: same size here (48 px < 320), quality 'preview'
    prev = bh.rgb(cli_render(tmp_path, toml, space, "prev", quality="preview"))
    assert bpy.ops.thurston.preview() == {"FINISHED"}
    near(bh.image_pixels(bpy.data.images["Thurston Preview"])[..., :3], prev)

    # panorama: Blender's equirect image centre looks along world +X, up +Z
    sc.thurston.panorama_width = 32
    pano = bh.rgb(
        cli_render(
            tmp_path,
            toml,
            space,
            "pano",
            size=(32, 16),
            projection="equirect",
            extra=["--camera-forward=1,0,0", "--camera-up=0,0,1"],
        )
    )
    assert bpy.ops.thurston.bake_panorama() == {"FINISHED"}
    near(bh.image_pixels(bpy.data.images["Thurston Panorama"])[..., :3], pano)


def same_points(a, b, tol=1e-6):
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    return len(a) == len(b) and d.min(axis=0).max() < tol and d.min(axis=1).max() < tol


# --- 3. export from a real depsgraph ---------------------------------------------------------------
def exported(scale=1.0):
    notes = []
    scene = export.export_scene(bpy.context.evaluated_depsgraph_get(), scale, notes)
    return {o.name: o for o in scene.objects}, scene, notes


def test_export_applies_modifiers():
    bh.fresh_scene()
    sub = bh.box("Sub", 0.1, (0, 0.2, 0))
    mod = sub.modifiers.new("subsurf", "SUBSURF")
    mod.levels = mod.render_levels = 1
    arr = bh.box("Arr", 0.1, (0, -0.2, 0))
    a = arr.modifiers.new("array", "ARRAY")
    a.count = 3
    a.relative_offset_displace = (1.5, 0, 0)
    objs, _, _ = exported()
    # Catmull-Clark level 1 of a cube: 24 quads = 48 triangles (the cube alone: 12)
    assert len(objs["Sub"].triangles) == 48
    # three copies 1.5 sizes apart: 36 triangles spanning x in [-0.05, 0.05 + 2 * 0.15]
    assert len(objs["Arr"].triangles) == 36
    V = objs["Arr"].vertices
    np.testing.assert_allclose(V.min(axis=0), [-0.05, -0.25, -0.05], atol=1e-6)
    np.testing.assert_allclose(V.max(axis=0), [0.35, -0.15, 0.05], atol=1e-6)


def test_export_follows_render_visibility_of_collections():
    """Blender does not render objects whose collections are disabled in renders (on the collection
    or a parent) or excluded from the view layer; neither does the export."""
    sc = bh.fresh_scene()
    parent = bpy.data.collections.new("NoRender")
    child = bpy.data.collections.new("Child")
    excluded = bpy.data.collections.new("Excluded")
    for c in (parent, excluded):
        sc.collection.children.link(c)
    parent.children.link(child)
    parent.hide_render = True
    for name, coll in (("InChild", child), ("InExcluded", excluded)):
        b = bh.box(name, 0.1, (0, 0.2, 0))
        sc.collection.objects.unlink(b)
        coll.objects.link(b)
    bpy.context.view_layer.layer_collection.children["Excluded"].exclude = True
    bh.box("Shown", 0.1, (0, 0, -0.3))
    objs, _, _ = exported()
    assert set(objs) == {"Shown"}


def test_export_instances_hidden_and_guide():
    sc = bh.fresh_scene(scale=2.0)
    src = bpy.data.collections.new("Src")  # not linked to the scene: seen only through instances
    b = bh.box("Inst", 0.1, (0.05, 0, 0))
    sc.collection.objects.unlink(b)
    src.objects.link(b)
    empties = []
    for k, loc in enumerate([(0.2, 0.3, 0.0), (-0.4, 0.0, 0.2)]):
        e = bpy.data.objects.new(f"Empty{k}", None)
        e.instance_type = "COLLECTION"
        e.instance_collection = src
        e.location = loc
        e.rotation_euler = (0, 0, math.pi / 2 * k)
        bh.link(e)
        empties.append(e)
    hidden = bh.box("Hidden", 0.1, (0, 0, 0.3))
    hidden.hide_render = True
    bh.box("Shown", 0.1, (0, 0, -0.3))
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    guide = bpy.data.objects["Thurston Domain"]
    assert guide.hide_render
    objs, scene, _ = exported(scale=2.0)
    assert "Hidden" not in objs and not any("Thurston" in n for n in objs)
    assert len(scene.objects) == 2  # the two instances share one mesh
    np.testing.assert_allclose(objs["Shown"].vertices.mean(axis=0), [0, 0, -0.15], atol=1e-9)  # world / scale
    (shared,) = (o for n, o in objs.items() if n.startswith("Inst"))
    inst = [shared.placed(A[None]) for A in shared.instances]
    assert len(inst) == 2
    box_local = np.array([(x, y, z) for x in (0.0, 0.1) for y in (-0.05, 0.05) for z in (-0.05, 0.05)])
    for o, e in zip(sorted(inst, key=lambda o: -o.vertices[:, 0].mean()), empties):
        M = np.array(e.matrix_world)
        want = (box_local @ M[:3, :3].T + M[:3, 3]) / 2.0
        assert same_points(o.vertices, want)


def test_export_skips_non_mesh_objects_with_a_note():
    bh.fresh_scene()
    bh.box("B", 0.1, (0, 0.3, 0))
    cu = bpy.data.curves.new("Curve", "CURVE")
    sp = cu.splines.new("BEZIER")
    sp.bezier_points.add(1)
    sp.bezier_points[1].co = (0.1, 0, 0)
    cu.bevel_depth = 0.01
    bh.link(bpy.data.objects.new("Curve", cu))
    bh.link(bpy.data.objects.new("Text", bpy.data.curves.new("Text", "FONT")))
    objs, _, notes = exported()
    text = " ".join(n.message for n in notes)
    assert "Curve" in text and "Text" in text
    assert list(objs) == ["B"], list(objs)


def test_export_materials():
    bh.fresh_scene()
    bh.box("P", 0.1, (0, 0.3, 0), color=(0.1, 0.2, 0.3), emission=(0.5, 0.25, 1.0), strength=3.0)
    e = bh.box("E", 0.1, (0, -0.3, 0))
    e.data.materials[0] = bh.material("em", emission=(0.2, 0.4, 0.6), strength=5.0, kind="emission")
    n = bh.box("N", 0.1, (0.3, 0, 0))
    n.data.materials.clear()
    objs, _, _ = exported()
    np.testing.assert_allclose(objs["P"].color, [0.1, 0.2, 0.3], atol=1e-6)
    np.testing.assert_allclose(objs["P"].emission, [1.5, 0.75, 3.0], atol=1e-6)
    np.testing.assert_allclose(objs["E"].emission, [1.0, 2.0, 3.0], atol=1e-6)
    np.testing.assert_allclose(objs["N"].emission, [0, 0, 0])


# --- 4. domain guide ----------------------------------------------------------------------------------
def guide_points():
    obj = bpy.data.objects["Thurston Domain"]
    return obj, np.array([tuple(v.co) for v in obj.data.vertices])


def test_domain_guide_follows_space_and_scale():
    sc = bh.fresh_scene("torus")
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    obj, pts = guide_points()
    dom = spaces.load("torus").domain
    assert (len(obj.data.vertices), len(obj.data.edges)) == (len(dom.vertices), len(dom.edges)) == (8, 12)
    assert obj.name in bpy.data.collections["Thurston Guide"].objects
    assert "Thurston Guide" in sc.collection.children
    assert same_points(pts, dom.vertices)
    sc.thurston.space = "poincare"
    obj, pts = guide_points()
    dom = spaces.load("poincare").domain
    assert (len(obj.data.vertices), len(obj.data.edges)) == (len(dom.vertices), len(dom.edges)) == (20, 30)
    sc.thurston.scale = 2.5
    obj, pts = guide_points()
    assert same_points(pts, dom.vertices * 2.5)
    assert len([o for o in bpy.data.objects if o.name.startswith("Thurston Domain")]) == 1


def test_domain_guide_of_genus2xs1():
    """The octagonal prism: 16 vertices at Klein radius sqrt(12 sqrt2 - 16) (the regular octagon
    with angles pi/4), at heights +-L/2, L = acosh(5 + 4 sqrt2); 8 + 8 + 8 edges; 10 faces."""
    bh.fresh_scene("genus2xs1")
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    obj, pts = guide_points()
    L = math.acosh(5 + 4 * math.sqrt(2))
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), math.sqrt(12 * math.sqrt(2) - 16), rtol=1e-6)
    np.testing.assert_allclose(np.abs(pts[:, 2]), L / 2, rtol=1e-6)
    assert len(pts) == 16 and len(obj.data.edges) == 24 and len(obj.data.polygons) == 10
    angles = np.sort(np.arctan2(pts[pts[:, 2] > 0, 1], pts[pts[:, 2] > 0, 0]))
    np.testing.assert_allclose(np.diff(angles), math.pi / 4, atol=1e-6)


def test_domain_guide_of_sl2_is_the_curved_octagonal_prism():
    """The octagon times [-pi, pi] in the Poincare chart: the guide's points lie on the domain's
    boundary (a side's Klein test or a lid at equality), and its sides bulge towards the axis
    (circle arcs, not the chords of the vertices)."""
    bh.fresh_scene("sl2")
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    obj, pts = guide_points()
    w = pts[:, 0] + 1j * pts[:, 1]
    k = 2 * w / (1 + np.abs(w) ** 2)
    side = np.max(
        np.c_[k.real, k.imag] @ np.array([[math.cos(a), math.sin(a)] for a in np.arange(8) * math.pi / 4]).T, axis=1
    )
    on_side = np.abs(side - math.sqrt(2 * math.sqrt(2) - 2)) < 1e-5
    on_lid = np.abs(np.abs(pts[:, 2]) - math.pi) < 1e-5
    assert np.all(on_side | on_lid) and len(obj.data.polygons) > 1000
    poincare_vertex = math.sqrt(12 * math.sqrt(2) - 16) / (1 + math.sqrt(1 - (12 * math.sqrt(2) - 16)))
    chord = poincare_vertex * math.cos(math.pi / 8)  # the chord of two vertices, at its midpoint
    eighths = np.angle(w) / (math.pi / 4)
    mid = on_side & ~on_lid & (np.abs(eighths - np.round(eighths)) < 1e-6)  # the sides' middles
    assert mid.any() and np.all(np.abs(w[mid]) < chord - 0.01)


@pytest.mark.parametrize("space", presets(lambda space: isinstance(space, spaces.ShellSpace)))
def test_domain_guide_of_a_shell_is_its_two_spheres(space):
    """The shell 1 <= |x| <= e^(2 pi) (rp3_rp3: the file's shell, not the double cover's the tracer
    walks): the guide's vertices lie on the two spheres, both drawn."""
    bh.fresh_scene(space, scale=0.001)
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    obj, pts = guide_points()
    radii = np.linalg.norm(pts, axis=1) / 0.001
    on_inner, on_outer = np.isclose(radii, 1, rtol=1e-6), np.isclose(radii, math.exp(2 * math.pi), rtol=1e-6)
    assert np.all(on_inner | on_outer) and on_inner.sum() == on_outer.sum() > 100
    assert len(obj.data.polygons) > 100


def prism_coordinates(space, points):
    """Coordinates (a, b, c) of points a e1 + b e2 + c e3 in the side vectors e of the domain, computed
    here: Nil's cube [-1/2, 1/2]^3 (e = the axes) and Sol's prism {s u1 + t u2 : |s|, |t| <= 1/2} x
    [-ln phi, ln phi], u1 = (1, phi) / n, u2 = (-phi, 1) / n, n = sqrt(1 + phi^2) (e = u1, u2, 2 ln phi z);
    the domain's points have all coordinates in [-1/2, 1/2], its vertices all of them +-1/2."""
    phi = (1 + math.sqrt(5)) / 2
    n = math.hypot(1, phi)
    sides = {"nil": np.eye(3), "sol": np.array([[1 / n, phi / n, 0], [-phi / n, 1 / n, 0], [0, 0, 2 * math.log(phi)]])}
    return np.linalg.solve(sides[space].T, np.asarray(points, float).T).T


@pytest.mark.parametrize("space,scale", [("nil", 1.0), ("sol", 1.5)])
def test_domain_guide_of_nil_and_sol(space, scale):
    bh.fresh_scene(space, scale)
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    obj, pts = guide_points()
    assert obj["thurston_space"] == space
    assert same_points(pts, spaces.load(space).domain.vertices * scale)
    C = prism_coordinates(space, pts / scale)
    np.testing.assert_allclose(np.abs(C), 0.5, atol=1e-6)
    assert len({tuple(np.sign(c)) for c in C}) == 8
    # edges: the 12 pairs of vertices that differ in one coordinate
    edges = {tuple(sorted(e.vertices)) for e in obj.data.edges}
    want = {(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(np.abs(C[i] - C[j]) > 0.5) == 1}
    assert len(edges) == len(obj.data.edges) == 12 and edges == want
    # faces: 6 quadrilaterals, one on each side a, b or c = +-1/2
    sides = set()
    for poly in obj.data.polygons:
        ring = C[list(poly.vertices)]
        axis = int(np.argmax(np.ptp(ring, axis=0) < 1e-6))
        assert len(ring) == 4 and np.sum(np.ptp(ring, axis=0) < 1e-6) == 1
        sides.add((axis, float(np.sign(ring[0, axis]))))
    assert len(obj.data.polygons) == len(sides) == 6


# --- 5. Render View to Image --------------------------------------------------------------------------
def test_render_view_image_reuse_and_save(tmp_path):
    sc = build_scene()
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    img = bpy.data.images["Thurston View"]
    assert img.is_float and "Linear" in img.colorspace_settings.name
    assert tuple(img.size) == (bh.W, bh.H)
    first = bh.image_pixels(img)
    ptr = img.as_pointer()
    bpy.data.objects["Red"].location.x += 0.05
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    assert bpy.data.images["Thurston View"].as_pointer() == ptr
    assert "Thurston View.001" not in bpy.data.images
    assert not np.allclose(bh.image_pixels(img), first)  # the datablock holds the new render

    out = tmp_path / "view.exr"
    sc.thurston.save_path = str(out)
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    chans = bh.read_exr(out)
    px = bh.image_pixels(img)
    np.testing.assert_allclose(bh.rgb(chans), px[..., :3], rtol=1e-6, atol=1e-7)
    assert "Z" in chans and np.isfinite(chans["Z"]).mean() > 0.5

    before = out.read_bytes()
    with pytest.raises(RuntimeError, match="exists; tick Overwrite in the Thurston panel") as info:
        bpy.ops.thurston.render_view()
    assert "--overwrite" not in str(info.value)
    assert out.read_bytes() == before
    # Blender's relative paths: // is the .blend's folder
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=False)
    sc.thurston.save_path, sc.thurston.overwrite = "//relative.png", False
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    assert (tmp_path / "relative.png").is_file()
    sc.thurston.save_path = str(out)
    sc.thurston.overwrite = True
    bpy.data.objects["Red"].location.x -= 0.1
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    assert out.read_bytes() != before


def user_image():
    img = bpy.data.images.new("Thurston View", 4, 4, float_buffer=True)
    img.pixels.foreach_set(np.full(64, 0.25, np.float32))
    return img


def test_render_view_leaves_users_image_alone():
    build_scene()
    mine = user_image()
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    assert tuple(mine.size) == (4, 4) and np.all(bh.image_pixels(mine) == 0.25)
    made = [im for im in bpy.data.images if im.name.startswith("Thurston View") and im != mine]
    assert len(made) == 1 and tuple(made[0].size) == (bh.W, bh.H)


def test_render_view_reuses_its_own_image_next_to_users():
    build_scene()
    user_image()
    bpy.ops.thurston.render_view()
    bpy.ops.thurston.render_view()
    names = sorted(im.name for im in bpy.data.images if im.name.startswith("Thurston View"))
    assert names == ["Thurston View", "Thurston View.001"]


# --- 6. Bake Panorama -------------------------------------------------------------------------------
def test_bake_panorama_world_nodes_and_orientation():
    sc = bh.fresh_scene("torus")
    sc.thurston.max_distance = 0.5  # only the boxes themselves, not their copies one domain away
    sc.thurston.panorama_width = 64
    black = (0, 0, 0)
    bh.box("MinusX", 0.1, (-0.3, 0, 0), color=black, emission=(1, 0, 0))
    bh.box("PlusY", 0.1, (0, 0.3, 0), color=black, emission=(0, 1, 0))
    bh.box("PlusZ", 0.1, (0, 0, 0.3), color=black, emission=(0, 0, 1))
    bh.camera((0, 0, 0), rotation=(0.3, 0.2, 1.0))  # the camera's orientation must not matter
    world = bpy.data.worlds.new("World")
    sc.world = world
    if world.node_tree is None:  # Blender 5 gives new worlds a node tree
        world.use_nodes = True
    mine = world.node_tree.nodes.new("ShaderNodeValue")
    mine.name = "My Value"
    assert bpy.ops.thurston.bake_panorama() == {"FINISHED"}
    assert bpy.ops.thurston.bake_panorama() == {"FINISHED"}
    img = bpy.data.images["Thurston Panorama"]
    assert tuple(img.size) == (64, 32)
    nodes = sc.world.node_tree.nodes
    assert "My Value" in nodes
    envs = [n for n in nodes if n.type == "TEX_ENVIRONMENT"]
    assert len(envs) == 1 and envs[0].image == img
    bg = next(n for n in nodes if n.type == "BACKGROUND")
    assert bg.inputs["Color"].is_linked and bg.inputs["Color"].links[0].from_node == envs[0]
    out = next(n for n in nodes if n.type == "OUTPUT_WORLD")
    assert out.inputs["Surface"].links[0].from_node == bg

    px = bh.image_pixels(img)[..., :3]  # rows top-down: row 0 is v = 1

    def at(d):
        """The pixel Blender's equirectangular lookup reads for world direction d
        (Blender's direction_to_equirectangular: u = -atan2(y, x) / 2 pi + 0.5)."""
        d = np.asarray(d, float) / np.linalg.norm(d)
        u = -math.atan2(d[1], d[0]) / (2 * math.pi) + 0.5
        v = math.atan2(d[2], math.hypot(d[0], d[1])) / math.pi + 0.5
        return px[min(31, int((1 - v) * 32)), int(u * 64) % 64]

    red, green, blue = (np.argmax(at(d)) if at(d).max() > 0.5 else None for d in ((-1, 0, 0), (0, 1, 0), (0, 0, 1)))
    assert (red, green, blue) == (0, 1, 2)
    for d in ((1, 0, 0), (0, -1, 0), (0, 0, -1)):
        assert at(d).max() < 0.01, d


@pytest.mark.slow
def test_baked_panorama_seen_by_cycles_matches_the_scene(tmp_path):
    """Independent of any formula: Cycles renders the World with the baked panorama, looking along
    -X and +Y from the bake point, and sees the colours of the objects that lie there."""
    sc = bh.fresh_scene("torus", size=(8, 8))
    sc.thurston.max_distance = 0.5
    sc.thurston.panorama_width = 128
    black = (0, 0, 0)
    boxes = [
        bh.box("MinusX", 0.2, (-0.3, 0, 0), color=black, emission=(1, 0, 0)),
        bh.box("PlusY", 0.2, (0, 0.3, 0), color=black, emission=(0, 1, 0)),
    ]
    cam = bh.camera((0, 0, 0), rotation=(0.3, 0.2, 1.0))
    assert bpy.ops.thurston.bake_panorama() == {"FINISHED"}
    for b in boxes:
        b.hide_render = True  # Cycles sees only the World
    sc.render.engine = "CYCLES"
    sc.cycles.samples = 4
    sc.cycles.device = "CPU"
    sc.render.image_settings.file_format = "OPEN_EXR"
    cam.data.lens = 200  # a narrow view around the axis
    for name, rotation, channel in (("minus_x", (math.pi / 2, 0, math.pi / 2), 0), ("plus_y", (math.pi / 2, 0, 0), 1)):
        cam.rotation_euler = rotation
        sc.render.filepath = str(tmp_path / f"{name}.exr")
        bpy.ops.render.render(write_still=True)
        centre = bh.rgb(bh.read_exr(tmp_path / f"{name}.exr"))[3:5, 3:5].mean(axis=(0, 1))
        assert np.argmax(centre) == channel and centre[channel] > 0.5, (name, centre)


# --- 7. the render engine ---------------------------------------------------------------------------
def enable_passes(sc):
    vl = sc.view_layers[0]
    vl.use_pass_z = vl.use_pass_normal = vl.use_pass_object_index = vl.use_pass_position = True
    vl.thurston.use_pass_geodesic_distance = vl.thurston.use_pass_crossings = True


def view_axis_cosines(cam, w, h):
    """Blender's camera (horizontal sensor fit): the cosine between each pixel centre's ray and the
    optical axis."""
    t = math.tan(cam.data.angle_x / 2)
    sx = (2 * (np.arange(w) + 0.5) / w - 1) * t
    sy = (1 - 2 * (np.arange(h) + 0.5) / h) * t * h / w
    return 1 / np.sqrt(1 + sx[None, :] ** 2 + sy[:, None] ** 2)


def test_engine_passes_match_core(tmp_path):
    sc = build_scene("torus")
    enable_passes(sc)
    toml = bh.write_scene_files(sc, tmp_path, 1.0)
    truth = cli_render(tmp_path, toml, "torus", "truth")
    ch = bh.f12(sc, tmp_path / "f12.exr")
    L = "ViewLayer."
    hit = np.isfinite(truth["Z"])
    assert 0.3 < hit.mean() < 1.0
    close(np.where(hit, ch[L + "Geodesic Distance.X"], 0), np.where(hit, truth["Z"], 0))
    # Blender's depth: along the view axis
    cos = view_axis_cosines(sc.camera, bh.W, bh.H)
    close(np.where(hit, ch[L + "Depth.Z"], 0), np.where(hit, truth["Z"] * cos, 0))
    assert np.all(ch[L + "Depth.Z"][~hit] >= 1e9) and np.all(ch[L + "Geodesic Distance.X"][~hit] >= 1e9)
    for a in "XYZ":
        close(ch[f"{L}Position.{a}"][hit], truth[f"Position.{a}"][hit])
    for a in "XYZ":
        close(ch[f"{L}Normal.{a}"][hit], truth[f"Normal.{a}"][hit])
    np.testing.assert_array_equal(ch[L + "Crossings.X"], truth["Crossings"])
    assert truth["Crossings"].max() > 0
    # IndexOB holds each object's pass_index (set in build_scene), 0 where nothing is hit; the core's
    # object pass numbers the objects in the order of the scene files written from the same data
    pass_index = {i: bpy.data.objects[name].pass_index for i, name in enumerate(bh.exported_names(sc))}
    expected = np.vectorize(lambda k: pass_index.get(int(k), 0))(truth["IndexOB"])
    np.testing.assert_array_equal(ch[L + "IndexOB.X"], expected)
    assert len(set(expected[hit].tolist())) >= 2


def test_engine_depth_along_the_view_axis_and_geodesic_distance(tmp_path):
    """A wall square to the view axis, d ahead: Blender's Depth is d everywhere on it (as Cycles
    writes it), the geodesic distance d / cos(angle off the axis); both in Blender units."""
    scale = 2.0
    sc = bh.fresh_scene("torus", scale)
    sc.view_layers[0].use_pass_z = True
    sc.view_layers[0].thurston.use_pass_geodesic_distance = True
    d = 0.29  # chart distance from the camera to the wall's near face
    bh.box("Wall", (0.9 * scale, 0.02 * scale, 0.9 * scale), (0, (d + 0.01) * scale, 0))
    cam = bh.camera((0, 0, 0), lens=35.0)
    ch = bh.f12(sc, tmp_path / "depth.exr")
    np.testing.assert_allclose(ch["ViewLayer.Depth.Z"], d * scale, rtol=1e-5)
    np.testing.assert_allclose(
        ch["ViewLayer.Geodesic Distance.X"], d * scale / view_axis_cosines(cam, bh.W, bh.H), rtol=1e-5
    )


def test_engine_reports_errors():
    sc = bh.fresh_scene()
    sc.render.engine = "THURSTON"
    bh.camera()
    with pytest.raises(RuntimeError, match="nothing to render"):
        bpy.ops.render.render()
    sc.camera = None
    bh.box("B", 0.1, (0, 0.3, 0))
    with pytest.raises(RuntimeError, match="(?i)camera"):
        bpy.ops.render.render()
    sc.camera = bpy.data.objects["Camera"]
    sc.thurston.space = "FILE"
    sc.thurston.space_file = "/nonexistent.toml"
    with pytest.raises(RuntimeError, match="nonexistent.toml"):
        bpy.ops.render.render()


def test_tolerance_reaches_the_render():
    """The panel's tolerance is in Blender units (0: the quality's bound); the tracer takes chart units."""
    sc = build_scene("nil", 2.0)
    s = sc.thurston
    assert export.render_settings(s, bh.W, bh.H).tolerance is None
    s.tolerance = 0.002
    assert export.render_settings(s, bh.W, bh.H).tolerance == pytest.approx(0.001, rel=1e-6)  # a float32 setting
    chords = {}
    for tolerance in (0.2, 2e-5):
        s.tolerance = tolerance
        assert bpy.ops.thurston.render_view() == {"FINISHED"}
        chords[tolerance] = s.stats.chords_per_ray
        assert f"within {tolerance / 2:.1e} chart units" in s.stats.bound
    assert chords[2e-5] > 1.5 * chords[0.2] > 0, chords


# --- 8. bad input ---------------------------------------------------------------------------------
def no_view_image():
    return not any(im.name.startswith("Thurston View") for im in bpy.data.images)


def test_operator_errors():
    sc = bh.fresh_scene()
    bh.box("B", 0.1, (0, 0.3, 0))
    for op in (bpy.ops.thurston.render_view, bpy.ops.thurston.preview, bpy.ops.thurston.bake_panorama):
        with pytest.raises(RuntimeError, match="no camera"):
            op()
    bh.camera()
    sc.thurston.space = "FILE"
    sc.thurston.space_file = "/nonexistent.toml"
    with pytest.raises(RuntimeError, match="/nonexistent.toml.*cannot be read"):
        bpy.ops.thurston.render_view()
    sc.thurston.space_file = ""
    with pytest.raises(RuntimeError, match="no file"):
        bpy.ops.thurston.render_view()
    assert no_view_image()

    bh.fresh_scene()
    bh.camera()
    hidden = bh.box("Hidden", 0.1, (0, 0.3, 0))
    hidden.hide_render = True
    bpy.ops.thurston.domain_guide()
    with pytest.raises(RuntimeError, match="nothing to render"):
        bpy.ops.thurston.render_view()
    assert no_view_image()


def depth_of(sc, tmp_path, name):
    sc.view_layers[0].use_pass_z = True
    return bh.f12(sc, tmp_path / f"{name}.exr")["ViewLayer.Depth.Z"]


def outside_camera_scene(tmp_path):
    """The test scene and its depth pass, then the camera moved by a lattice translation of the torus
    (an isometry of the space: the view stays the same)."""
    sc = build_scene("torus")
    cam = sc.camera
    inside = np.array(cam.matrix_world)
    ref = depth_of(sc, tmp_path, "ref")
    cam.location = (cam.location.x + 1.0, cam.location.y - 2.0, cam.location.z + 1.0)
    bpy.context.view_layer.update()
    return sc, cam, inside, ref


def test_render_with_camera_outside_the_domain(tmp_path):
    sc, cam, inside, ref = outside_camera_scene(tmp_path)
    np.testing.assert_allclose(depth_of(sc, tmp_path, "outside"), ref, rtol=1e-6)
    assert bpy.ops.thurston.render_view() == {"FINISHED"}


CAMERA_INSIDE_BUG = (
    "guide.THURSTON_OT_camera_inside.execute assigns cam.matrix_world = [list(r) for r in moved]; "
    "bpy reads nested sequences column by column, so the camera gets the transposed matrix "
    "(rotation transposed, translation lost: the camera lands at the world origin)"
)


def test_camera_inside_keeps_the_view(tmp_path):
    sc, cam, inside, ref = outside_camera_scene(tmp_path)
    assert bpy.ops.thurston.camera_inside() == {"FINISHED"}
    bpy.context.view_layer.update()
    np.testing.assert_allclose(np.array(cam.matrix_world), inside, atol=1e-6)
    np.testing.assert_allclose(depth_of(sc, tmp_path, "moved"), ref, rtol=1e-5)


def test_camera_inside_with_a_rotating_pairing(tmp_path):
    sc = build_scene("quarter_turn")
    cam = sc.camera
    cam.location = (0.3, 0.9, 1.7)
    bpy.context.view_layer.update()
    before = depth_of(sc, tmp_path, "before")
    assert (before < 1e9).mean() > 0.2
    assert bpy.ops.thurston.camera_inside() == {"FINISHED"}
    bpy.context.view_layer.update()
    p = np.array(cam.matrix_world.translation)
    assert np.all(np.abs(p) <= 0.5 + 1e-6) and np.abs(p).max() > 0.05
    R = np.array(cam.matrix_world)[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(depth_of(sc, tmp_path, "after"), before, rtol=1e-5, atol=1e-6)


def tracer_view(sc):
    """The camera point and frame the tracer derives from the scene camera (render.camera_frame)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    camera = export.export_camera(sc, depsgraph, sc.thurston.scale, bh.W, bh.H)
    X, frame = render.camera_frame(export.load_space(sc.thurston), camera)
    return np.array([X, *frame])


# Nil's x-faces are paired by a shear, Sol's lids by the monodromy (x phi^-2, y phi^2): differentials
# far from rotations of the chart, so the camera's axes must be mapped as the tracer reads them
CURVED_OUTSIDE = [("nil", (1.3, 0.0, 0.0)), ("sol", (0.0, 0.0, 0.75))]


def outside_curved(space, shift):
    sc = build_scene(space)
    sc.camera.location = np.array(sc.camera.location) + shift
    bpy.context.view_layer.update()
    assert domain_guide.camera_outside(sc)
    return sc


@pytest.mark.parametrize("space,shift", CURVED_OUTSIDE)
def test_camera_inside_keeps_the_tracers_view_in_nil_and_sol(space, shift):
    sc = outside_curved(space, shift)
    before = tracer_view(sc)
    assert bpy.ops.thurston.camera_inside() == {"FINISHED"}
    bpy.context.view_layer.update()
    assert not domain_guide.camera_outside(sc)
    M = np.array(sc.camera.matrix_world)
    np.testing.assert_allclose(M[:3, :3].T @ M[:3, :3], np.eye(3), atol=1e-6)
    assert np.all(np.abs(prism_coordinates(space, M[:3, 3])) < 0.5)
    np.testing.assert_allclose(tracer_view(sc), before, atol=1e-6)  # float32 matrices


@pytest.mark.parametrize("space,shift", CURVED_OUTSIDE)
def test_camera_inside_keeps_the_picture_in_nil_and_sol(tmp_path, space, shift):
    sc = outside_curved(space, shift)
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    before = bh.image_pixels(bpy.data.images["Thurston View"])[..., :3]
    assert bpy.ops.thurston.camera_inside() == {"FINISHED"}
    bpy.context.view_layer.update()
    colour = bh.rgb(bh.f12(sc, tmp_path / "moved.exr"), "ViewLayer.Combined.")
    assert np.ptp(colour) > 0.05
    close(colour, before)


def test_camera_brought_onto_a_face_counts_as_inside():
    """Equally far outside two faces, the camera is carried through one onto the other (a point of
    the domain); stored in float32 it lies a rounding outside, and the panel's warning goes away."""
    sc = build_scene("poincare")
    sc.camera.location = (0.0, 0.55, 0.2)
    bpy.context.view_layer.update()
    assert domain_guide.camera_outside(sc)
    assert bpy.ops.thurston.camera_inside() == {"FINISHED"}
    bpy.context.view_layer.update()
    assert not domain_guide.camera_outside(sc)


def test_camera_that_cannot_be_brought_in():
    bh.fresh_scene("seifert_weber")
    bh.box("B", 0.1, (0, 0.3, 0))
    cam = bh.camera((3, 0, 0))
    with pytest.raises(RuntimeError, match=r"camera position \[3\.0, 0\.0, 0\.0\] is not a point of H3"):
        bpy.ops.thurston.render_view()
    assert no_view_image()
    before = np.array(cam.matrix_world)
    with pytest.raises(RuntimeError):
        bpy.ops.thurston.camera_inside()
    np.testing.assert_array_equal(np.array(cam.matrix_world), before)


def test_camera_inside_error_names_the_camera():
    bh.fresh_scene("seifert_weber")
    bh.box("B", 0.1, (0, 0.3, 0))
    bh.camera((3, 0, 0))
    with pytest.raises(RuntimeError) as info:
        bpy.ops.thurston.camera_inside()
    msg = str(info.value)
    assert "nan" not in msg and "camera" in msg.lower() and "3" in msg


# --- 9. background batch renders of a saved .blend ----------------------------------------------------
def test_render_blend_subprocess(tmp_path):
    scale = 2.0
    sc = build_scene("poincare", scale)
    sc.thurston.passes = {"COLOR", "DEPTH"}
    cam = sc.camera
    sc.frame_start, sc.frame_end = 1, 5
    cam.keyframe_insert("location", frame=1)
    cam.location.x += 0.15 * scale
    cam.keyframe_insert("location", frame=2)
    blend = tmp_path / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    # the truth for frame 1: the same scene as files, rendered by the core in the space saved in the file
    sc.frame_set(1)
    files = tmp_path / "files"
    files.mkdir()
    truth = bh.rgb(cli_render(files, bh.write_scene_files(sc, files, scale), "poincare", "truth"))

    out = tmp_path / "out"
    out.mkdir()
    run = bh.render_blend(blend, out, frames="1..2")
    assert run.returncode == 0, run.stderr
    frames = [out / "anim_0001.exr", out / "anim_0002.exr"]
    assert sorted(out.iterdir()) == frames
    one, two = (bh.read_exr(f) for f in frames)
    # the passes saved in the file, as Blender's multilayer EXR names them
    assert set(one) == {"ViewLayer.Combined." + c for c in "RGBA"} | {
        "ViewLayer.Depth.Z",
        "ViewLayer.Geodesic Distance.X",
    }
    L = "ViewLayer.Combined."
    close(bh.rgb(one, L), truth)
    assert np.abs(bh.rgb(one, L) - bh.rgb(two, L)).max() > 0.05  # the camera moved

    stamp = [(f.read_bytes(), f.stat().st_mtime_ns) for f in frames]
    run = bh.render_blend(blend, out, frames="1..2")
    assert run.returncode == 2
    assert "exists" in run.stderr and "Traceback" not in run.stderr
    assert [(f.read_bytes(), f.stat().st_mtime_ns) for f in frames] == stamp


@pytest.mark.slow
@pytest.mark.parametrize("space", CURVED)
def test_render_blend_in_the_curved_geometries(tmp_path, space):
    sc = build_scene(space)
    sc.thurston.passes = {"COLOR"}
    blend = tmp_path / "walk.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    truth = bh.rgb(cli_render(tmp_path, bh.write_scene_files(sc, tmp_path, 1.0), space, "truth"))
    run = bh.render_blend(blend, tmp_path)
    assert run.returncode == 0, run.stderr
    close(bh.rgb(bh.read_exr(tmp_path / "walk_0001.exr"), "ViewLayer.Combined."), truth)
    assert "chords/ray" in run.stdout and "pixel footprint" in run.stdout  # the frame's stats line


def test_settings_presets_round_trip(tmp_path, monkeypatch):
    """A preset saved from the panel's menu restores every setting it names."""
    monkeypatch.setenv("BLENDER_USER_SCRIPTS", str(tmp_path))
    bh.fresh_scene()
    s = bpy.context.scene.thurston
    s.space, s.quality, s.scale, s.fog, s.passes = "nil", "final", 2.5, 3.0, {"COLOR", "DEPTH"}
    s.tolerance = 0.004
    assert bpy.ops.thurston.add_preset(name="Night Walk") == {"FINISHED"}
    preset = next(tmp_path.glob("**/presets/thurston/Night_Walk.py"), None) or next(
        Path(bpy.utils.resource_path("USER")).glob("**/presets/thurston/Night_Walk.py")
    )
    assert "settings.space_id = 'nil'" in preset.read_text()  # the id, not the enum's position
    s.space, s.quality, s.scale, s.fog, s.passes, s.tolerance = "torus", "draft", 1.0, 0.0, {"NORMAL"}, 0.0
    assert bpy.ops.script.execute_preset(filepath=str(preset), menu_idname="THURSTON_MT_presets") == {"FINISHED"}
    assert (s.space, s.quality, s.scale, s.fog, set(s.passes)) == ("nil", "final", 2.5, 3.0, {"COLOR", "DEPTH"})
    assert s.tolerance == pytest.approx(0.004)
    preset.unlink()


def test_point_light_brightness_matches_cycles(tmp_path):
    """A Lambert plane lit head-on by a point light of P watts at distance r has radiance
    rho / pi * P / (4 pi r^2) (closed form); THURSTON's F12 gives that within a light reach that
    holds only the light's own copy (the others are a cell away), and so does Cycles."""
    sc = bh.fresh_scene("torus", size=(16, 16))
    sc.thurston.light_reach = 0.5
    rho, watts, r = 0.8, 10.0, 0.3
    plane = bh.box("Plane", (0.4, 0.001, 0.4), (0, r, 0), color=(rho, rho, rho))
    bh.lambert(plane.active_material)
    light = bh.point_light((0, 0, 0), energy=watts)
    light.data.shadow_soft_size = 0.0
    bh.camera(location=(0, -0.1, 0))
    sc.view_settings.view_transform = "Standard"
    sc.thurston.quality = "draft"  # one sample, through the pixel centre
    # the ray through the centre of pixel (row 8, column 8) of 16: half a pixel off the axis each way
    t = math.tan(sc.camera.data.angle / 2) / 16
    direction = np.array([t, 1.0, -t])
    hit = np.array([0, -0.1, 0]) + direction * (r - 0.0005 + 0.1)  # the plane's front at y = r - 0.0005
    dist = np.linalg.norm(hit)
    expected = rho / math.pi * watts / (4 * math.pi) * (hit[1] / dist) / dist**2
    thurston = bh.rgb(bh.f12(sc, tmp_path / "thurston.exr"), "ViewLayer.Combined.")[8, 8]
    np.testing.assert_allclose(thurston, expected, rtol=1e-4)
    sc.render.engine = "CYCLES"
    sc.cycles.samples = 64
    sc.cycles.device = "CPU"
    sc.render.filepath = str(tmp_path / "cycles.exr")  # the multilayer EXR settings of f12 stay
    bpy.ops.render.render(write_still=True)
    cycles = bh.rgb(bh.read_exr(tmp_path / "cycles.exr"), "ViewLayer.Combined.")
    np.testing.assert_allclose(cycles[7:9, 7:9].mean(axis=(0, 1)), expected, rtol=0.03)


def test_f12_animation_moves_the_camera(tmp_path):
    """An animation render evaluates the camera at every frame: the depth straight ahead to a wall
    at y = 0.3 is 0.3 - y(camera) - half the wall's thickness, frame by frame."""
    sc = bh.fresh_scene("torus", size=(9, 9))
    bh.box("Wall", (0.6, 0.02, 0.6), (0, 0.3, 0))
    cam = bh.camera((0, 0, 0))
    cam.data.clip_start = 0.01  # the wall comes to 0.09, nearer than the default clip start
    for frame, y in ((1, 0.0), (3, 0.2)):
        cam.location = (0, y, 0)
        cam.keyframe_insert("location", frame=frame)
    for fc in cam.animation_data.action.fcurves if hasattr(cam.animation_data.action, "fcurves") else []:
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"
    sc.frame_start, sc.frame_end = 1, 3
    sc.render.engine = "THURSTON"
    sc.view_layers[0].use_pass_z = True
    s = sc.render.image_settings
    s.media_type = "MULTI_LAYER_IMAGE"
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"
    sc.render.filepath = str(tmp_path / "frame_###")
    bpy.ops.render.render(animation=True)
    depths = []
    for frame in (1, 2, 3):
        sc.frame_set(frame)
        y = cam.matrix_world.translation.y
        z = bh.read_exr(tmp_path / f"frame_{frame:03d}.exr")["ViewLayer.Depth.Z"][4, 4]
        depths.append((z, 0.3 - 0.01 - y))
    np.testing.assert_allclose([d for d, _ in depths], [t for _, t in depths], atol=1e-6)
    assert depths[0][0] - depths[2][0] > 0.19


def test_render_blend_renders_what_blender_renders(tmp_path):
    """Batch renders evaluate the file for rendering: an object hidden only in the viewport is there,
    and modifiers work at their render level. Straight ahead, the raw cube's front face (x from -0.01
    to 0.19) would be hit at 0.05; subdivided three times it shrinks off the view axis, which then
    meets the viewport-hidden wall at 0.29."""
    sc = bh.fresh_scene("torus", size=(9, 9))
    wall = bh.box("Wall", (0.6, 0.02, 0.6), (0, 0.3, 0))
    wall.hide_viewport = True
    cube = bh.box("Cube", 0.2, (0.09, 0.15, 0))
    sub = cube.modifiers.new("Subdivision", "SUBSURF")
    sub.levels, sub.render_levels = 0, 3
    bh.camera((0, 0, 0))
    sc.thurston.passes = {"COLOR", "DEPTH"}
    blend = tmp_path / "vis.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    run = bh.render_blend(blend, tmp_path)
    assert run.returncode == 0, run.stderr
    z = bh.read_exr(tmp_path / "vis_0001.exr")["ViewLayer.Depth.Z"]
    assert z[4, 4] == pytest.approx(0.29, abs=1e-6)


# --- 10. the space is stored by id ----------------------------------------------------------------------
def space_items(settings):
    """The ids in the space dropdown: Blender's error for an unknown one lists them."""
    with pytest.raises(TypeError) as info:
        settings.space = "no_such_space"
    return info.value.args[0]


def user_presets(tmp_path, monkeypatch, name="aaa_first"):
    """A folder of user presets on $THURSTON_SPACE_PATH holding a copy of the torus named `name`."""
    folder = tmp_path / "user_presets"
    folder.mkdir()
    shutil.copy(ROOT / "thurston_addon" / "presets" / "torus.toml", folder / f"{name}.toml")
    monkeypatch.setenv(spaces.SPACE_PATH_VARIABLE, str(folder))
    return folder / f"{name}.toml"


def test_nil_and_sol_are_in_the_space_list():
    sc = bh.fresh_scene()
    items = space_items(sc.thurston)
    for space, geometry in (("nil", "Nil"), ("sol", "Sol")):
        assert f"'{space}'" in items
        sc.thurston.space = space
        assert (sc.thurston.space, sc.thurston.space_id) == (space, space)
        loaded = export.load_space(sc.thurston)
        assert (loaded.id, loaded.geometry.name) == (space, geometry)
        assert isinstance(loaded, spaces.CoordinateSpace)


def test_new_scenes_default_to_poincare():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert bpy.context.scene.thurston.space == "poincare"
    assert bpy.data.scenes.new("Another").thurston.space_id == "poincare"
    assert export.load_space(bpy.context.scene.thurston).id == "poincare"


def test_saved_file_keeps_its_space_when_a_preset_sorts_first(tmp_path, monkeypatch):
    bh.fresh_scene("poincare")
    blend = tmp_path / "walk.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    first = user_presets(tmp_path, monkeypatch)
    assert spaces.preset_ids()[0] == "aaa_first"
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    s = bpy.context.scene.thurston
    assert (s.space, s.space_id) == ("poincare", "poincare")
    assert export.load_space(s).id == "poincare"
    assert "'aaa_first'" in space_items(s)
    s.space = "aaa_first"
    assert s.space_id == "aaa_first" and export.load_space(s).source == str(first)
    s.space = "FILE"
    assert s.space_id == "FILE"


@pytest.mark.parametrize("index,space_id", [(4, "seifert_weber"), (0, "half_turn"), (8, "FILE")])
def test_files_saved_with_the_enum_index_are_migrated(tmp_path, index, space_id):
    """Before the id was stored, a file held the enum's position under "space"; on load it becomes the id."""
    sc = bh.fresh_scene()
    own = str(tmp_path / "own.toml")
    sc.thurston.space_file = own
    name = sc.name
    second = bpy.data.scenes.new("Second")
    for settings, old in ((sc.thurston, index), (second.thurston, 7)):
        settings.space = "torus"  # stores space_id: clear it, as in an old file
        del settings["space_id"]
        settings["space"] = old
    blend = tmp_path / "old.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    s = bpy.data.scenes[name].thurston
    assert (s.space, s.space_id, s.space_file) == (space_id, space_id, own)
    assert bpy.data.scenes["Second"].thurston.space == "torus"
    assert all("space" not in b.thurston.keys() for b in bpy.data.scenes)

    # render-blend registers the add-on itself: before it opens the file, so old files are migrated too
    thurston_addon.unregister()
    batch.open_blend(blend)
    assert bpy.data.scenes[name].thurston.space_id == space_id


def test_a_space_whose_preset_is_gone(tmp_path, monkeypatch):
    sc = bh.fresh_scene()
    bh.box("B", 0.1, (0, 0.3, 0))
    bh.camera()
    s = sc.thurston
    user_presets(tmp_path, monkeypatch, "my_torus")
    s.space = "my_torus"
    monkeypatch.delenv(spaces.SPACE_PATH_VARIABLE)
    # still shown (as itself, marked missing) instead of a blank or another space
    assert s.space == "my_torus" and properties.space_missing(s)
    assert "'my_torus'" in space_items(s)
    with pytest.raises(export.ExportError, match="'my_torus' not found"):
        export.load_space(s)
    with pytest.raises(RuntimeError, match="'my_torus' not found"):
        bpy.ops.thurston.render_view()
    s.space = "torus"
    assert not properties.space_missing(s) and "'my_torus'" not in space_items(s)
