"""Writing renders (multi-channel linear EXR and 8-bit sRGB PNG or other formats) and reading
textures, via OpenImageIO."""

from __future__ import annotations

import contextlib
import os
import resource
from pathlib import Path

import numpy as np

from .files import OutputError, check_memory, replacing
from .passes import CHANNELS

XMP_KEY = "XML:com.adobe.xmp"
# Google's Spherical Video metadata (RFC v1) names a panorama's stereo layout: its values by ours
STEREO_MODES = {None: "mono", "top-bottom": "top-bottom", "side-by-side": "left-right"}


def panorama_xmp(width: int, height: int, layout: str | None = None) -> str:
    """The XMP packet that marks an equirectangular panorama of one eye's width x height as such:
    Google's Photo Sphere (GPano) properties, which panorama viewers read, and the stereo layout of
    the two eyes in the image (layout: top-bottom or side-by-side; None: mono) as the Spherical
    Video metadata's StereoMode (GSpherical), which headset players read."""
    gpano = {
        "ProjectionType": "equirectangular",
        "UsePanoramaViewer": "True",
        "StitchingSoftware": "Thurston",
        "FullPanoWidthPixels": width,
        "FullPanoHeightPixels": height,
        "CroppedAreaImageWidthPixels": width,
        "CroppedAreaImageHeightPixels": height,
        "CroppedAreaLeftPixels": 0,
        "CroppedAreaTopPixels": 0,
    }
    gspherical = {
        "Spherical": "true",
        "Stitched": "true",
        "ProjectionType": "equirectangular",
        "StereoMode": STEREO_MODES[layout],
    }
    properties = "".join(f'\n    GPano:{k}="{v}"' for k, v in gpano.items()) + "".join(
        f'\n    GSpherical:{k}="{v}"' for k, v in gspherical.items()
    )
    return (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        '  <rdf:Description rdf:about=""\n'
        '    xmlns:GPano="http://ns.google.com/photos/1.0/panorama/"\n'
        '    xmlns:GSpherical="http://ns.google.com/videos/1.0/spherical/"'
        f"{properties}/>\n"
        " </rdf:RDF>\n"
        "</x:xmpmeta>"
    )


