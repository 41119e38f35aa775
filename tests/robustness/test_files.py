"""Outputs are written whole or not at all, inputs must be regular files, and every long run stops
on a signal: real `thurston` processes on real file systems (small tmpfs mounts where the tests run
as root), with the exit code, the one error line, the previous file's bytes and the folder's
listing asserted."""

import os
import re
import resource
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from support.outputs import PREVIOUS, default_signals, error_line, fill, listing, stop, tmpfs

from thurston_addon import files, images

THURSTON = Path(sys.executable).with_name("thurston")
FORMATS = ("png", "jpg", "exr", "tif")


def thurston(*args, timeout=120, **kwargs):
    return subprocess.run([str(THURSTON), *map(str, args)], capture_output=True, text=True, timeout=timeout, **kwargs)


def render_args(out, *extra):
    return (
        "render",
        "--space",
        "torus",
        "--size",
        "160x90",
        "--quality",
        "draft",
        "--threads",
        "1",
        "--out",
        out,
        *extra,
    )


def pixels(path):
    return images.read_texture(path)


def rays_file(folder: Path, n=20000) -> Path:
    path = folder / "rays.npy"
    np.save(path, np.tile([0.01, 0.02, 0.03, 1.0, 0.3, 0.2], (n, 1)))
    return path


# --- 1. failed writes: exit 2, one message naming the file, the previous file untouched, no temporary ----


@pytest.mark.parametrize("suffix", FORMATS + ("npz",))
def test_full_disk_keeps_the_previous_file(tmp_path, suffix):
    """On a full disk, with --overwrite, every format (and trace's .npz) fails with the file system's
    reason, and the previous file keeps its bytes (before: 0-byte PNGs reported as success, JPEG
    ending the process inside libjpeg, a traceback for .npz)."""
    rays = rays_file(tmp_path)
    with tmpfs(tmp_path / "disk", "256k") as disk:
        out = disk / f"out.{suffix}"
        out.write_bytes(PREVIOUS)
        fill(disk)
        before = listing(disk)
        if suffix == "npz":
            run = thurston("trace", "--space", "torus", "--rays", rays, "--out", out, "--overwrite")
        else:
            run = thurston(*render_args(out, "--overwrite"))
        assert run.returncode == 2, run.stderr
        assert error_line(run.stderr) == f"thurston: error: cannot write {str(out)!r}: No space left on device"
        assert out.read_bytes() == PREVIOUS
        assert listing(disk) == before


@pytest.mark.parametrize("suffix", ("png", "jpg", "npz"))
def test_file_too_large_is_refused_cleanly(tmp_path, suffix):
    """RLIMIT_FSIZE (ulimit -f) below the file's size: the write fails with EFBIG, not the process
    (a soft limit); a hard limit the encoder could reach is refused before encoding (libjpeg would
    end the process on reaching it)."""
    rays = rays_file(tmp_path)
    out = tmp_path / f"out.{suffix}"
    args = ("trace", "--space", "torus", "--rays", rays, "--out", out) if suffix == "npz" else render_args(out)
    soft_limit = lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (4096, resource.RLIM_INFINITY))  # noqa: E731
    run = thurston(*args, preexec_fn=soft_limit)
    assert run.returncode == 2, run.stderr
    assert error_line(run.stderr) == f"thurston: error: cannot write {str(out)!r}: File too large"
    assert listing(tmp_path) == ["rays.npy"]
    if suffix != "npz":
        hard_limit = lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))  # noqa: E731
        run = thurston(*args, preexec_fn=hard_limit)
        assert run.returncode == 2, run.stderr
        assert "the file size limit (ulimit -f) of 4096 bytes" in error_line(run.stderr)
        assert listing(tmp_path) == ["rays.npy"]


def test_read_only_folder(tmp_path):
    """A read-only file system: the command line refuses before rendering; a write that meets one
    (the folder became read-only during the render) fails naming the file and keeps the old one."""
    with tmpfs(tmp_path / "disk", "1m") as disk:
        out = disk / "out.png"
        out.write_bytes(PREVIOUS)
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        run = thurston(*render_args(out, "--overwrite"))
        assert run.returncode == 2
        assert error_line(run.stderr) == f"thurston: error: output folder {str(disk)!r} is not writable"
        color = {"color": np.full((4, 4, 3), 0.5, np.float32)}
        with pytest.raises(files.OutputError, match=re.escape(f"cannot write {str(out)!r}: Read-only file system")):
            images.write(out, color, overwrite=True)
        with pytest.raises(files.OutputError, match="Read-only file system"):
            files.write_bytes(disk / "hits.npz", b"data", overwrite=True)
        assert out.read_bytes() == PREVIOUS and listing(disk) == ["out.png"]


