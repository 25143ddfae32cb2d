"""What produced a result, and writing result files atomically.

Every ``episode.json`` and every results record carries ``provenance()``:
the code version (``git describe`` of the checkout the package runs from, or
the installed package version outside a checkout), the Drake version, the
seed and the resolved configuration, so a number can be traced back to the
code and settings that made it.

Result files are replaced atomically (``atomic_write_text``: a temporary file
in the same directory, flushed and fsynced, then ``os.replace``), so a killed
process leaves either the old file or the new one, never half of either.
"""

import dataclasses as dc
import functools
import os
import subprocess
import tempfile
from importlib import metadata
from pathlib import Path

PACKAGE = "vamg_drake"


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Replaces ``path`` with ``data`` atomically (temporary file + os.replace)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """Replaces ``path`` with ``text`` (UTF-8) atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


@functools.cache
def code_version() -> str:
    """``git describe --always --dirty`` of the package's checkout, else
    ``<package version>`` (an installed copy outside a checkout)."""
    root = Path(__file__).resolve().parents[1]
    if (root / ".git").exists():
        try:
            out = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty", "--tags"],
                                 capture_output=True, text=True, timeout=10, check=True)
            if out.stdout.strip():
                return f"git:{out.stdout.strip()}"
        except (OSError, subprocess.SubprocessError):
            pass
    try:
        return f"{PACKAGE} {metadata.version(PACKAGE)}"
    except metadata.PackageNotFoundError:
        return f"{PACKAGE} (unknown version)"


@functools.cache
def drake_version() -> str:
    """The installed Drake version (the ``drake`` distribution), or "unknown"."""
    try:
        return metadata.version("drake")
    except metadata.PackageNotFoundError:
        return "unknown"


def provenance(config=None, seed: int | None = None) -> dict:
    """Returns {code_version, drake_version, seed, config} for a result file.

    Args:
        config: a dataclass config (stored as a plain dict), a dict, or None.
        seed: the episode's seed(s) as recorded by the caller.
    """
    if config is not None and dc.is_dataclass(config):
        config = dc.asdict(config)
    return {"code_version": code_version(), "drake_version": drake_version(), "seed": seed, "config": config}
