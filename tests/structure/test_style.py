"""The tree keeps its style: ruff's lint and format (ruff.toml) over the Python, clang-format
(.clang-format) over the C++ core. The tools' versions are pinned in requirements.txt, so a newer
tool's taste never fails the tests."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def run(*argv: str) -> subprocess.CompletedProcess:
    tool = BIN / argv[0]
    if not tool.exists():
        pytest.fail(f"{tool} is missing: run scripts/setup.sh (requirements.txt installs it)")
    return subprocess.run([str(tool), *argv[1:]], cwd=ROOT, capture_output=True, text=True)


def test_ruff_finds_nothing():
    done = run("ruff", "check", "--output-format", "concise", ".")
    assert done.returncode == 0, done.stdout + done.stderr


def test_python_is_formatted():
    done = run("ruff", "format", "--check", ".")
    assert done.returncode == 0, f"run `ruff format .`:\n{done.stdout}{done.stderr}"


def test_cpp_is_formatted():
    sources = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "src").rglob("*") if p.suffix in (".cpp", ".hpp"))
    assert sources
    done = run("clang-format", "--dry-run", "--Werror", *sources)
    assert done.returncode == 0, f"run `clang-format -i` on the core:\n{done.stderr[:4000]}"
