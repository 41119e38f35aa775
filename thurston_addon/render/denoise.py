"""Denoising with Intel Open Image Denoise (OIDN): its RT filter on the colour (HDR), guided by the
albedo and normal passes (cleanAux off: the guides are as noisy as the samples made them).

Two ways to the library: the pyoidn binding (PyPI `pyoidn`, the `denoise` extra; it bundles OIDN
and its own libtbb), or a given OIDN shared library (Blender's own, which Blender has loaded already)
called through ctypes. Both work in a process that has the core loaded: one libtbb.so.12 serves
both (tests/render/test_denoise.py runs both import orders in child processes)."""

from __future__ import annotations

import ctypes

import numpy as np

from .settings import DENOISE_MISSING as MISSING
from .settings import RenderError


def denoise(color, albedo, normal, library: str | None = None) -> np.ndarray:
    """The colour (h, w, 3) denoised by OIDN's RT filter with the albedo and normal guides
    (float32, (h, w, 3)); `library`: an OIDN shared library to call (None: pyoidn's). RenderError
    where no OIDN can be loaded or it fails."""
    images = [np.ascontiguousarray(np.nan_to_num(a), np.float32) for a in (color, albedo, normal)]
    if library is not None:
        return _denoise_library(library, *images)
    try:
        import pyoidn
    except ImportError:
        raise RenderError(MISSING) from None
    try:
        out = pyoidn.denoise(*images, hdr=True, clean_aux=False, filter_type="RT")
    except (OSError, RuntimeError) as exc:
        raise RenderError(f"Open Image Denoise failed: {exc}") from None
    return np.asarray(out, np.float32)


_DEVICE_CPU, _FORMAT_FLOAT3 = 1, 3


def _denoise_library(path: str, color, albedo, normal) -> np.ndarray:
    """OIDN's C API (stable across versions 1 and 2) through ctypes on the library at `path`."""
    try:
        lib = ctypes.CDLL(path)
    except OSError as exc:
        raise RenderError(f"cannot load Open Image Denoise from {path}: {exc}") from None
    vp, cp, sz = ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t
    signatures = {
        "oidnNewDevice": (vp, [ctypes.c_int]),
        "oidnCommitDevice": (None, [vp]),
        "oidnGetDeviceError": (ctypes.c_int, [vp, ctypes.POINTER(cp)]),
        "oidnNewFilter": (vp, [vp, cp]),
        "oidnSetSharedFilterImage": (None, [vp, cp, vp, ctypes.c_int, sz, sz, sz, sz, sz]),
        "oidnSetFilterBool": (None, [vp, cp, ctypes.c_bool]),
        "oidnCommitFilter": (None, [vp]),
        "oidnExecuteFilter": (None, [vp]),
        "oidnReleaseFilter": (None, [vp]),
        "oidnReleaseDevice": (None, [vp]),
    }
    f = {}
    for name, (restype, argtypes) in signatures.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = restype, argtypes
        f[name] = fn
    h, w, _ = color.shape
    out = np.empty_like(color)
    device = f["oidnNewDevice"](_DEVICE_CPU)
    if not device:
        raise RenderError(f"Open Image Denoise ({path}) could not make a CPU device")

    def check(step):
        message = cp()
        if f["oidnGetDeviceError"](device, ctypes.byref(message)):
            text = message.value.decode(errors="replace") if message.value else "no message"
            raise RenderError(f"Open Image Denoise failed ({step}): {text}")

    try:
        f["oidnCommitDevice"](device)
        check("device")
        filt = f["oidnNewFilter"](device, b"RT")
        check("filter")
        try:
            for name, image in ((b"color", color), (b"albedo", albedo), (b"normal", normal), (b"output", out)):
                f["oidnSetSharedFilterImage"](filt, name, image.ctypes.data, _FORMAT_FLOAT3, w, h, 0, 0, 0)
            f["oidnSetFilterBool"](filt, b"hdr", True)
            f["oidnSetFilterBool"](filt, b"cleanAux", False)
            f["oidnCommitFilter"](filt)
            check("filter setup")
            f["oidnExecuteFilter"](filt)
            check("filter")
        finally:
            f["oidnReleaseFilter"](filt)
    finally:
        f["oidnReleaseDevice"](device)
    return out
