"""Surfaces: smooth shading from corner normals, per-face materials, image textures through UVs,
mesh files that carry them (OBJ vn/vt/map_Kd, glTF), and the corner normals of copies in curved
spaces. Truth: the analytic sphere normal, the Lambert closed form of a point light, the texels
written, the files' own numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from support.gltf_triangle import embedded, textured_triangle, triangle_blob
from support.textured_quad import texel_centres, textured_quad

from thurston_addon import render, spaces
from thurston_addon.scenes import Material, PointLight, Scene, SceneError, SceneObject, clean, load_mesh_file


@pytest.fixture(scope="module")
def torus():
    return spaces.load("torus")


def rays_to(space, targets, origin=(0.0, 0.0, 0.0)):
    g = space.geometry
    p = np.tile(np.asarray(origin, float), (len(targets), 1))
    X = g.to_model(p)
    return X, g.normalize_tangent(X, g.tangent_to_model(p, np.asarray(targets, float) - p))


def trace(space, scene, targets, shade=False, light_reach=None):
    X, D = rays_to(space, targets)
    return render.make_tracer(space, scene, light_reach=light_reach).trace(X, D, 0.45, 20, shade=shade)


def srgb_to_linear(c):  # the sRGB transfer function, as the test's own truth
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# --- smooth and flat normals ---------------------------------------------------------------------
CENTRE, RADIUS = np.array([0.25, 0.0, 0.0]), 0.1


def sphere(smooth: bool):
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    normals = (mesh.vertices / RADIUS)[mesh.faces] if smooth else None
    return SceneObject("sphere", mesh.vertices + CENTRE, mesh.faces, corner_normals=normals)


def sphere_targets(n=400):
    rng = np.random.default_rng(7)
    d = rng.normal(size=(n, 3)) * [0, 1, 1]
    d = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0, 0.95 * RADIUS, (n, 1))
    return CENTRE + d


def angle(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1, 1)))


def test_smooth_normals_follow_the_sphere_flat_ones_the_faces(torus):
    targets = sphere_targets()
    out = {s: trace(torus, Scene(objects=[sphere(s)]), targets) for s in (True, False)}
    for o in out.values():
        assert np.all(o["stop"] == 0)
    analytic = (out[True]["position"] - CENTRE) / np.linalg.norm(out[True]["position"] - CENTRE, axis=1, keepdims=True)
    smooth = angle(out[True]["normal"], analytic)
    flat = angle(out[False]["normal"], analytic)
    # interpolation errs by about edge^2 / r^2, a face's normal by about edge / r
    assert smooth.max() < 0.15, smooth.max()
    assert flat.mean() > 1.0, flat.mean()
    np.testing.assert_allclose(np.linalg.norm(out[True]["normal"], axis=1), 1, atol=1e-6)


def test_corner_normals_of_the_faces_shade_as_flat(torus):
    flat = sphere(False)
    P = flat.vertices[flat.triangles]
    faces = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    faces /= np.linalg.norm(faces, axis=1, keepdims=True)
    shaded = SceneObject("faces", flat.vertices, flat.triangles, corner_normals=np.repeat(faces[:, None], 3, axis=1))
    targets = sphere_targets()
    a, b = trace(torus, Scene(objects=[flat]), targets), trace(torus, Scene(objects=[shaded]), targets)
    np.testing.assert_allclose(a["normal"], b["normal"], atol=1e-6)


# --- materials and textures ----------------------------------------------------------------------
def test_texture_and_per_face_materials_in_the_lambert_closed_form(torus):
    """A quad at x = 0.2 facing the camera and the light at the origin: triangle 0 has a 4x4
    texture (texel centres sample the texel itself), triangle 1 a plain colour and an emission."""
    quad, texels, plain = textured_quad()
    power = 0.3
    scene = Scene(objects=[quad], lights=[PointLight(np.zeros(3), np.ones(3), power)])
    targets, rows, cols, textured = texel_centres()
    out = trace(torus, scene, targets, shade=True, light_reach=0.5)  # the light's own copy only
    r = np.linalg.norm(targets, axis=1)
    lambert = power * (0.2 / r) / r**2  # cos / r^2 for a point light in E3
    expected = np.where(
        textured[:, None],
        texels[rows, cols] * lambert[:, None],
        plain.color * lambert[:, None] + plain.emission,
    )
    np.testing.assert_allclose(out["color"], expected, rtol=1e-4)


def test_bad_surfaces_are_named():
    V, T = np.eye(3), [[0, 1, 2]]
    with pytest.raises(SceneError, match=r"object 'q': corner_uvs must have shape \(1, 3, 2\)"):
        SceneObject("q", V, T, corner_uvs=np.zeros((2, 3, 2)))
    with pytest.raises(SceneError, match="object 'q': triangle_material refers to a material it does not have"):
        SceneObject("q", V, T, triangle_material=[1], materials=[Material()])
    with pytest.raises(SceneError, match="texture file '/nowhere/t.png' does not exist"):
        Material(color_texture="/nowhere/t.png")
    # a texture on an object without UVs reads UV (0, 0), as an OBJ corner without vt (it was refused)
    tracer = render.make_tracer(
        spaces.load("torus"),
        Scene(objects=[SceneObject("q", V * 0.1, T, materials=[Material(color_texture=np.ones((2, 2, 3)))])]),
    )
    assert tracer.num_triangles == 1


def test_clean_keeps_the_surface_arrays_with_their_triangles():
    V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]]
    T = [[0, 1, 2], [0, 1, 3], [1, 2, 0]]  # the middle one is degenerate
    normals = np.arange(27, dtype=float).reshape(3, 3, 3) + 1
    obj = SceneObject(
        "o",
        V,
        T,
        corner_normals=normals,
        corner_uvs=normals[..., :2],
        triangle_material=[0, 1, 0],
        materials=[Material(), Material()],
    )
    with pytest.warns(UserWarning, match="skipped 1 degenerate"):
        clean(obj, "test")
    np.testing.assert_array_equal(obj.corner_normals, normals[[0, 2]])
    np.testing.assert_array_equal(obj.corner_uvs, normals[[0, 2], :, :2])
    np.testing.assert_array_equal(obj.triangle_material, [0, 0])


# --- mesh files ----------------------------------------------------------------------------------
def write_png(path, pixels):
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], "uint8"))
    out.write_image(pixels)
    out.close()


BYTES = np.array([[[255, 0, 0], [0, 128, 0]], [[0, 0, 64], [200, 200, 200]]], np.uint8)


def test_obj_normals_uvs_texture_and_materials_per_face(tmp_path):
    write_png(tmp_path / "checker.png", BYTES)
    (tmp_path / "m.mtl").write_text("newmtl tex\nKd 0.5 0.5 0.5\nmap_Kd checker.png\nnewmtl blue\nKd 0.1 0.2 0.9\n")
    (tmp_path / "m.obj").write_text("""mtllib m.mtl