def linear_to_srgb(c):
    c = np.clip(np.nan_to_num(c), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def srgb_to_linear(c):
    c = np.asarray(c)
    return np.where(c <= 0.04045, c / 12.92, np.power((c + 0.055) / 1.055, 2.4))


# The most pixels a texture may have (8192 x 8192): its header is checked before any pixel is read,
# since a small compressed file can claim a huge image (a 2 MB PNG of 16384 x 16384 took 14.5 GB).
# Reading one takes some 50 bytes a pixel at its peak (OpenImageIO's float pixels, RGB, sRGB decoding).
TEXTURE_PIXEL_LIMIT = 8192 * 8192


def read_texture(path: str | Path) -> np.ndarray:
    """An image file as a float32 (H, W, 3) linear RGB texture, rows top-down. As Blender reads a
    colour image: integer formats (8/16-bit PNG, JPEG, ...) are sRGB-encoded and decoded here,
    float formats (EXR, HDR) are linear; grey images give grey RGB, alpha is dropped. Raises
    ValueError naming the file where it cannot be read, or where its header claims more than
    TEXTURE_PIXEL_LIMIT pixels (refused, not downsampled: the user's own scaling is the one they want)."""
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise ValueError(f"cannot read texture {str(path)!r}: {oiio.geterror() or 'not an image'}")
    try:
        spec = image.spec()
        if spec.width * spec.height > TEXTURE_PIXEL_LIMIT:
            raise ValueError(
                f"texture {str(path)!r} is {spec.width}x{spec.height} pixels, more than the "
                f"{TEXTURE_PIXEL_LIMIT // 2**20} million (8192x8192) a texture may have; scale it down"
            )
        # its header's size, checked before the pixels are allocated (as float32, and as RGB)
        check_memory(
            4 * spec.width * spec.height * (spec.nchannels + 3),
            f"texture {str(path)!r} ({spec.width}x{spec.height}, {spec.nchannels} channels)",
            ValueError,
        )
        pixels = image.read_image(0, 0, 0, spec.nchannels, "float")
    finally:
        image.close()
    if pixels is None:
        reason = oiio.geterror().strip() or "its pixel data is truncated or corrupt"
        raise ValueError(f"cannot read texture {str(path)!r}: {reason}")
    pixels = np.asarray(pixels, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    rgb = pixels[..., :3] if spec.nchannels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if spec.format.basetype not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE):
        rgb = srgb_to_linear(rgb)
    return np.ascontiguousarray(rgb, np.float32)


def write(
    path: str | Path,
    passes: dict,
    names=None,
    metadata: dict | None = None,
    overwrite: bool = False,
    to_replace: str = "pass --overwrite",
    xmp: str | None = None,
) -> Path:
    """EXR: every pass in `names` (default all) as float channels, linear; other formats: the
    colour pass, sRGB-encoded, 8 bit. `xmp`: an XMP packet to embed (panorama_xmp). Whole or not at
    all (files.replacing): an existing file is replaced only if `overwrite`. Raises OutputError
    naming `path` where it cannot be written."""
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
    spec.attribute("tiff:write_exif", 0)  # an empty Exif directory fails in libtiff (a spurious error)
    for k, v in (metadata or {}).items():
        spec.attribute(f"thurston:{k}", str(v))
    if xmp is not None:
        # XMP's keyword in PNG (Adobe's XMP specification, part 3), and the same named attribute in EXR
        spec.attribute(XMP_KEY, xmp)
    data = _encode(path, spec, pixels)
    with replacing(path, overwrite, to_replace) as tmp:
        tmp.write_bytes(data)
        check_image_file(tmp, path, (W, H, len(channels)))
    return path


def _encode(path: Path, spec, pixels) -> bytes:
    """The bytes of the image file `path` will hold, encoded into memory: a full disk or a file
    size limit then fails our own write, which raises, never the codec's (libjpeg ends the process
    on a failed write; libpng's leave OpenImageIO reporting success)."""
    import OpenImageIO as oiio

    def failed(reason: str) -> OutputError:
        return OutputError(f"cannot write {str(path)!r}: {reason.strip() or 'the encoder failed'}")

    out = oiio.ImageOutput.create(str(path))  # the format from the output's name
    if out is None:
        raise failed(oiio.geterror())
    with open(os.memfd_create("thurston-image"), "rb") as memory, _file_size_limit_lifted(path, pixels.nbytes):
        # the writers open files by name: the memory file's name in /proc
        name = f"/proc/self/fd/{memory.fileno()}"
        written = out.open(name, spec) and out.write_image(pixels)
        closed = out.close()
        error = out.geterror()
        if not (written and closed) or error:
            raise failed(error.replace(name, str(path)))
        return memory.read()


@contextlib.contextmanager
def _file_size_limit_lifted(path: Path, pixel_bytes: int):
    """Lifts the soft RLIMIT_FSIZE (ulimit -f) to the hard one while encoding into memory: the limit
    is for the file written to disk, which our own write then refuses as too large. A hard limit
    the encoding might reach (the float pixels' size and a margin for headers bound every format's
    file) is refused before: libjpeg would end the process on reaching it."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    if hard != resource.RLIM_INFINITY and hard < pixel_bytes + 2**20:
        raise OutputError(
            f"cannot write {str(path)!r}: the file size limit (ulimit -f) of {hard} bytes is "
            f"below the {pixel_bytes + 2**20} bytes the encoder may need"
        )
    resource.setrlimit(resource.RLIMIT_FSIZE, (hard, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))


def check_image_file(file: Path, path: Path, shape: tuple[int, int, int] | None = None):
    """That `file` (written for the output `path`) reads back whole, as an image of this shape
    (width, height, channels) where given; else OutputError naming `path`."""
    import OpenImageIO as oiio

    def failed(reason: str) -> OutputError:
        full = os.statvfs(file.parent).f_bavail == 0
        return OutputError(
            f"cannot write {str(path)!r}: {'No space left on device: ' if full else ''}the written "
            f"file does not read back whole ({reason.strip().replace(str(file), str(path))})"
        )

    image = oiio.ImageInput.open(str(file))
    if image is None:
        raise failed(oiio.geterror())
    try:
        spec = image.spec()
        found = (spec.width, spec.height, spec.nchannels)
        pixels = image.read_image(0, 0, 0, spec.nchannels, "float")
        error = image.geterror()
    finally:
        image.close()
    if pixels is None or error or shape not in (None, found):
        raise failed(error or f"width, height, channels {found}, not {shape}")
