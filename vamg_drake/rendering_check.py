"""Checks that the shared libraries for headless (EGL) rendering are present."""

from __future__ import annotations

import ctypes.util

#: Debian/Ubuntu packages that provide them.
REQUIRED = {"EGL": "libegl1", "GL": "libgl1-mesa-dri (and libgl1)", "glib-2.0": "libglib2.0-0"}


class RenderingLibrariesMissing(RuntimeError):
    pass


def missing_rendering_libraries() -> list[str]:
    """Names of the Debian packages whose libraries cannot be found."""
    return [pkg for lib, pkg in REQUIRED.items() if ctypes.util.find_library(lib) is None]


def check_rendering_libraries() -> None:
    """Raises with the apt command to run when a library is missing."""
    missing = missing_rendering_libraries()
    if missing:
        raise RenderingLibrariesMissing(
            "headless depth rendering needs system libraries that are missing: "
            + ", ".join(missing)
            + ". Install them with: apt-get update && apt-get install -y libglib2.0-0 libegl1 libgl1 libgl1-mesa-dri"
            " (scripts/setup.sh does this)."
        )
