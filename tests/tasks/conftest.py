"""Task tests load robots offline from ../shared/robots when that folder exists (CI sets it too)."""

from __future__ import annotations

import os
import pathlib

_ROBOTS = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "robots"
if _ROBOTS.is_dir():
    os.environ.setdefault("MENAGERIE_ROOT", str(_ROBOTS))
