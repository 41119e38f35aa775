"""The files the program reads and writes. Inputs must be regular files: a FIFO would block the
read, a directory or a device is no input; and no larger than their kind's limit (SIZE_LIMITS), so
that a wrong or hostile file cannot take the machine's memory before anything is checked. Outputs are written whole or not at all: into a
temporary file of a unique name beside the output, checked, flushed to the disk and moved into
place in one step, so that a failed write (a full disk, a file too large, a signal) or a
concurrent run never leaves a broken, mixed or foreign file under the output's name."""

from __future__ import annotations

import contextlib
import difflib
import os
import secrets
import stat
from pathlib import Path

import numpy as np

MiB, GiB = 2**20, 2**30
# The largest file of each kind that is read, in bytes: parsed text takes several times its size in
# memory (an OBJ file about 16 times: 4 GiB for the largest), a binary mesh file of 1 GiB holds
# some 20 million triangles.
SIZE_LIMITS = {
    "space file": 1 * MiB,
    "scene file": 16 * MiB,  # TOML
    "material library": 16 * MiB,
    "OBJ file": 256 * MiB,
    "mesh file": 1 * GiB,  # PLY, STL, glTF, GLB and a glTF's buffers
    "texture": 1 * GiB,
}


class OutputError(ValueError):
    pass


def check_input(path: str | Path, what: str, error: type[Exception], limit: str | None = None) -> Path:
    """The path of an input file (`what`: its kind, in messages), if it is a regular file no larger
    than SIZE_LIMITS[limit] (no limit if None); else `error` saying why not."""
    path = Path(path)
    try:
        info = os.stat(path)
        mode = info.st_mode
    except FileNotFoundError:
        raise error(f"{what} {str(path)!r} does not exist") from None
    except OSError as exc:
        raise error(f"cannot read {what} {str(path)!r}: {exc.strerror}") from None
    if not stat.S_ISREG(mode):
        kind = (
            "a directory"
            if stat.S_ISDIR(mode)
            else "a FIFO (named pipe)"
            if stat.S_ISFIFO(mode)
            else "a device"
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket"
        )
        raise error(f"{what} {str(path)!r} is {kind}, not a regular file")
    if limit is not None and info.st_size > SIZE_LIMITS[limit]:
        raise error(
            f"{what} {str(path)!r} is {size_text(info.st_size)}, more than the {size_text(SIZE_LIMITS[limit])} "
            f"a {limit} may have"
        )
    return path


REFERENCE_OPTION = "--allow-files-outside FOLDER"


def reference_folders(scene_file: str | Path, allowed=()) -> tuple[Path, ...]:
    """The folders the files a scene file refers to may be read from: the scene file's own folder
    (and below), then each folder the user allows (links resolved)."""
    return tuple(Path(os.path.realpath(f)) for f in (Path(scene_file).absolute().parent, *allowed))


def check_reference(
    path: str | Path, folders: tuple[Path, ...], what: str, error: type[Exception], limit: str | None = None
) -> Path:
    """A file a scene refers to (a material library, a texture, a glTF buffer or image, a mesh file
    of a scene file), read only from `folders` (reference_folders) and below, its links resolved,
    so that a hostile scene cannot read the rest of the machine; then `check_input`'s checks."""
    path = Path(path)
    real = Path(os.path.realpath(path))
    if not any(real.is_relative_to(folder) for folder in folders):
        raise error(
            f"{what} {str(path)!r} is outside the scene's folder {str(folders[0])!r}: files a scene refers "
            f"to are read from its folder and below; pass {REFERENCE_OPTION} to allow another folder"
        )
    return check_input(path, what, error, limit)


def read_text(path: str | Path, what: str, error: type[Exception], limit: str) -> str:
    """A UTF-8 text input (checked by check_input) as a string; `error` where it cannot be read."""
    path = check_input(path, what, error, limit)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"cannot read {what} {str(path)!r}: it is not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise error(f"cannot read {what} {str(path)!r}: {exc.strerror or exc}") from None


def size_text(n: int) -> str:
    for unit, size in (("TiB", 2**40), ("GiB", GiB), ("MiB", MiB), ("KiB", 1024)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n} bytes"


def physical_memory() -> int | None:
    """Bytes of physical memory, None where the system does not tell (no sysconf)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def check_memory(nbytes: int, what: str, error: type[Exception]):
    """`error` if `what` would take more than this machine's memory."""
    have = physical_memory()
    if have is not None and nbytes > have:
        raise error(f"{what} would take {size_text(nbytes)}, more than this machine's memory ({size_text(have)})")


def load_npy(path: str | Path, what: str, error: type[Exception]) -> np.ndarray:
    """A .npy array, its header checked before anything is allocated: a plain (not object) dtype,
    data as long as the header says (not truncated) and no larger than this machine's memory."""
    path = check_input(path, what, error)
    name = f"{what} {str(path)!r}"
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version not in ((1, 0), (2, 0)):
                raise ValueError(f"unsupported .npy format version {version[0]}.{version[1]}")
            read_header = (
                np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            )
            try:
                shape, fortran_order, dtype = read_header(f)
            except (ValueError, SyntaxError, TypeError):  # numpy's words quote the parser's internals
                raise ValueError(
                    "its header is not a .npy header (a dictionary of 'descr', 'fortran_order' and 'shape'); "
                    "write the file with numpy.save"
                ) from None
            offset = f.tell()
    except (ValueError, EOFError, OSError) as exc:
        raise error(f"cannot read {name} as a .npy array: {exc}") from None
    if dtype.hasobject:
        raise error(f"{name} holds Python objects ({dtype}); a numeric array is needed")
    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
    held = path.stat().st_size - offset
    if held < nbytes:
        raise error(
            f"{name} is truncated: its header describes a {dtype} array of shape {tuple(shape)} "
            f"({size_text(nbytes)}), the file holds {size_text(held)} of data"
        )
    check_memory(nbytes, f"{name} (a {dtype} array of shape {tuple(shape)})", error)
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise error(f"cannot read {name} as a .npy array: {exc}") from None


