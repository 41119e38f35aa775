"""Instancing: a mesh placed by many chart-affine maps is stored once in the core (Embree
instances) and renders as the same mesh copied (flattened) would, and as closed forms say."""

import math

import numpy as np
import pytest
import thurston_core as _core
import trimesh

from thurston_addon import render, scenes, spaces
from thurston_addon.scenes import Camera, PointLight, Scene, SceneError, SceneObject

RADIUS = 0.01
BALL = trimesh.creation.icosphere(subdivisions=2, radius=RADIUS)
# how far the icosphere's faces lie inside its sphere: a depth straight at a ball is within this
# of (distance - radius)
SAGITTA = RADIUS - float(np.min(np.abs(np.einsum("ij,ij->i", BALL.face_normals, BALL.triangles_center))))


def space(name):
    return spaces.load(spaces.preset_path(name))


def translations(points):
    A = np.broadcast_to(np.eye(4), (len(points), 4, 4)).copy()
    A[:, :3, 3] = points
    return A


def grid(n, z, half, at=0.5):
    """n x n points over the square [-half, half]^2 at height z, at this fraction of each cell."""
    c = -half + (np.arange(n) + at) * 2 * half / n
    x, y = np.meshgrid(c, c, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.full(n * n, z)], axis=1)


def trace_at(sp, sc, origin, targets, max_distance=3.0):
    """Depths of rays from the chart point `origin` towards the chart points `targets`."""
    g = sp.geometry
    tracer = render.make_tracer(sp, sc, threads=2)
    x = np.broadcast_to(np.asarray(origin, float), (len(targets), 3))
    X = np.ascontiguousarray(g.to_model(x))
    D = np.ascontiguousarray(g.normalize_tangent(X, g.tangent_to_model(x, np.asarray(targets) - x)))
    return render.trace(tracer, X, D, max_distance, 8, 1e-6, shade=False)


def rare(differs):
    return np.mean(differs) < 1e-3


def compare_passes(sp, instanced, camera, size=(96, 72)):
    flat = Scene([o.placed() for o in instanced.objects], instanced.lights, camera)
    # chords within 1e-4 of the curve (curved geometries): the two scenes' occupancy grids differ
    # (instance boxes, triangle boxes), so coarse chords may move a silhouette differently within
    # the quality's tolerance
    settings = render.Settings(width=size[0], height=size[1], quality="draft", tolerance=1e-4)
    a = render.render(sp, Scene(instanced.objects, instanced.lights, camera), settings)
    b = render.render(sp, flat, settings)
    hit = np.isfinite(b.passes["depth"])
    assert hit.mean() > 0.05  # the test sees something
    np.testing.assert_array_equal(np.isfinite(a.passes["depth"]), hit)
    # A ray through a mesh edge may meet either triangle (Embree's float ray against float
    # vertices, or against the float instance map): their depths agree to ~1e-7, their normals
    # are the neighbouring faces'. So a few pixels may differ in the normal.
    np.testing.assert_allclose(a.passes["depth"][hit], b.passes["depth"][hit], rtol=0, atol=1e-6)
    assert rare(np.abs(a.passes["normal"][hit] - b.passes["normal"][hit]).max(axis=-1) > 1e-5)
    np.testing.assert_array_equal(a.passes["object"], b.passes["object"])
    # and shadow rays grazing an edge may go either way: a few pixels of the colour, in proportion
    # to the shadow rays a point has
    differs = np.abs(a.passes["color"] - b.passes["color"]).max(axis=-1) > 1e-5
    assert np.mean(differs) < 1e-3 * max(1.0, a.stats["light_paths_per_point"])
    return a, b


def test_torus_grid_of_instanced_spheres_renders_as_flattened_copies():
    sp = space("torus")
    # 20 x 20 balls, the last ones through the faces x, y = 0.5 (their copies re-enter at -0.5)
    points = grid(20, 0.15, half=0.5, at=0.9)
    ball = SceneObject("ball", BALL.vertices, BALL.faces, instances=translations(points))
    sc = Scene([ball], [PointLight(np.array([0, 0, -0.2]))])
    camera = Camera(np.zeros(3), np.array([0.1, 0.2, 1.0]), np.array([0, 1.0, 0]), 100)
    a, b = compare_passes(sp, sc, camera)
    assert a.stats["triangles"] == len(BALL.faces)  # the mesh once ...
    assert b.stats["triangles"] > 400 * len(BALL.faces)  # ... where the flattened copies hold 400 and more
    # the copies through the faces place the whole mesh (flattened copies keep the triangles that
    # can meet the domain)
    assert a.stats["instanced_triangles"] == (a.stats["instances"] - 1) * len(BALL.faces) >= b.stats["triangles"]


