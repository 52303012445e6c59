"""The user cache: what is slow to make from its inputs and cheap to keep.

One folder, never in the checkout: ``$EVALKIT_CACHE``, else ``$XDG_CACHE_HOME/evalkit``, else
``~/.cache/evalkit``; ``EVALKIT_CACHE=off`` turns caching off. It holds references of your own
scenes (``references/``, `references.mitsuba.user_store`), imported scenes (``scenes/``) and
scene facts such as `evalkit scene info`'s resolution advice (``facts/``).

Imported scenes: a 2-million-triangle Mitsuba file took 9 s to import on every command (Mitsuba's
parse, the canonical order, assembly). A scene is kept under a key of everything its import reads:
the file's bytes; the size and modification time of each file it names (meshes, textures,
includes; for OBJ, PLY and glTF, every file in its folder and below); the importers' own source;
and the Mitsuba variant asked for. A file name the key cannot resolve (a ``$parameter``) is not
cached. Entries are written whole (`evalkit.core.atomic`); one that cannot be read is made again.
Nothing is ever evicted: delete the folder to reclaim its space.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import xml.etree.ElementTree as ElementTree
from pathlib import Path

from evalkit.core.atomic import atomic_path

CACHE_VARIABLE = "EVALKIT_CACHE"
FORMAT = b"evalkit-cache-1"
MAX_FOLDER_FILES = 2000  # a mesh file's folder with more files than this is not cached


def cache_root() -> Path | None:
    """The cache folder, or None when ``EVALKIT_CACHE=off``."""
    value = os.environ.get(CACHE_VARIABLE, "")
    if value.lower() == "off":
        return None
    if value:
        return Path(value)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "evalkit"


def load(kind: str, key: str):
    """The object cached under ``key``, or None."""
    root = cache_root()
    path = None if root is None else root / kind / f"{key}.pickle"
    if path is None or not path.is_file():
        return None
    try:
        with open(path, "rb") as f:
            return pickle.load(f)
    except Exception:  # noqa: BLE001 - a damaged or foreign entry is made again, never trusted
        return None


def store(kind: str, key: str, value) -> None:
    root = cache_root()
    if root is None:
        return
    path = root / kind / f"{key}.pickle"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
    except OSError:  # a full or read-only cache costs the next command its import, nothing more
        pass


def code_hash(*sources: Path) -> str:
    """SHA-256 of source files: a cached result is only as current as the code that made it."""
    h = hashlib.sha256(FORMAT)
    for source in sources:
        h.update(Path(source).read_bytes())
    return h.hexdigest()


def scene_key(spec: str, builtin: bool) -> str | None:
    """The cache key of the scene ``spec`` names (a built-in name or a file), or None when what it
    reads cannot be told."""
    # The importers and what they compute with: the scene package and the BSDFs' tables.
    readers = [*sorted((Path(__file__).parent / "scene").glob("*.py")), Path(__file__).parent / "bsdf.py"]
    h = hashlib.sha256(FORMAT + code_hash(*readers).encode())
    h.update(os.environ.get("EVALKIT_MITSUBA_VARIANT", "").encode())
    if builtin:
        h.update(b"builtin:" + spec.encode())
        return h.hexdigest()
    path = Path(spec).resolve()
    h.update(f"{path}\0".encode())  # the scene keeps its source's name and path
    h.update(path.read_bytes())
    dependencies = _xml_files(path) if path.suffix.lower() == ".xml" else _folder_files(path)
    if dependencies is None:
        return None
    for dep in sorted(set(dependencies)):
        try:
            st = dep.stat()
        except OSError:
            return None  # the import will say what is missing
        h.update(f"{dep}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
    return h.hexdigest()


def _xml_files(path: Path, seen: set | None = None) -> list[Path] | None:
    """The files a Mitsuba XML file names (``filename`` strings and includes), and theirs."""
    seen = seen if seen is not None else set()
    seen.add(path)
    try:
        root = ElementTree.parse(path).getroot()
    except (ElementTree.ParseError, OSError):
        return []  # the import reports it
    files = []
    for element in root.iter():
        name = element.get("filename") or (element.get("value") if element.get("name") == "filename" else None)
        if name is None:
            continue
        if "$" in name:
            return None
        dep = (path.parent / name).resolve()
        files.append(dep)
        if dep.suffix.lower() == ".xml" and dep not in seen and dep.is_file():
            more = _xml_files(dep, seen)
            if more is None:
                return None
            files += more
    return files


def _folder_files(path: Path) -> list[Path] | None:
    files = []
    for folder, _, names in os.walk(path.parent):
        files += [Path(folder) / n for n in names]
        if len(files) > MAX_FOLDER_FILES:
            return None
    return [f for f in files if f != path]