def check_keys(table: dict, allowed, where: str, error: type[Exception]):
    """`error` naming the first key of `table` not in `allowed`, and the allowed key nearest to it
    (a misspelling) or else all of them."""
    allowed = list(allowed)
    for key in table:
        if key not in allowed:
            near = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f"did you mean {near[0]!r}?" if near else f"valid keys: {', '.join(allowed)}"
            raise error(f"{where}: unknown key {key!r}; {hint}")


def check_output(path: str | Path, overwrite: bool, to_replace: str = "pass --overwrite") -> Path:
    """The output path, if it can be written; `to_replace`: how the user allows replacing a file,
    in the front end's words. Checked before the work, so that it is not wasted; `replacing`
    checks again when the file is put in place."""
    path = Path(path)
    _check_name(path)
    if path.exists() and not overwrite:
        raise OutputError(f"output {str(path)!r} exists; {to_replace} to replace it")
    if path.is_dir():
        raise OutputError(f"output {str(path)!r} is a directory")
    if not path.parent.exists():
        raise OutputError(f"output folder {str(path.parent)!r} does not exist")
    if not os.access(path.parent, os.W_OK):
        raise OutputError(f"output folder {str(path.parent)!r} is not writable")
    return path


def _check_name(path: Path):
    """OutputError where the output's name cannot be written: not UTF-8 text (OpenImageIO takes
    only UTF-8 names), or longer than the file system allows for it and its temporary file."""
    name = str(path)
    try:
        name.encode("utf-8")
    except UnicodeEncodeError as exc:
        raw = os.fsencode(name)
        raise OutputError(
            f"output name {name!r} is not UTF-8 text (byte {raw[exc.start : exc.start + 1]!r}); give a UTF-8 name"
        ) from None
    folder = path.parent if str(path.parent) else Path(".")
    try:
        longest = os.pathconf(folder if folder.exists() else ".", "PC_NAME_MAX")
    except (OSError, ValueError):
        longest = 255
    needed = len(os.fsencode(_temporary_name(path, "0" * 12).name))
    if needed > longest:
        raise OutputError(
            f"output name {path.name[:40]!r}... is {len(os.fsencode(path.name))} bytes: with the temporary file's "
            f"{needed - len(os.fsencode(path.name))} more that it is written to first, that is more than the "
            f"{longest} the file system allows; give a shorter name"
        )


def _temporary_name(path: Path, token: str) -> Path:
    return path.with_name(f".{path.name}.{token}.partial{path.suffix}")


@contextlib.contextmanager
def replacing(path: str | Path, overwrite: bool, to_replace: str = "pass --overwrite"):
    """Yields a new empty temporary file beside `path` (same suffix, so that writers choosing the
    format by name choose the output's) for the caller to fill and check. When the block ends,
    the file is flushed to the disk and becomes `path` atomically: replacing it if `overwrite`,
    else only if no file has appeared there meanwhile. When the block raises (any exception, also
    KeyboardInterrupt or a signal's), or the move fails, the temporary file is removed and `path`
    is left as it was. Errors of the file system are OutputError naming `path`."""
    path = Path(path)
    # the temporary name is claimed before its file is created: a signal's exception (Ctrl-C,
    # cli.Terminated) landing just after the creation still finds it to remove
    claimed: list[Path] = []
    try:
        tmp = _new_temporary(path, claimed)
        yield tmp
        _flush(tmp)
        if overwrite:
            os.replace(tmp, path)
        else:
            _put_if_absent(tmp, path, to_replace)
        _flush_folder(path.parent)
    except OSError as exc:
        raise OutputError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None
    finally:
        for tmp in claimed:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()


def write_bytes(path: str | Path, data, overwrite: bool, to_replace: str = "pass --overwrite") -> Path:
    """`data` (bytes-like) as the file `path`, whole or not at all (see `replacing`)."""
    path = Path(path)
    with replacing(path, overwrite, to_replace) as tmp, open(tmp, "wb") as f:
        f.write(data)
    return path


def _new_temporary(path: Path, claimed: list[Path]) -> Path:
    """A new file of a unique name `.NAME.RANDOM.partial.SUFFIX` beside `path`, created
    exclusively (so that concurrent writers never share one) with the mode the umask gives; its
    name is put in `claimed` before the file is created (and taken out where another has it)."""
    while True:
        tmp = _temporary_name(path, secrets.token_hex(6))
        claimed.append(tmp)
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            claimed.remove(tmp)  # (another writer's: not ours to remove)
            continue
        except OSError as exc:
            claimed.remove(tmp)  # (not created)
            raise OutputError(f"cannot write {str(path)!r}: {exc.strerror}") from None


def _flush(tmp: Path):
    """fsync: a disk that fails late (network file systems report some errors only here) fails
    the write instead of leaving a short file after a crash."""
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _put_if_absent(tmp: Path, path: Path, to_replace: str):
    """tmp becomes path unless a file is there: the output is claimed by an exclusive create (it
    works on every file system, hard links do not) and the finished file moved over the claim."""
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except FileExistsError:
        raise OutputError(
            f"output {str(path)!r} appeared while this run was working; {to_replace} to replace it"
        ) from None
    try:
        os.replace(tmp, path)
    except BaseException:
        path.unlink()  # the empty claim is ours
        raise


def _flush_folder(folder: Path):
    """fsync the folder, so that the move itself survives a crash."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
