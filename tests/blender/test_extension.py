"""The Blender extension: build the zip with scripts/build_extension.py, validate it with Blender's
own tool, install it into a fresh bpy process, render through it, disable it.

The bpy process is sanitised so that it can only see what Blender itself would bring: Python runs
with -S (no site-packages, so neither the dev install of thurston_core nor the editable import
finder of scikit-build-core) and a folder holding only bpy and the packages Blender bundles
(numpy, requests, zstandard, ...). thurston_core, scipy, OpenImageIO and trimesh can then only come
from the extension's wheels. Blender's user folders (config, scripts, extensions) and HOME are
temporary.
"""

from __future__ import annotations

import glob
import importlib.util
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BUILD = ROOT / "scripts" / "build_extension.py"

BPY_SPEC = importlib.util.find_spec("bpy")
# slow: every test needs the extension built (about two minutes)
pytestmark = [
    pytest.mark.skipif(BPY_SPEC is None, reason="bpy is not installed (pip install -r requirements.txt)"),
    pytest.mark.slow,
]

# What Blender's bundled Python holds besides the standard library (and what the bpy wheel requires).
BLENDER_BUNDLED = [
    "bpy",
    "numpy",
    "numpy.libs",
    "zstandard",
    "requests",
    "urllib3",
    "idna",
    "certifi",
    "charset_normalizer",
]

CHILD = r"""
import json, math, os, sys
zip_path, out_dir, site_dir = sys.argv[1:4]
sys.path.insert(0, site_dir)
report = {"sys_path": list(sys.path), "meta_path": [repr(f) for f in sys.meta_path]}

import bpy
import addon_utils
import numpy as np

NAME = "bl_ext.user_default.thurston"


def operators():
    return {f"{m}.{o}" for m in dir(bpy.ops) for o in dir(getattr(bpy.ops, m))}


def engines():
    return {i.identifier for i in bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items}


def compat_engines():
    return {p.__name__ for p in bpy.types.Panel.__subclasses__() if "THURSTON" in getattr(p, "COMPAT_ENGINES", ())}


types_before, ops_before, engines_before = set(dir(bpy.types)), operators(), engines()
report["types_before_has_scene_thurston"] = hasattr(bpy.types.Scene, "thurston")

report["install"] = sorted(bpy.ops.extensions.package_install_files(
    repo="user_default", filepath=zip_path, enable_on_install=True))
report["enabled"] = NAME in bpy.context.preferences.addons
report["check"] = list(addon_utils.check(NAME))
report["site_packages"] = os.path.join(os.environ["BLENDER_USER_EXTENSIONS"], ".local", "lib",
                                       "python3.11", "site-packages")
report["new_types"] = sorted(set(dir(bpy.types)) - types_before)
report["new_ops"] = sorted(operators() - ops_before)
report["new_engines"] = sorted(engines() - engines_before)

import thurston_core
report["core_file"] = thurston_core.__file__
pkg = sys.modules[NAME]
report["pkg_file"] = pkg.__file__

# first use: Blender's startup scene (cube, light, camera), engine switched to Thurston, F12; then the
# fix the report names, and F12 again
sc = bpy.context.scene
report["first_use_objects"] = sorted(o.name for o in sc.objects)
sc.render.engine = "THURSTON"
sc.render.resolution_percentage = 5
if hasattr(sc.render.image_settings, "media_type"):
    sc.render.image_settings.media_type = "IMAGE"
sc.render.image_settings.file_format = "OPEN_EXR"
sc.render.filepath = os.path.join(out_dir, "first.exr")
bpy.ops.render.render(write_still=True)
report["first_use_notes"] = [[n.kind, n.message] for n in sc.thurston.stats.notes]
report["fit_scale"] = sorted(bpy.ops.thurston.fit_scale())
sc.render.filepath = os.path.join(out_dir, "fitted.exr")
bpy.ops.render.render(write_still=True)
report["fitted_notes"] = [n.kind for n in sc.thurston.stats.notes]
import OpenImageIO
fitted = OpenImageIO.ImageBuf(sc.render.filepath).get_pixels(OpenImageIO.FLOAT)
report["fitted_lit"] = float((fitted[..., :3].max(axis=-1) > 0.05).mean())

report["operator"] = hasattr(bpy.ops.thurston, "render_view")
exr = os.path.join(out_dir, "view.exr")
if report["operator"]:
    sc = bpy.context.scene
    for ob in list(bpy.data.objects):
        if ob.type == "MESH":
            bpy.data.objects.remove(ob)
    bpy.ops.mesh.primitive_ico_sphere_add(radius=0.1, location=(0.3, 0.0, 0.0))
    sc.camera.location = (0.0, 0.0, 0.0)
    sc.camera.rotation_euler = (math.pi / 2, 0.0, -math.pi / 2)  # looking along +X
    sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 32, 18, 100
    t = sc.thurston
    t.space, t.quality, t.shading = "torus", "draft", "normal"
    t.save_path, t.overwrite = exr, True
    report["render"] = sorted(bpy.ops.thurston.render_view())
    image = bpy.data.images["Thurston View"]
    px = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(px)
    color = px.reshape(-1, 4)[:, :3]
    report["size"] = list(image.size)
    report["summary"] = t.stats.summary
    # saved twice and reopened: the view keeps its pixels, the scene its settings
    blend = os.path.join(out_dir, "saved.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=blend)
    reopened = bpy.data.images.get("Thurston View")
    again = np.zeros(len(px), np.float32)
    if reopened is not None and len(reopened.pixels) == len(px):
        reopened.pixels.foreach_get(again)
    report["reopened_same"] = bool(reopened is not None and np.array_equal(again, px))
    report["reopened_space"] = bpy.context.scene.thurston.space
else:  # the Blender layer's operators are not there yet: the package's own API
    import importlib
    spaces = importlib.import_module(NAME + ".spaces")
    scenes = importlib.import_module(NAME + ".scenes")
    render = importlib.import_module(NAME + ".render")
    images = importlib.import_module(NAME + ".images")
    space = spaces.load("torus")
    result = render.render(space, scenes.default_scene(space),
                           render.Settings(width=32, height=18, quality="draft", shading="normal"))
    images.write(exr, result.passes)
    color = result.passes["color"]
    report["render"] = ["FINISHED"]
    report["size"] = [color.shape[1], color.shape[0]]
    report["summary"] = result.summary()
report["color_std"] = float(np.nan_to_num(color).std())
report["exr_size"] = os.path.getsize(exr) if os.path.exists(exr) else 0

import OpenImageIO, scipy, trimesh
report["dep_files"] = {m.__name__: m.__file__ for m in (OpenImageIO, scipy, trimesh)}
report["tbb"] = sorted({line.split()[-1] for line in open("/proc/self/maps") if "libtbb" in line})

addon_utils.disable(NAME, default_set=True)
report["enabled_after_disable"] = NAME in bpy.context.preferences.addons
report["left_types"] = sorted(set(dir(bpy.types)) - types_before)
report["left_ops"] = sorted(operators() - ops_before)
report["left_engines"] = sorted(engines() - engines_before)
report["left_compat_engines"] = sorted(compat_engines())
report["scene_attr_left"] = hasattr(bpy.types.Scene, "thurston")
report["scene_rna_left"] = "thurston" in bpy.types.Scene.bl_rna.properties
print("REPORT " + json.dumps(report))
"""