o quad
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
vn 0.6 0 0.8
usemtl tex
f 1/1/1 2/2/2 3/3/1
usemtl blue
f 1//2 3//1 4//2
""")
    (obj,) = load_mesh_file(tmp_path / "m.obj")
    assert obj.name == "quad"
    np.testing.assert_allclose(
        obj.corner_normals, [[[0, 0, 1], [0.6, 0, 0.8], [0, 0, 1]], [[0.6, 0, 0.8], [0, 0, 1], [0.6, 0, 0.8]]]
    )
    np.testing.assert_allclose(obj.corner_uvs, [[[0, 0], [1, 0], [1, 1]], [[0, 0], [0, 0], [0, 0]]])
    np.testing.assert_array_equal(obj.triangle_material, [0, 1])
    tex, blue = obj.materials
    np.testing.assert_allclose(tex.color, 1)  # as Blender imports it: the texture replaces Kd
    np.testing.assert_allclose(tex.color_texture, srgb_to_linear(BYTES / 255.0), atol=1e-6)
    np.testing.assert_allclose(blue.color, [0.1, 0.2, 0.9])
    assert blue.color_texture is None
    (tmp_path / "m.mtl").write_text("newmtl tex\nmap_Kd gone.png\n")
    with pytest.raises(SceneError, match=r"m\.mtl:2: map_Kd '.*gone\.png' does not exist"):
        load_mesh_file(tmp_path / "m.obj")


def test_glb_normals_uvs_and_base_colour_factor(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    uv = np.random.default_rng(1).uniform(size=(len(mesh.vertices), 2))
    normals = mesh.vertices / 0.1
    material = trimesh.visual.material.PBRMaterial(name="paint", baseColorFactor=[0.2, 0.4, 0.6, 1.0])
    glb = trimesh.Trimesh(
        mesh.vertices,
        mesh.faces,
        vertex_normals=normals,
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
    )
    glb.export(tmp_path / "ball.glb")
    (obj,) = load_mesh_file(tmp_path / "ball.glb")
    np.testing.assert_allclose(obj.corner_normals, normals[mesh.faces], atol=1e-6)
    np.testing.assert_allclose(obj.corner_uvs, uv[mesh.faces], atol=1e-6)
    np.testing.assert_allclose(obj.materials[0].color, [0.2, 0.4, 0.6], atol=1 / 255)
    flat = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    flat.export(tmp_path / "flat.glb")
    assert load_mesh_file(tmp_path / "flat.glb")[0].corner_normals is None  # glTF without normals: flat


def test_gltf_base_colour_texture(tmp_path):
    """A glTF written by hand: one triangle with TEXCOORD_0 and a base colour texture in a PNG."""
    write_png(tmp_path / "tex.png", BYTES)
    # glTF: v down from the top
    blob = triangle_blob([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0], [1, 0], [0, 1]])
    gltf = textured_triangle(embedded(blob), "tex.png", top=1.0, byte_length=len(blob))
    (tmp_path / "tri.gltf").write_text(json.dumps(gltf))
    (obj,) = load_mesh_file(tmp_path / "tri.gltf")
    np.testing.assert_allclose(obj.materials[0].color_texture, srgb_to_linear(BYTES / 255.0), atol=1e-6)
    np.testing.assert_allclose(obj.corner_uvs[0], [[0, 1], [1, 1], [0, 0]], atol=1e-6)  # v up


# --- copies in curved spaces ---------------------------------------------------------------------
@pytest.mark.parametrize("space_id", ["nil", "poincare"])
def test_copies_carry_flat_corner_normals_to_the_geometric_normal(space_id):
    """A box sticking out of the domain (so its copies are drawn), once with corner normals equal
    to its faces' and once without: the shading normals of every copy are the geometric ones."""
    space = spaces.load(space_id)
    box = trimesh.creation.box(extents=[0.6 * space.chart_inradius] * 3)
    face = space.domain.vertices[np.argmax(space.domain.vertices[:, 0])]
    V = box.vertices + 0.9 * face
    P = V[box.faces]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    plain = SceneObject("box", V, box.faces)
    shaded = SceneObject("box", V, box.faces, corner_normals=np.repeat(n[:, None], 3, axis=1))
    assert len(render.compile_scene(space, Scene(objects=[plain]))["triangles"]) > len(box.faces)  # copies
    settings = render.Settings(width=40, height=24, quality="draft", shading="normal")
    a, b = (render.render(space, Scene(objects=[o]), settings).passes for o in (plain, shaded))
    hit = a["stop"] == 0
    assert hit.mean() > 0.3
    np.testing.assert_allclose(np.linalg.norm(b["normal"][hit], axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(b["normal"][hit], a["normal"][hit], atol=1e-4)


def test_transparent_alpha_is_zero_where_nothing_is_hit(torus):
    scene = Scene(objects=[sphere(True)], lights=[PointLight(np.zeros(3))])
    settings = render.Settings(width=32, height=18, quality="standard", max_distance=0.4, transparent=True)
    p = render.render(torus, scene, settings).passes
    missed, hit = ~np.isfinite(p["depth"]), np.isfinite(p["depth"])
    assert missed.any() and hit.any()
    # the centre ray and the four samples agree away from the silhouette; edges are partly covered
    assert np.mean(p["alpha"][missed] == 0) > 0.8 and np.mean(p["alpha"][hit] == 1) > 0.8
    assert np.all((p["alpha"] >= 0) & (p["alpha"] <= 1))
    np.testing.assert_array_equal(p["color"][p["alpha"] == 0], 0)
