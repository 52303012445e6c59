"""Text OBJ and PLY files checked line by line before trimesh reads them.

trimesh drops a face with fewer than three vertices without a word, and reports a bad index or a
stray word as numpy's error, with a 0-based index and no line. These checks name the file, the
1-based line and what is wrong, in one `InputError`. They read what trimesh reads (vertex and
face records); everything else is left to it. Binary PLY has no lines: trimesh refuses a binary
face list it cannot read whole, and `mesh_import` checks the faces that come back.
"""

from __future__ import annotations

from evalkit.core.errors import InputError

_OBJ_COORDINATES = {"v": 3, "vt": 1, "vn": 3}  # the fewest numbers each record needs
_OBJ_REFERENCES = ("v", "vt", "vn")  # f v/vt/vn


def check_obj(path: str, text: str) -> None:
    """Vertex records of enough numbers; faces of three or more references, each an integer that
    names a vertex (texture coordinate, normal) defined above it, 1-based or negative (relative)."""
    counts = dict.fromkeys(_OBJ_COORDINATES, 0)
    for number, words in _records(text):
        key = words[0]
        if key in _OBJ_COORDINATES:
            need = _OBJ_COORDINATES[key]
            if len(words) - 1 < need:
                raise _line_error(path, number, f"'{key}' needs {need} numbers, found {len(words) - 1}")
            for word in words[1 : need + 1]:
                _number(path, number, word, key)
            counts[key] += 1
        elif key == "f":
            if len(words) < 4:
                raise _line_error(path, number, f"a face needs 3 vertices or more, found {len(words) - 1}")
            for ref in words[1:]:
                parts = ref.split("/")
                if len(parts) > 3 or not parts[0]:
                    raise _line_error(path, number, f"'{ref}' is not a face vertex (v, v/vt, v//vn or v/vt/vn)")
                for kind, part in zip(_OBJ_REFERENCES, parts):
                    if part:
                        _reference(path, number, part, kind, counts[kind])


def _records(text: str):
    """(1-based line, words) of each non-empty OBJ record, comments cut and ``\\`` continuations
    joined (numbered by their first line)."""
    pending, start = [], 0
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split("#", 1)[0].split()
        if not pending:
            start = number
        if words and words[-1] == "\\":
            pending += words[:-1]
            continue
        words, pending = pending + words, []
        if words:
            yield start, words


def _reference(path, number, word, kind, defined) -> None:
    try:
        index = int(word)
    except ValueError:
        raise _line_error(path, number, f"face {kind} index '{word}' is not an integer") from None
    if index == 0 or index > defined or index < -defined:
        raise _line_error(path, number, f"face {kind} index {index} names none of the {defined} '{kind}' above it")


def _number(path, number, word, key) -> float:
    try:
        return float(word)
    except ValueError:
        raise _line_error(path, number, f"'{key}' value '{word}' is not a number") from None


def check_ply(path: str, data: bytes) -> None:
    """A text PLY's element records against its header: each line the properties' count of
    numbers, faces of three or more vertex indices within the vertex count."""
    head, sep, body = data.partition(b"end_header")
    if not sep or not head.lstrip().startswith(b"ply"):
        return  # not a PLY trimesh can read either; its own error says so
    header = head.decode("ascii", "replace").splitlines()
    if not any(line.split()[:2] == ["format", "ascii"] for line in header):
        return
    elements = []  # (name, count, [(property, is_list)])
    for number, line in enumerate(header, 1):
        words = line.split()
        if words[:1] == ["element"] and len(words) == 3:
            try:
                elements.append((words[1], int(words[2]), []))
            except ValueError:
                raise _line_error(path, number, f"element count '{words[2]}' is not an integer") from None
        elif words[:1] == ["property"] and elements and len(words) >= 3:
            elements[-1][2].append((words[-1], words[1] == "list"))
    vertices = next((count for name, count, _ in elements if name == "vertex"), 0)
    lines = body.decode("ascii", "replace").splitlines()[1:]  # the rest of the end_header line
    number = len(header) + 1
    for name, count, properties in elements:
        for _ in range(count):
            number += 1
            if number - len(header) - 2 >= len(lines):
                raise _line_error(path, number, f"the file ends inside element '{name}' ({count} declared)")
            _ply_record(path, number, lines[number - len(header) - 2].split(), name, properties, vertices)


def _ply_record(path, number, words, element, properties, vertices) -> None:
    at = 0
    for prop, is_list in properties:
        if is_list:
            if at >= len(words):
                raise _line_error(path, number, f"{element} record ends before its list '{prop}'")
            length = _number(path, number, words[at], prop)
            if length != int(length) or length < 0:
                raise _line_error(path, number, f"list length '{words[at]}' of '{prop}' is not a count")
            items = words[at + 1 : at + 1 + int(length)]
            if len(items) < int(length):
                raise _line_error(path, number, f"'{prop}' declares {int(length)} items, the line has {len(items)}")
            if element == "face" and prop in ("vertex_indices", "vertex_index"):
                if len(items) < 3:
                    raise _line_error(path, number, f"a face needs 3 vertices or more, found {len(items)}")
                for word in items:
                    index = _number(path, number, word, prop)
                    if index != int(index) or not 0 <= index < vertices:
                        raise _line_error(path, number, f"face vertex index {word} is not one of 0..{vertices - 1}")
            else:
                for word in items:
                    _number(path, number, word, prop)
            at += 1 + int(length)
        else:
            if at >= len(words):
                raise _line_error(path, number, f"{element} record has {len(words)} values, '{prop}' is missing")
            _number(path, number, words[at], prop)
            at += 1
    if at != len(words):
        raise _line_error(path, number, f"{element} record has {len(words)} values, its properties take {at}")


def _line_error(path, number, problem) -> InputError:
    return InputError(path, f"line {number}: {problem}")