def test_depths_straight_at_instanced_spheres_are_distance_minus_radius():
    sp = space("torus")
    points = grid(20, 0.3, half=0.4)
    ball = SceneObject("ball", BALL.vertices, BALL.faces, instances=translations(points))
    out = trace_at(sp, Scene([ball]), np.zeros(3), points)
    expected = np.linalg.norm(points, axis=1) - RADIUS
    assert np.all(out["stop"] == 0)
    assert np.all(out["depth"] >= expected - 1e-12) and np.all(out["depth"] <= expected + SAGITTA)


def test_rotated_non_uniformly_scaled_instance_has_the_inverse_transpose_normal():
    """A square in the plane x + y = 0 of its mesh, placed by A = translation R S: its chart plane
    has the normal L^-T n (not L n); with corner normals n the shading normal is the same."""
    sp = space("torus")
    s = 0.2
    V = np.array([[s, -s, -s], [-s, s, -s], [-s, s, s], [s, -s, s]])
    T = np.array([[0, 1, 2], [0, 2, 3]])
    n = np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    c, si = math.cos(0.7), math.sin(0.7)
    L = np.array([[c, -si, 0], [si, c, 0], [0, 0, 1]]) @ np.diag([0.3, 1.5, 0.8])
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = L, [0.1, 0.05, 0.0]
    expected = np.linalg.solve(L.T, n)
    expected /= np.linalg.norm(expected)
    for normals in (None, np.broadcast_to(n, (2, 3, 3))):
        sq = SceneObject("square", V, T, corner_normals=normals, instances=A[None])
        origin = np.array([0.1, 0.05, 0.0]) - 0.3 * expected
        out = trace_at(sp, Scene([sq]), origin, (origin + expected)[None])
        assert out["stop"][0] == 0
        assert out["depth"][0] == pytest.approx(0.3, abs=1e-12)  # the plane through the translation
        np.testing.assert_allclose(out["normal"][0], -expected, atol=1e-6)  # facing the ray


@pytest.mark.parametrize("name", ["poincare", "nil", "genus2xs1"])
def test_instances_render_as_flattened_copies_in_curved_spaces(name):
    sp = space(name)
    inr = sp.chart_inradius
    # balls on a ring around the camera's axis, one pushed through a face (its copies re-enter)
    angles = np.linspace(0, 2 * math.pi, 9)[:-1]
    points = np.stack([0.5 * inr * np.cos(angles), 0.5 * inr * np.sin(angles), np.full(8, 0.5 * inr)], axis=1)
    c = sp.domain.covectors()[0]
    points[0] = c[:3] / np.linalg.norm(c[:3]) * (-c[3] / np.linalg.norm(c[:3]) + RADIUS)
    L = np.diag([2.0, 1.0, 3.0]) * inr / space("poincare").chart_inradius  # ellipsoids, sized to the domain
    A = translations(points)
    A[:, :3, :3] = L
    obj = SceneObject("ball", BALL.vertices, BALL.faces, instances=A)
    sc = Scene([obj], [PointLight(np.array([0.0, 0.0, -0.1 * inr]))])
    camera = Camera(np.zeros(3), np.array([0, 0, 1.0]), np.array([0, 1.0, 0]), 110)
    a, _ = compare_passes(sp, sc, camera)
    if not sp.geometry.affine_isometries:  # the copies through the face are flattened, the rest instances
        assert a.stats["triangles"] > len(BALL.faces)
    else:
        assert a.stats["triangles"] == len(BALL.faces)


def test_closed_form_first_hits_in_poincare_and_nil():
    """Straight up the z axis from the origin: S3's gnomonic chart puts the chart point (0, 0, z)
    at distance atan z; in Nil the z axis is a geodesic of length z."""
    for name, distance in (("poincare", math.atan), ("nil", lambda z: z)):
        sp = space(name)
        z = 0.6 * sp.chart_inradius
        ball = SceneObject("ball", BALL.vertices, BALL.faces, instances=translations([[0, 0, z]]))
        out = trace_at(sp, Scene([ball]), np.zeros(3), np.array([[0, 0, z]]))
        assert out["stop"][0] == 0
        assert distance(z - RADIUS) - 1e-9 <= out["depth"][0] <= distance(z - RADIUS + SAGITTA) + 1e-9


