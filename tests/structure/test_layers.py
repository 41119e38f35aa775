"""The package's layers, read from the source with `ast` (nothing is imported): the bpy-free library
never imports Blender's modules or the Blender layer (blender/, operators/, panels/), except the command
line's render-blend, which imports it inside its function; and no module imports, directly or through
others, itself. A module is a .py file or a package (its __init__.py), whichever the tree holds."""

import ast
from pathlib import Path

PACKAGE = "thurston_addon"
ROOT = Path(__file__).resolve().parents[2] / PACKAGE
BLENDER_LAYER = ("blender", "operators", "panels")
# Modules that exist only inside Blender (the bpy wheel and Blender's own Python).
BLENDER_MODULES = {
    "bpy",
    "bpy_extras",
    "bl_operators",
    "bl_ui",
    "bmesh",
    "mathutils",
    "gpu",
    "gpu_extras",
    "idprop",
    "aud",
    "freestyle",
}
# The one place the library reaches the Blender layer: render-blend, importing it when it runs.
LAZY_BLENDER_IMPORTS = {(f"{PACKAGE}.cli", "cmd_render_blend")}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts}


def is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def imports(name: str):
    """(imported module, enclosing function or None) for each import in the module: `from X import y`
    names X.y where that is a module of the tree, else X; relative imports are resolved."""
    tree = ast.parse(MODULES[name].read_text(), filename=str(MODULES[name]))
    package = name if is_package(name) else name.rpartition(".")[0]

    def visit(node, function):
        for child in ast.iter_child_nodes(node):
            inner = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else function
            if isinstance(child, ast.Import):
                for alias in child.names:
                    yield alias.name, function
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")[: len(package.split(".")) - (child.level - 1)]
                    source = ".".join(base + ([child.module] if child.module else []))
                else:
                    source = child.module
                for alias in child.names:
                    yield (f"{source}.{alias.name}" if f"{source}.{alias.name}" in MODULES else source), function
            yield from visit(child, inner)

    yield from visit(tree, None)


def in_blender_layer(name: str) -> bool:
    parts = name.split(".")
    return parts[0] == PACKAGE and len(parts) > 1 and parts[1] in BLENDER_LAYER


def library_modules():
    return [name for name in MODULES if name != PACKAGE and not in_blender_layer(name)]


def test_the_tree_is_read():
    """The reading finds the layers it checks (a guard against a check that passes on nothing)."""
    assert {f"{PACKAGE}.cli", f"{PACKAGE}.blender.registration", f"{PACKAGE}.blender.export"} <= set(MODULES)
    assert any(name.startswith(f"{PACKAGE}.geometries.") for name in MODULES)
    edges = {(name, imported) for name in MODULES for imported, _ in imports(name)}
    assert (f"{PACKAGE}.blender.domain_guide", f"{PACKAGE}.blender.export") in edges
    assert (f"{PACKAGE}.blender.export.surfaces", f"{PACKAGE}.images") in edges
    assert (f"{PACKAGE}.cli", f"{PACKAGE}.blender.batch") in edges


def test_the_library_never_imports_blender():
    found = []
    for name in library_modules():
        for imported, function in imports(name):
            if (name, function) in LAZY_BLENDER_IMPORTS:
                continue
            if imported.split(".")[0] in BLENDER_MODULES or in_blender_layer(imported):
                found.append(f"{name} imports {imported}" + (f" (in {function})" if function else ""))
    assert not found, found


def test_no_two_modules_share_a_name():
    """A module's name (a file's stem, a package's folder) says what it is, once: `render` is the
    library's render pipeline, not also a panel."""
    by_name = {}
    for name in MODULES:
        if name != PACKAGE:
            by_name.setdefault(name.rpartition(".")[2], []).append(name)
    assert not {leaf: names for leaf, names in by_name.items() if len(names) > 1}


def test_nothing_imports_the_entry():
    """thurston_addon/__init__.py is the top: Blender's entry, delegating to blender.registration."""
    found = [name for name in MODULES for imported, _ in imports(name) if imported == PACKAGE]
    assert not found, found


def test_no_import_cycle():
    """Depth-first search over every import, at module level or inside a function (one inside a
    function is still a dependency, only a later one)."""
    graph = {
        name: sorted({imported for imported, _ in imports(name) if imported in MODULES and imported != name})
        for name in MODULES
    }
    state = {}  # name -> "open" while on the current path, "done" after

    def walk(name, path):
        state[name] = "open"
        for nxt in graph[name]:
            if state.get(nxt) == "open":
                return path[path.index(nxt) :] + [nxt] if nxt in path else [name, nxt]
            if nxt not in state:
                cycle = walk(nxt, path + [nxt])
                if cycle:
                    return cycle
        state[name] = "done"
        return None

    for name in sorted(graph):
        if name not in state:
            cycle = walk(name, [name])
            assert cycle is None, " -> ".join(cycle)
