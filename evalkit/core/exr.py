"""Float32 RGB OpenEXR files with provenance in the header.

Every image the toolkit writes carries the parameters and versions that made it as string header
attributes named ``evalkit.<key>`` (JSON for anything that is not a string), so a file found on
its own still says where it came from.
"""

from __future__ import annotations

import errno
import json
import os

import numpy as np

from evalkit.core.atomic import atomic_path
from evalkit.core.errors import InputError

PREFIX = "evalkit."


def write_exr(path: str | os.PathLike, rgb: np.ndarray, provenance: dict) -> None:
    """Write ``rgb`` (H, W, 3) as float32 RGB with ZIP compression (lossless)."""
    import OpenEXR

    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION}
    for key, value in provenance.items():
        header[PREFIX + key] = value if isinstance(value, str) else json.dumps(value)
    with atomic_path(path) as tmp:
        try:
            OpenEXR.File(header, {"RGB": rgb}).write(os.fspath(tmp))
        except RuntimeError as e:  # OpenEXR's word for every failed write; the system's error, as an OSError
            code = errno.ENOSPC if "No space left" in str(e) else errno.EIO
            raise OSError(code, os.strerror(code), os.fspath(path)) from e


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """(rgb (H, W, 3) float32, provenance dict) of an RGB or RGBA EXR; a missing or unreadable
    file raises `InputError`."""
    import OpenEXR

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(path, "file not found")
    try:
        with OpenEXR.File(path) as f:
            channels = f.channels()
            header = dict(f.header())  # the header object does not outlive the open file
            if "RGB" in channels:
                rgb = np.array(channels["RGB"].pixels)
            elif "RGBA" in channels:
                rgb = np.array(channels["RGBA"].pixels)[..., :3]
            elif {"R", "G", "B"} <= set(channels):
                rgb = np.stack([np.array(channels[c].pixels) for c in "RGB"], axis=-1)
            else:
                raise InputError(path, f"no RGB channels (has {', '.join(sorted(channels))})")
    except InputError:
        raise
    except Exception as e:  # OpenEXR raises plain exceptions with its own text
        raise InputError(path, f"not a readable OpenEXR file ({e})") from None
    provenance = {}
    for key, value in header.items():
        if isinstance(key, str) and key.startswith(PREFIX):
            try:
                provenance[key[len(PREFIX) :]] = json.loads(value)
            except (TypeError, ValueError):
                provenance[key[len(PREFIX) :]] = value
    return rgb.astype(np.float32), provenance