def test_ten_thousand_instances_hold_the_mesh_once():
    sp = space("torus")
    points = grid(100, 0.0, half=0.45)
    ball = SceneObject("ball", BALL.vertices, BALL.faces, instances=translations(points))
    data = render.compile_scene(sp, Scene([ball]))
    nt, nv = len(BALL.faces), len(BALL.vertices)
    assert data["triangles"].shape == (nt, 3) and data["vertices"].shape == (nv, 3)
    assert data["triangle_material"].shape == (nt,)
    assert data["instance_transform"].shape == (1 + 10_000, 3, 4)  # the (empty) flat mesh and the balls
    tracer = _core.Tracer(render.core_scene(data))
    assert tracer.num_triangles == nt
    assert tracer.num_instanced_triangles == 10_000 * nt


def test_emissive_instances_cast_no_shadows():
    """A lamp instanced around a light does not shadow it; the same mesh not emitting does."""
    sp = space("torus")
    shell = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    floor = SceneObject(
        "floor", [[-0.4, -0.4, -0.2], [0.4, -0.4, -0.2], [0.4, 0.4, -0.2], [-0.4, 0.4, -0.2]], [[0, 1, 2], [0, 2, 3]]
    )
    for emission, lit in ((np.ones(3), True), (np.zeros(3), False)):
        lamp = SceneObject("lamp", shell.vertices, shell.faces, emission=emission, instances=translations([[0, 0, 0]]))
        tracer = render.make_tracer(sp, Scene([floor, lamp], [PointLight(np.zeros(3))]), threads=1)
        X = np.array([[0.0, 0.0, -0.1, 1.0]])
        out = render.trace(tracer, X, np.array([[0.0, 0.0, -1.0, 0.0]]), 1.0, 4)
        assert out["object"][0] == 0 and (out["color"][0].max() > 0) == lit


@pytest.mark.parametrize(
    "value, message",
    [
        (np.full((1, 4, 4), np.nan), "instance 0 has a NaN"),
        (np.zeros((1, 4, 4)) + np.diag([1, 1, 0, 1]), "instance 0 has a singular transform"),
        (np.ones((1, 4, 4)), "instance 0 is not affine"),
        (np.eye(3)[None], r"instance transforms must have shape \(k, 4, 4\)"),
    ],
)
def test_bad_instance_transforms_name_the_object(value, message):
    with pytest.raises(SceneError, match=f"object 'ball': {message}"):
        SceneObject("ball", BALL.vertices, BALL.faces, instances=value)


def test_core_rejects_singular_and_out_of_range_instances():
    sp = space("torus")
    data = render.compile_scene(sp, Scene([SceneObject("ball", BALL.vertices, BALL.faces, instances=np.eye(4)[None])]))
    singular = data["instance_transform"].copy()
    singular[1, :, :3] = 0
    with pytest.raises(ValueError, match="instance_transform row 1 is singular"):
        _core.Tracer(render.core_scene(data | dict(instance_transform=singular)))
    with pytest.raises(ValueError, match="instance_object row 1 is 5"):
        _core.Tracer(render.core_scene(data | dict(instance_object=np.array([0, 5], np.int32))))
    with pytest.raises(ValueError, match="go together"):
        _core.Tracer(render.core_scene(data | dict(instance_mesh=None)))


def test_scene_file_transforms(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(
        '[[object]]\nprimitive = "sphere"\nradius = 0.05\n'
        "transforms = [[[1, 0, 0, 0.2], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],\n"
        "              [[2, 0, 0, -0.2], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]]\n"
    )
    (obj,) = scenes.load_scene_file(path).objects
    assert obj.instances.shape == (2, 4, 4) and obj.instances[1, 0, 0] == 2
    path.write_text(
        '[[object]]\nprimitive = "sphere"\ntransforms = [[[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]]\n'
    )
    with pytest.raises(SceneError, match="object 0: object 'sphere': instance 0 has a singular transform"):
        scenes.load_scene_file(path)


def test_camera_inside_an_instance_is_noted_in_its_placement():
    """The check looks for the camera in every placement of the mesh, not in the mesh where its
    own coordinates would put it."""
    from thurston_addon import checks

    sp = space("torus")
    ball = SceneObject("ball", BALL.vertices, BALL.faces, instances=translations([[0.2, 0, 0], [0, 0.3, 0]]))
    notes = lambda position: {
        n.kind
        for n in checks.before_render(
            sp,
            Scene([ball]),
            Camera(np.asarray(position, float), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])),
            lambert=False,
        )
    }
    assert checks.CAMERA_IN_OBJECT in notes([0.0, 0.3, 0.0])
    assert checks.CAMERA_IN_OBJECT not in notes([0.0, 0.0, 0.0])  # where the mesh itself lies
