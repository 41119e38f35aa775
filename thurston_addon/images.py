"""Writing renders (multi-channel linear EXR and 8-bit sRGB PNG or other formats) and reading
textures, via OpenImageIO."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

# EXR channel names per pass (Blender-like layer.channel names)
CHANNELS = {
    "color": ("R", "G", "B"),
    "depth": ("Z",),
    "normal": ("Normal.X", "Normal.Y", "Normal.Z"),
    "position": ("Position.X", "Position.Y", "Position.Z"),
    "object": ("IndexOB",),
    "crossings": ("Crossings",),
    "stop": ("Stop",),
}


class OutputError(ValueError):
    pass


def check_output(path: str | Path, overwrite: bool, to_replace: str = "pass --overwrite") -> Path:
    """The output path, if it can be written; `to_replace`: how the user allows replacing a file,
    in the front end's words."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputError(f"output {str(path)!r} exists; {to_replace} to replace it")
    if path.is_dir():
        raise OutputError(f"output {str(path)!r} is a directory")
    if not path.parent.exists():
        raise OutputError(f"output folder {str(path.parent)!r} does not exist")
    if not os.access(path.parent, os.W_OK):
        raise OutputError(f"output folder {str(path.parent)!r} is not writable")
    return path


def linear_to_srgb(c):
    c = np.clip(np.nan_to_num(c), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def srgb_to_linear(c):
    c = np.asarray(c)
    return np.where(c <= 0.04045, c / 12.92, np.power((c + 0.055) / 1.055, 2.4))


def read_texture(path: str | Path) -> np.ndarray:
    """An image file as a float32 (H, W, 3) linear RGB texture, rows top-down. As Blender reads a
    colour image: integer formats (8/16-bit PNG, JPEG, ...) are sRGB-encoded and decoded here,
    float formats (EXR, HDR) are linear; grey images give grey RGB, alpha is dropped. Raises
    ValueError naming the file where it cannot be read."""
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise ValueError(f"cannot read texture {str(path)!r}: {oiio.geterror() or 'not an image'}")
    try:
        spec = image.spec()
        pixels = image.read_image(0, 0, 0, spec.nchannels, "float")
    finally:
        image.close()
    if pixels is None:
        raise ValueError(f"cannot read texture {str(path)!r}: {oiio.geterror()}")
    pixels = np.asarray(pixels, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    rgb = pixels[..., :3] if spec.nchannels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if spec.format.basetype not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE):
        rgb = srgb_to_linear(rgb)
    return np.ascontiguousarray(rgb, np.float32)


def write(path: str | Path, passes: dict, names=None, metadata: dict | None = None):
    """EXR: every pass in `names` (default all) as float channels, linear; other formats: the
    colour pass, sRGB-encoded, 8 bit. Written to a temporary file and moved into place, so a failed
    write never leaves a broken file under the user's name."""
    import OpenImageIO as oiio

    path = Path(path)
    exr = path.suffix.lower() == ".exr"
    names = [n for n in (names or CHANNELS) if n in passes] if exr else ["color"]
    H, W = passes["color"].shape[:2]
    planes, channels = [], []
    for n in names:
        a = np.asarray(passes[n], dtype=np.float32).reshape(H, W, -1)
        if n != "color" or exr:
            planes.append(a)
        else:
            planes.append(linear_to_srgb(a).astype(np.float32))
        channels += CHANNELS[n]
    pixels = np.ascontiguousarray(np.concatenate(planes, axis=2))
    spec = oiio.ImageSpec(W, H, len(channels), oiio.FLOAT if exr else oiio.UINT8)
    spec.channelnames = tuple(channels)
    if exr:
        spec.attribute("compression", "zip")
        if "depth" in names:
            spec.z_channel = channels.index("Z")
    for k, v in (metadata or {}).items():
        spec.attribute(f"thurston:{k}", str(v))
    tmp = path.with_name(f".{path.name}.partial{path.suffix}")

    def failed(reason: str) -> OutputError:  # the user's file name, not the temporary one
        return OutputError(f"cannot write {str(path)!r}: {reason.replace(str(tmp), str(path))}")

    try:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise failed(oiio.geterror())
        try:
            if not out.open(str(tmp), spec) or not out.write_image(pixels):
                raise failed(out.geterror())
        finally:
            closed = out.close()
        if not closed:
            raise failed(out.geterror() or "closing the file failed")
        os.replace(tmp, path)
    except BaseException:
        _remove_partial(tmp)
        raise
    return path


def _remove_partial(tmp: Path):
    """Remove the temporary file of a failed write (also one a crashed earlier write left behind);
    never a directory that happens to have its name."""
    try:
        if tmp.is_symlink() or tmp.is_file():
            tmp.unlink()
    except OSError:
        pass
