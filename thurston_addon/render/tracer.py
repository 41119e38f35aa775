"""The C++ tracer of a compiled scene, and its trace with what the core rejects raised as RenderError."""

from __future__ import annotations

import math

from ..scenes import Scene
from ..spaces import Space
from .compilation import compile_scene
from .settings import RenderError


def core_scene(data: dict):
    """The core's record of a compiled scene (compile_scene's arrays): a thurston_core.Scene whose
    parts take the arrays of their fields' names (a part's optional arrays left out: None)."""
    import thurston_core as core

    kinds = dict(
        domain=core.Domain,
        meshes=core.Meshes,
        surfaces=core.Surfaces,
        lights=core.Lights,
        instances=core.Instances,
        emitters=core.Emitters,
    )
    given = {part: {name: value for name, value in data.items() if hasattr(kind, name)} for part, kind in kinds.items()}
    unknown = set(data) - {"geometry", "geometry_parameters"} - set().union(*given.values())
    if unknown:
        raise TypeError(f"no part of the core's scene takes {sorted(unknown)}")
    return core.Scene(
        data["geometry"],
        **{part: kinds[part](**arrays) for part, arrays in given.items()},
        geometry_parameters=data.get("geometry_parameters", []),
    )


def ray_block() -> int:
    """The block of ray ids whose rays learn shadow-walk visibility together in the core: a render
    region of whole blocks traces as the whole image does."""
    import thurston_core

    return thurston_core.RAY_BLOCK


def make_tracer(space: Space, scene: Scene, threads: int = 0, light_reach: float | None = None):
    """The C++ tracer for a scene, summing light over light_reach (None: default_light_reach); what
    the core rejects (ValueError) is raised as RenderError."""
    import thurston_core

    data = compile_scene(space, scene, light_reach)
    try:
        return thurston_core.Tracer(core_scene(data), threads=threads)
    except thurston_core.ThreadStartError as exc:
        raise RenderError(f"{exc}; ask for fewer threads") from None
    except ValueError as exc:
        raise RenderError(f"the tracer rejected the scene: {exc}") from None


def trace(
    tracer,
    origins,
    directions,
    max_distance,
    max_crossings,
    tolerance=1e-3,
    tolerance_per_distance=0.0,
    shade=True,
    progress=None,
    fog=None,
    light_samples=1,
    seed=0,
    bounces=0,
    light_budget=0,
    ray_ids=None,
    visibility_map=0,
    map_check=0.0,
):
    """tracer.trace, with what the core rejects (ValueError) raised as RenderError. Exceptions
    from the progress callback pass through unchanged (they are the caller's, not the input's)."""
    raised = []

    def report(done, total):
        try:
            return progress(done, total)
        except BaseException as exc:
            raised.append(exc)
            raise

    try:
        return tracer.trace(
            origins,
            directions,
            max_distance,
            max_crossings,
            shade=shade,
            progress=None if progress is None else report,
            tolerance=tolerance,
            tolerance_per_distance=tolerance_per_distance,
            fog=fog or math.inf,
            light_samples=light_samples,
            seed=seed,
            bounces=bounces,
            light_budget=light_budget,
            ray_ids=ray_ids,
            visibility_map=visibility_map,
            map_check=map_check,
        )
    except ValueError as exc:
        if raised:
            raise
        raise RenderError(f"the tracer rejected the rays: {exc}") from None