def test_refused_encoding_and_an_interrupted_write_leave_nothing(tmp_path):
    """What OpenImageIO refuses (an ICO larger than 256 x 256) is OutputError naming the file; an
    exception inside the write (what a signal handler raises: KeyboardInterrupt) removes the
    temporary file and keeps the previous one; a successful write leaves only its output."""
    with pytest.raises(files.OutputError, match=re.escape(f"cannot write {str(tmp_path / 'x.ico')!r}") + ".*256"):
        images.write(tmp_path / "x.ico", {"color": np.zeros((300, 300, 3), np.float32)})
    assert listing(tmp_path) == []
    out = tmp_path / "out.exr"
    out.write_bytes(PREVIOUS)
    with pytest.raises(KeyboardInterrupt), files.replacing(out, overwrite=True) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".out.exr.") and tmp.suffix == ".exr"
        tmp.write_bytes(b"half of an image")
        raise KeyboardInterrupt
    assert out.read_bytes() == PREVIOUS and listing(tmp_path) == ["out.exr"]
    images.write(tmp_path / "y.png", {"color": np.zeros((4, 4, 3), np.float32)})
    assert listing(tmp_path) == ["out.exr", "y.png"]
    assert stat.S_IMODE(os.stat(tmp_path / "y.png").st_mode) == 0o666 & ~current_umask()


def current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# --- 2. concurrent runs and the overwrite promise -------------------------------------------------------


@pytest.mark.slow
def test_a_file_that_appears_during_the_render_is_not_replaced(tmp_path):
    """Without --overwrite the output is claimed only at the end: a file created while the render
    runs stays, and the render fails saying so (before: checked at the start, clobbered at the end)."""
    out = tmp_path / "out.png"
    run = subprocess.Popen(
        [str(THURSTON), *map(str, render_args(out, "--size", "640x360", "--quality", "final"))],
        stderr=subprocess.PIPE,
        text=True,
    )
    assert run.stderr.readline().startswith("render torus [")  # tracing has begun: the start's check passed
    out.write_bytes(PREVIOUS)
    stderr = run.stderr.read()
    assert run.wait(timeout=120) == 2
    assert error_line(stderr) == (
        f"thurston: error: output {str(out)!r} appeared while this run was working; pass --overwrite to replace it"
    )
    assert out.read_bytes() == PREVIOUS and listing(tmp_path) == ["out.png"]


