"""What makes a render come out black, empty or not as meant, found before and after it. Each finding
is a Note: a kind (so a front end can offer its fix) and a message saying what to change. No Blender
here: the command line prints the notes as warnings, the Blender layer puts them in its report."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from .scenes import Camera, Scene
from .spaces import Space

CAMERA_OUTSIDE = "camera_outside"
CAMERA_IN_OBJECT = "camera_in_object"
NO_LIGHTS = "no_lights"
UNLIT = "unlit"
SCENE_TOO_LARGE = "scene_too_large"
SCENE_TOO_SMALL = "scene_too_small"
DROPPED = "dropped"  # objects or parts of them not rendered (the message names them)
SCALED_TO_ZERO = "scaled_to_zero"  # objects left out of a frame: scaled to 0 there (named)
EXPOSURE = "exposure"  # the lit surfaces render black or white: the note's value is the exposure to use
NOTHING_HIT = "nothing_hit"  # every ray stopped before a surface (the distance limit, the clip end)
CLAMPED = "clamped"  # pixels whose light summed beyond float32, clamped to its largest value
LONG_WALK = "long_walk"  # the limits let rays that meet nothing walk for hours

# The fastest walk measured (the flat torus, one thread: about 7 million face crossings a second);
# the curved geometries' walks are slower. A render whose rays could cross more faces than
# LONG_WALK_SECONDS of this is said before it starts.
CROSSINGS_PER_SECOND = 1e7
LONG_WALK_SECONDS = 600.0

# Fog dims a surface at depth d by exp(-d / fog): beyond this many fog distances it shows black.
FOG_BLACK = 80.0
# A spot cone narrower than this (full angle, radians) lights next to nothing.
NARROW_SPOT = 1e-6

# An object whose chart diagonal exceeds the domain's this many times fills the domain with its
# overlapping copies (one the domain's size, as its edges, does not); a scene smaller than
# 1/TOO_SMALL of the domain shows as specks.
TOO_LARGE = 2.0
TOO_SMALL = 200.0
# The scene's size after Fit Scale: this fraction of the domain's inscribed ball's diameter.
FIT_FRACTION = 0.6


# The exposure a front end proposes brings the lit surfaces' median (linear, luminance) to mid grey;
# it proposes one where that median, after the exposure already set, is below EXPOSURE_DARK or above
# EXPOSURE_BRIGHT (black, or white under Blender's Standard view: 0.8 shows as 0.9).
MID_GREY = 0.18
EXPOSURE_DARK = 0.005
EXPOSURE_BRIGHT = 0.8
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709


@dataclass(frozen=True)
class Note:
    kind: str
    message: str
    value: float | None = None  # what the fix sets, where it is a number (EXPOSURE: the stops)


HOME_SAMPLE = 1000  # vertices an object's home is chosen by


def home_element(space: Space, vertices) -> np.ndarray:
    """The isometry that brings an object (chart vertices) home: the one that brings the most of
    its vertices (up to HOME_SAMPLE of them, evenly taken) into the domain. (Its centre will not do
    where the chart mean is no point of the object's region: S2xR's great circles average to the
    chart's missing origin.) Raises SpaceError if a vertex cannot be brought in."""
    g = space.geometry
    V = np.asarray(vertices, float)
    sample = V[:: max(1, len(V) // HOME_SAMPLE)]
    M = space.move_inside(g.to_model(sample))[2]
    keys = [g.element_key(m) for m in M]
    best, _ = Counter(keys).most_common(1)[0]
    return g.reorthonormalize(M[keys.index(best)])


def home_elements(space: Space, centres) -> np.ndarray:
    """The home elements (k, 4, 4) of objects with these chart centres, all at once; objects with
    the same home share one exact isometry."""
    g = space.geometry
    M = space.move_inside(g.to_model(np.asarray(centres, float)))[2]
    keys, inverse = np.unique(np.round(M.reshape(len(M), 16), 9), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    first = np.unique(inverse, return_index=True)[1]
    return np.array([g.reorthonormalize(M[i]) for i in first])[inverse]


# Fit Scale keeps the scene's lights and camera this far inside a bounded chart (the Klein ball of
# H3, the disk of H2xR and SL2): a point there, 0.9 of the way out, lies atanh(0.9) = 1.5 from the
# centre in H3.
CHART_MARGIN = 0.9


def fit_scale(space: Space, scene_size: float) -> float:
    """The scale (scene units per chart unit) at which a scene of diagonal `scene_size` spans
    FIT_FRACTION of the diameter of the domain's inscribed chart ball."""
    return scene_size / (FIT_FRACTION * 2 * space.chart_inradius)


# A scene spanning more domains than this was not meant at its scale: bringing it into the domain
# takes thousands of face crossings, or (H3) it lies beyond the chart. A front end says which
# setting scales it.
MAX_SPAN = 1000.0


def scene_span(scene: Scene, camera: Camera | None = None) -> float:
    """The chart diagonal of the box holding the camera, the lights and every object's copies as
    placed (their instances' boxes)."""
    points = [np.asarray(camera.position, float)[None]] if camera is not None else []
    points += [np.asarray(light.position, float)[None] for light in scene.lights]
    for obj in scene.objects:
        lo, hi = obj.vertices.min(axis=0), obj.vertices.max(axis=0)
        corners = np.array([[(lo, hi)[(k >> i) & 1][i] for i in range(3)] for k in range(8)])
        if obj.instances is None:
            points.append(corners)
        else:
            A = obj.instances
            points.append((np.einsum("kij,nj->kni", A[:, :3, :3], corners) + A[:, None, :3, 3]).reshape(-1, 3))
    return _diagonal(np.vstack(points)) if points else 0.0


def domain_span(space: Space) -> float:
    """The chart diagonal of the domain's vertices (the size the notes compare objects with)."""
    return _diagonal(space.domain.vertices)


def fit(space: Space, scene_box, points=()) -> tuple[float, np.ndarray]:
    """(scale, offset): the scale of fit_scale for the scene's box (lo, hi, scene units), larger
    where needed (by factors of 1.25) for the scene's `points` (its lights and camera, scene
    units) to lie in a bounded chart within CHART_MARGIN of its edge; and the translation (scene
    units) that puts the box's centre at the domain's centre, where the domain is not built about
    the chart origin (shells: the origin is no point of the space; zero elsewhere, where the face
    pairings bring any placement in)."""
    lo, hi = (np.asarray(v, float) for v in scene_box)
    centre = np.asarray(space.centre, float)
    moved = bool(np.any(centre))
    middle = (lo + hi) / 2 if moved else np.zeros(3)
    P = np.asarray(points, float).reshape(-1, 3) - middle
    g = space.geometry
    scale = fit_scale(space, float(np.linalg.norm(hi - lo)))
    for _ in range(200):  # 1.25^200: any finite points
        if np.all(g.in_chart((P / scale + centre) / CHART_MARGIN)):
            break
        scale *= 1.25
    return scale, (centre * scale - middle if moved else np.zeros(3))


def _placed(obj) -> np.ndarray:
    """An object's chart vertices as placed (its first placement, where it is instanced)."""
    if obj.instances is None:
        return obj.vertices
    A = obj.instances[0]
    return obj.vertices @ A[:3, :3].T + A[:3, 3]


def _diagonal(vertices) -> float:
    return float(np.linalg.norm(np.ptp(vertices, axis=0)))


def _names(objects) -> str:
    names = sorted({o.name for o in objects})
    return ", ".join(repr(n) for n in names[:5]) + (" ..." if len(names) > 5 else "")


def winding_numbers(points, vertices, triangles, block=1_000_000) -> np.ndarray:
    """The winding number of a triangle mesh about each point: the solid angles of its triangles
    (Van Oosterom and Strackee) over 4 pi; 1 inside a closed outward mesh, 0 outside. Chart
    triangles: the number is topological, so any chart gives the manifold's answer. Triangles are
    taken in chunks of about `block` (point, triangle) pairs, to bound the memory."""
    P = np.asarray(points, float)
    out = np.zeros(len(P))
    chunk = max(1, block // max(len(P), 1))
    for start in range(0, len(triangles), chunk):
        T = triangles[start : start + chunk]
        a, b, c = (vertices[T[:, k]][None, :, :] - P[:, None, :] for k in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("pti,pti->pt", a, np.cross(b, c))
        div = (
            la * lb * lc
            + np.einsum("pti,pti->pt", a, b) * lc
            + np.einsum("pti,pti->pt", a, c) * lb
            + np.einsum("pti,pti->pt", b, c) * la
        )
        out += np.sum(2 * np.arctan2(det, div), axis=1) / (4 * math.pi)
    return out


def _encloses(space: Space, obj, point_model) -> bool:
    """Whether the object (any of its placements) encloses a copy of the point: the point's images
    around the domain, taken back by each placement's home element and into its mesh's
    coordinates, then the mesh's winding number about those in its box."""
    g = space.geometry
    A = obj.instances if obj.instances is not None else np.eye(4)[None]
    homes = home_elements(space, A[:, :3, :3] @ obj.vertices.mean(axis=0) + A[:, :3, 3])
    images = np.array([E @ point_model for E in space.neighbourhood(1)])
    P = np.asarray(g.to_chart(np.einsum("kij,nj->kni", np.linalg.inv(homes), images)), float)
    P = np.einsum("kij,knj->kni", np.linalg.inv(A[:, :3, :3]), P - A[:, None, :3, 3]).reshape(-1, 3)
    lo, hi = obj.vertices.min(axis=0), obj.vertices.max(axis=0)
    P = P[np.all((P >= lo) & (P <= hi), axis=1)]
    return bool(len(P)) and bool(np.any(np.abs(winding_numbers(P, obj.vertices, obj.triangles)) > 0.5))


def before_render(space: Space, scene: Scene, camera: Camera, lambert: bool) -> list[Note]:
    """Notes on the scene and camera as given: camera outside the domain or inside an unlit closed
    object, no lights, objects far larger or smaller than the domain."""
    g = space.geometry
    notes = []
    X = g.to_model(np.asarray(camera.position, float))
    if not space.domain.contains(X):
        notes.append(
            Note(
                CAMERA_OUTSIDE,
                "the camera lies outside the fundamental domain: the face pairings "
                "move it in, to the same point of the space (the view is the same)",
            )
        )
    lights = [g.to_model(np.asarray(light.position, float)) for light in scene.lights]
    ratios = {o.name: space.size_ratio(_placed(o)) for o in scene.objects}
    for obj in scene.objects:
        # an object larger than the domain fills it (its note says so; in a shell it may hold the
        # chart's origin, which no isometry brings in)
        if np.any(obj.emission > 0) or ratios[obj.name] > TOO_LARGE or not _encloses(space, obj, X):
            continue
        if not any(_encloses(space, obj, L) for L in lights):
            notes.append(
                Note(
                    CAMERA_IN_OBJECT,
                    f"the camera is inside object {obj.name!r} and no light is: "
                    f"it sees the object's unlit inside; move the camera out of it",
                )
            )
    # (emissive objects light the scene too: area lights, a point light's sphere)
    emissive = [o for o in scene.objects if np.any(o.emission > 0)]
    if lambert and not scene.lights and not emissive:
        notes.append(
            Note(NO_LIGHTS, "the scene has no lights: everything renders black; add a point light inside the domain")
        )
    large = [o for o in scene.objects if ratios[o.name] > TOO_LARGE]
    if large:
        one = len(large) == 1
        ratio = ratios[large[0].name]
        notes.append(
            Note(
                SCENE_TOO_LARGE,
                f"{_names(large)} {'is' if one else 'are'} larger than the domain ("
                + (
                    f"{ratio:.3g} times its size"
                    if math.isfinite(ratio)
                    else "around the chart's origin, which is no point of the space"
                )
                + f"): {'its' if one else 'their'} copies overlap and fill it; scale the scene "
                f"to fit the domain",
            )
        )
    elif scene.objects:
        # the scene: its objects and its lights (a small object lit from afar is not a small scene)
        points = np.vstack(
            [_placed(o) for o in scene.objects] + [np.reshape([li.position for li in scene.lights], (-1, 3))]
        )
        ratio = space.size_ratio(points)
        if ratio < 1 / TOO_SMALL:
            notes.append(
                Note(
                    SCENE_TOO_SMALL,
                    f"the scene is over {TOO_SMALL:g} times smaller than the domain "
                    f"({1 / ratio:.3g} times): its copies show as specks; scale the scene to fit the domain",
                )
            )
    return notes


def long_walk(space: Space, rays: int, max_distance: float, max_crossings: int, threads: int) -> Note | None:
    """A note where the limits let `rays` rays that meet nothing walk for longer than
    LONG_WALK_SECONDS: each crosses a face about every domain inradius, up to the crossings' limit."""
    per_ray = min(float(max_crossings), max_distance / max(space.chart_inradius, 1e-300))
    seconds = rays * per_ray / (CROSSINGS_PER_SECOND * max(threads, 1))
    if not seconds > LONG_WALK_SECONDS:
        return None
    return Note(
        LONG_WALK,
        f"each ray may walk up to {per_ray:.3g} face crossings (max distance {max_distance:.3g}, max crossings "
        f"{max_crossings}) before it stops: where rays meet nothing, these {rays} rays take at least "
        f"{_duration(seconds)}; lower max distance or max crossings (the render shows its progress and "
        "stops on Ctrl+C or Esc)",
    )


def _duration(seconds: float) -> str:
    for unit, size in (("years", 3.15e7), ("days", 86400), ("hours", 3600), ("minutes", 60)):
        if seconds >= 2 * size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"


def lit_median(scene: Scene, passes: dict) -> float | None:
    """The median luminance (linear) of the pixels that show a surface lit by the lights (not an
    emitter); None where there is none."""
    obj = passes["object"]
    emissive = np.array([np.any(o.emission > 0) for o in scene.objects] + [False])
    lit = (obj >= 0) & ~emissive[obj]
    if not lit.any():
        return None
    return float(np.median(np.nan_to_num(passes["color"][lit]) @ LUMINANCE))


def proposed_exposure(scene: Scene, passes: dict, exposure: float = 0.0) -> float | None:
    """The exposure (stops) that brings the lit surfaces' median to MID_GREY, where after the
    `exposure` already set it lies outside [EXPOSURE_DARK, EXPOSURE_BRIGHT]; None where it lies
    inside, or no lit surface shows (or none is lit at all: that is UNLIT's)."""
    median = lit_median(scene, passes)
    if median is None or median <= 0:
        return None
    if EXPOSURE_DARK <= median * 2.0**exposure <= EXPOSURE_BRIGHT:
        return None
    return math.log2(MID_GREY / median)


def after_render(
    scene: Scene, passes: dict, lambert: bool, exposure: float = 0.0, stats: dict | None = None
) -> list[Note]:
    """Notes on the rendered passes: no ray reaching a surface; pixels clamped; lights that reach
    no surface the camera sees, with the cause where the render's `stats` (Result.stats) tell it;
    lit surfaces that show black or white under the `exposure` (stops) the front end applies."""
    stats = stats or {}
    notes = []
    if stats.get("clamped_pixels"):
        notes.append(
            Note(
                CLAMPED,
                f"{stats['clamped_pixels']} pixels summed more light than float32 holds (3.4e38) and are "
                "clamped to it: make the emitters and lights weaker (their copies add up in a closed space)",
            )
        )
    obj = passes["object"]
    hit = obj >= 0
    short = _short_limit(stats)
    if scene.objects and not hit.any() and short:
        return notes + [Note(NOTHING_HIT, f"no ray reaches a surface: {short}")]
    emissive = np.array([np.any(o.emission > 0) for o in scene.objects] + [False])
    if not (lambert and (scene.lights or emissive.any())):  # emitters light too (a point light's sphere)
        return notes
    lit_surface = hit & ~emissive[obj]
    if lit_surface.any() and not np.any(passes["color"][lit_surface] > 0):
        depth = float(np.min(passes["depth"][lit_surface])) if "depth" in passes else 0.0
        return notes + [Note(UNLIT, _unlit_cause(scene, stats, depth, emissive.any()))]
    stops = proposed_exposure(scene, passes, exposure)
    if stops is None:
        return notes
    median = lit_median(scene, passes) * 2.0**exposure
    bright = median > EXPOSURE_BRIGHT
    return notes + [
        Note(
            EXPOSURE,
            f"the lit surfaces show {'white' if bright else 'black'} (their median brightness is "
            f"{median:.3g}"
            + (
                ": in a closed space a light reaches each point along every geodesic, and its copies add up"
                if bright
                else ""
            )
            + f"); an exposure of {stops:+.2f} stops brings it to {MID_GREY:g}, the lights' power "
            f"unchanged (or make the lights {2.0 ** abs(stops - exposure):.3g} times "
            f"{'weaker' if bright else 'stronger'})",
            value=stops,
        )
    ]


def _short_limit(stats: dict) -> str | None:
    """Which limit stops the rays before they reach as far as the domain's inradius, if one does
    (then nothing may be hit): the face crossings', the camera's clip end or the distance limit."""
    counts, span = stats.get("stop_counts", {}), stats.get("inradius", 0.0)
    clip_end, reach = stats.get("clip_end"), stats.get("max_distance")
    if counts.get("crossings", 0) > counts.get("distance", 0) and stats.get("max_crossings") == 0:
        return "every ray stops at its first face crossing (max crossings 0); raise max crossings"
    if clip_end is not None and clip_end < span and (reach is None or clip_end < reach):
        return f"the camera's clip end {clip_end:.3g} ends every ray before a surface; raise the clip end"
    if reach is not None and reach < span:
        return f"every ray stops at the distance limit {reach:.3g} before a surface; raise max distance"
    return None


def _unlit_cause(scene: Scene, stats: dict, depth: float, emitters: bool) -> str:
    """The unlit note's words: the cause the settings and lights show, else the usual ones."""
    fog, reach = stats.get("fog"), stats.get("light_reach")
    if fog and depth / fog > FOG_BLACK:
        return (
            f"every surface the camera sees shows black: the fog distance {fog:.3g} dims the nearest "
            f"({depth:.3g} away, {depth / fog:.3g} fog distances) to nothing; raise the fog distance or turn fog off"
        )
    if reach == 0 and not emitters:
        return "no light reaches any surface: the light reach is 0, so no geodesic to a light is summed; raise the light reach"
    spots = [light for light in scene.lights if light.spot_direction is not None]
    if scene.lights and len(spots) == len(scene.lights) and not emitters:
        narrowest = min(light.spot_size for light in spots)
        if max(light.spot_size for light in spots) < NARROW_SPOT:
            return (
                f"no light reaches any surface the camera sees: every light is a spot whose cone "
                f"({math.degrees(narrowest):.3g} degrees) is too narrow to light anything; widen spot_size"
            )
    return (
        "no light reaches any surface the camera sees: the lights are inside objects or "
        "hidden from the visible surfaces; move a light into view of them"
    )