def blender_ext_cli() -> Path:
    base = Path(list(BPY_SPEC.submodule_search_locations)[0])
    (cli,) = glob.glob(str(base / "*" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"))
    return Path(cli)


@pytest.fixture(scope="session")
def extension_zip(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run([sys.executable, str(BUILD), "--out", str(out)], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    zips = list(out.glob("thurston-*.zip"))
    assert len(zips) == 1, (zips, proc.stdout)
    assert str(zips[0]) in proc.stdout  # the script names what it built
    return zips[0]


@pytest.fixture(scope="session")
def installed(extension_zip, tmp_path_factory) -> dict:
    """Install, enable, render, disable in a fresh sanitised bpy process; its report."""
    tmp = tmp_path_factory.mktemp("blender")
    site = tmp / "site"
    site.mkdir()
    venv_site = Path(list(BPY_SPEC.submodule_search_locations)[0]).parent
    for name in BLENDER_BUNDLED:
        if (venv_site / name).exists():
            (site / name).symlink_to(venv_site / name)
    (tmp / "out").mkdir()
    child = tmp / "child.py"
    child.write_text(CHILD)
    env = {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "HOME": str(tmp / "home"),
        "BLENDER_USER_CONFIG": str(tmp / "config"),
        "BLENDER_USER_SCRIPTS": str(tmp / "scripts"),
        "BLENDER_USER_EXTENSIONS": str(tmp / "extensions"),
        "BLENDER_USER_DATAFILES": str(tmp / "datafiles"),
        "TMPDIR": str(tmp),
    }
    proc = subprocess.run(
        [sys.executable, "-S", "-s", str(child), str(extension_zip), str(tmp / "out"), str(site)],
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("REPORT ")]
    assert proc.returncode == 0 and lines, proc.stdout[-4000:] + proc.stderr[-4000:]
    report = json.loads(lines[-1][len("REPORT ") :])
    report["tmp"] = str(tmp)
    return report


def test_validator_accepts_zip(extension_zip):
    proc = subprocess.run(
        [sys.executable, str(blender_ext_cli()), "validate", str(extension_zip)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_zip_layout(extension_zip):
    with zipfile.ZipFile(extension_zip) as z:
        names = z.namelist()
        manifest = z.read("blender_manifest.toml").decode()
    import tomllib

    m = tomllib.loads(manifest)
    root = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    for key in ("id", "version", "name", "type", "blender_version_min", "platforms", "permissions"):
        assert m[key] == root[key]
    assert m["id"] == "thurston" and m["type"] == "add-on" and m["platforms"] == ["linux-x64"]
    assert extension_zip.name == f"thurston-{root['version']}.zip"
    # every wheel listed is in the zip, and every wheel in the zip is listed
    listed = {w.removeprefix("./") for w in m["wheels"]}
    assert listed == {n for n in names if n.endswith(".whl")}
    core = [w for w in listed if w.startswith("wheels/thurston_core-")]
    assert len(core) == 1 and "-cp311-cp311-manylinux_" in core[0] and core[0].endswith("_x86_64.whl")
    for dep in ("scipy", "openimageio", "trimesh"):
        assert any(w.startswith(f"wheels/{dep}-") for w in listed), dep
    assert not any(w.startswith("wheels/numpy-") for w in listed)  # Blender's own numpy
    # the add-on package's contents are the root; nothing from dev builds
    assert "__init__.py" in names and "spaces/__init__.py" in names and "presets/poincare.toml" in names
    assert not any("__pycache__" in n or n.endswith((".pyc", ".so")) for n in names)
    assert not any(n.startswith("thurston_addon/") for n in names)


def test_core_wheel_uses_blenders_tbb(extension_zip, tmp_path):
    """libembree3 is vendored; libtbb.so.12 is not (Blender's oneTBB serves it)."""
    with zipfile.ZipFile(extension_zip) as z:
        (core,) = [n for n in z.namelist() if n.startswith("wheels/thurston_core-")]
        z.extract(core, tmp_path)
    with zipfile.ZipFile(tmp_path / core) as w:
        libs = [n for n in w.namelist() if n.startswith("thurston_core.libs/")]
    assert any("libembree3" in n for n in libs), libs
    assert not any("libtbb" in n for n in libs), libs


def test_install_enables_addon(installed):
    r = installed
    assert r["install"] == ["FINISHED"]
    assert r["enabled"] and r["check"] == [True, True]
    assert not r["types_before_has_scene_thurston"]
    assert not any("_editable" in f or "ScikitBuild" in f for f in r["meta_path"])
    assert Path(r["pkg_file"]).is_relative_to(Path(r["tmp"]) / "extensions")


def test_core_and_dependencies_come_from_extension_wheels(installed):
    site = Path(installed["site_packages"])
    assert Path(installed["core_file"]).is_relative_to(site), installed["core_file"]
    for name, path in installed["dep_files"].items():
        assert Path(path).is_relative_to(site), (name, path)


def test_one_tbb_runtime_blenders(installed):
    tbb = [p for p in installed["tbb"] if "libtbb." in os.path.basename(p) or "libtbb-" in os.path.basename(p)]
    assert len(tbb) == 1 and "/bpy/" in tbb[0], installed["tbb"]


def test_render_through_addon(installed):
    r = installed
    assert r["render"] == ["FINISHED"], r
    assert r["size"] == [32, 18]
    assert r["color_std"] > 0.01, r["summary"]  # an image, not a constant
    assert r["exr_size"] > 0  # OpenImageIO from the extension wrote it


def test_a_saved_file_reopens_with_its_image_and_settings(installed):
    assert installed["reopened_same"] and installed["reopened_space"] == "torus"


def test_first_use_of_the_startup_scene(installed):
    """F12 on Blender's startup scene says what to change and names the fix; after Fit Scale the
    image shows the lit cube and its copies."""
    r = installed
    assert r["first_use_objects"] == ["Camera", "Cube", "Light"]
    kinds = {kind for kind, _ in r["first_use_notes"]}
    assert kinds == {"scene_too_large"}, r["first_use_notes"]  # the one note; the rest waits for its fix
    assert any("Fit Scale" in message for _, message in r["first_use_notes"])
    assert r["fit_scale"] == ["FINISHED"] and "scene_too_large" not in r["fitted_notes"]
    assert r["fitted_lit"] > 0.2  # the cube and its copies (Fit Scale fits the cube and the light)


def test_disable_leaves_nothing_registered(installed):
    r = installed
    if r["operator"]:  # the Blender layer registered something worth checking
        assert "thurston.render_view" in r["new_ops"]
        assert r["new_types"]
    assert not r["enabled_after_disable"]
    assert r["left_types"] == []
    assert r["left_ops"] == []
    assert r["left_engines"] == []
    assert r["left_compat_engines"] == []
    assert not r["scene_attr_left"] and not r["scene_rna_left"]