@pytest.mark.slow
@pytest.mark.parametrize("overwrite", (True, False))
def test_concurrent_runs_on_one_path(tmp_path, overwrite):
    """Two processes rendering different views into one path at once: with --overwrite both succeed
    and the file is one of the two images whole; without, exactly one succeeds and the file is its
    image. No temporary file is left either way."""
    views = {"a": ("--camera-forward", "0,1,0"), "b": ("--camera-forward", "1,0,0")}
    truth = {}
    for name, view in views.items():  # each view alone, for comparison
        assert thurston(*render_args(tmp_path / f"{name}.exr", *view)).returncode == 0
        truth[name] = pixels(tmp_path / f"{name}.exr")
    assert np.abs(truth["a"] - truth["b"]).max() > 0.1
    shared = tmp_path / "shared" / "out.exr"
    shared.parent.mkdir()
    extra = ("--overwrite",) if overwrite else ()
    runs = {
        name: subprocess.Popen(
            [str(THURSTON), *map(str, render_args(shared, *view, *extra))],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name, view in views.items()
    }
    results = {name: (run.wait(timeout=120), run.stderr.read()) for name, run in runs.items()}
    winners = [name for name, (code, _) in results.items() if code == 0]
    assert listing(shared.parent) == ["out.exr"]
    final = pixels(shared)
    if overwrite:
        assert sorted(winners) == ["a", "b"], results
        assert any(np.array_equal(final, truth[name]) for name in views)
    else:
        assert len(winners) == 1, results
        loser = next(name for name in views if name not in winners)
        code, stderr = results[loser]
        assert code == 2 and re.search(
            r"(exists|appeared while this run was working); pass --overwrite", error_line(stderr)
        )
        assert np.array_equal(final, truth[winners[0]])


# --- 3. no hangs: signals, threads, inputs that are no files ----------------------------------------------

LONG_RAYS = ("--max-crossings", "2000000000", "--max-distance", "1e15")


@pytest.mark.parametrize(
    "space, signum",
    [
        ("torus", signal.SIGINT),
        ("torus", signal.SIGTERM),
        ("poincare", signal.SIGINT),
        ("nil", signal.SIGTERM),
        ("sol", signal.SIGINT),
    ],
)
def test_a_signal_stops_rays_that_never_end(tmp_path, space, signum):
    """Rays through an empty scene with limits no ray reaches: SIGINT or SIGTERM stops the render
    within a fraction of a second (measured 0.06-0.17 s; 5 s allowed here), exits 130 / 143 with one
    line, keeps the previous file and leaves no temporary file (before: the walks looked at the
    cancel only between chunks of rays, so the run went on for as long as its rays)."""
    empty = tmp_path / "empty.toml"
    empty.write_text("")
    out = tmp_path / "out.png"
    out.write_bytes(PREVIOUS)
    run = subprocess.Popen(
        [
            str(THURSTON),
            "render",
            "--space",
            space,
            "--scene",
            str(empty),
            "--size",
            "8x8",
            "--quality",
            "draft",
            "--threads",
            "2",
            *LONG_RAYS,
            "--out",
            str(out),
            "--overwrite",
        ],
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signals,
    )
    line = run.stderr.readline()
    while not line.startswith(f"render {space} ["):  # tracing has begun (warnings come before)
        line = run.stderr.readline()
    time.sleep(0.5)
    _, took, _ = stop(run, signum)
    print(f"{space} {signum.name}: stopped in {took:.3f} s")
    assert out.read_bytes() == PREVIOUS and listing(tmp_path) == ["empty.toml", "out.png"]


def test_more_threads_than_the_system_starts(tmp_path):
    """Threads the system refuses (here: an address-space limit of 3 GiB, which 1000 thread stacks
    exceed) give one error naming the count, at once (before: the pool deadlocked destroying its
    condition variable under the threads already started, and ignored SIGINT); beyond MAX_THREADS
    the request is refused before any thread starts."""
    out = tmp_path / "out.png"
    limit = lambda: resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))  # noqa: E731
    run = thurston(*render_args(out, "--threads", "1000"), preexec_fn=limit, timeout=60)
    assert run.returncode == 2, run.stderr
    assert re.fullmatch(
        r"thurston: error: cannot start 1000 threads: the system refused thread \d+ \(.+\); "
        r"ask for fewer threads",
        error_line(run.stderr),
    )
    run = thurston(*render_args(out, "--threads", "5000"))
    assert run.returncode == 2
    assert (
        error_line(run.stderr) == "thurston: error: threads must be a whole number from 0 (all cores) to 4096, got 5000"
    )
    assert listing(tmp_path) == []


@pytest.mark.parametrize(
    "option, kind",
    [(o, "fifo") for o in ("--space", "--scene", "--scene-obj", "--scene-gltf", "--rays")]
    + [("--space", "directory"), ("--scene-obj", "directory"), ("--rays", "device")],
)
def test_an_input_that_is_no_regular_file(tmp_path, option, kind):
    """A FIFO (which would block the read forever), a directory or a device as any input file: one
    error at once naming it (before: .toml FIFOs blocked, .obj ones were "does not exist")."""
    suffix = {"--space": ".toml", "--scene": ".toml", "--scene-obj": ".obj", "--scene-gltf": ".gltf", "--rays": ".npy"}[
        option
    ]
    if kind == "device":
        path = Path("/dev/null")
    else:
        path = tmp_path / f"input{suffix}"
        os.mkfifo(path) if kind == "fifo" else path.mkdir()
    what = {"--space": "space file", "--rays": "rays file"}.get(option, "scene file")
    described = {"fifo": "a FIFO (named pipe)", "directory": "a directory", "device": "a device"}[kind]
    if option == "--rays":
        args = ("trace", "--space", "torus", "--rays", path, "--out", tmp_path / "hits.npz")
    else:
        given = ("--space", path) if option == "--space" else ("--space", "torus", "--scene", path)
        args = ("render", *given, "--size", "8x8", "--out", tmp_path / "out.png")
    run = thurston(*args, timeout=60)
    assert run.returncode == 2
    assert error_line(run.stderr) == f"thurston: error: {what} {str(path)!r} is {described}, not a regular file"
