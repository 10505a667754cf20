"""OpenImageIO / OpenEXR error texts turned into one readable line for the user.

OpenImageIO hands back the C++ library's messages: codes such as ``EXR_ERR_ATTR_SIZE_MISMATCH``,
the file path repeated inside, the same cause repeated several times, and, for damaged
headers, bytes that are not UTF-8 (the Python binding then raises ``UnicodeDecodeError``
instead of returning the text). :func:`error_text` always returns text (undecodable bytes
shown as ``\\xNN``); :func:`explain` says what is wrong with the file in a user's terms and
what to do about it, keeping the library's own words only where it has no translation.
"""

from __future__ import annotations

import re
import stat
from typing import Any

#: What a user can do about a file whose bytes are damaged.
REWRITE = "write or copy the file again"

_SEGMENT = re.compile(r"EXR Error \([^)]*\):\s*")
_CODE = re.compile(r"^(EXR_ERR_[A-Z_]+)\s*")


_SPECIAL_FILES = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def special_file_kind(mode: int) -> str | None:
    """What a file of ``st_mode`` ``mode`` is when it is not a regular file, else ``None``.

    >>> import os; special_file_kind(os.stat("/dev/null").st_mode)
    'a character device'
    """
    if stat.S_ISREG(mode):
        return None
    return next((desc for test, desc in _SPECIAL_FILES if test(mode)), "not a regular file")


def error_text(obj: Any) -> str:
    """``obj.geterror()`` as one line; never raises, never loses the text.

    Messages about damaged headers may hold bytes that are not UTF-8; the binding then raises
    ``UnicodeDecodeError`` whose ``object`` is the raw message: it is decoded with the bad
    bytes shown as ``\\xNN``.
    """
    try:
        text = obj.geterror()
    except UnicodeDecodeError as e:
        raw = e.object
        text = bytes(raw).decode("utf-8", "backslashreplace") if raw else ""
    except Exception:  # any other failure of the binding: no text
        text = ""
    if isinstance(text, bytes):
        text = text.decode("utf-8", "backslashreplace")
    return " ".join(str(text).split())


def readable_name(name: str) -> str:
    """A channel or attribute name with undecodable bytes (surrogate escapes) as ``\\xNN``."""
    try:
        name.encode("utf-8")
        return name
    except UnicodeEncodeError:
        return name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _segments(text: str, path: str) -> list[tuple[str, str]]:
    """(code, message) of each distinct cause in an OpenEXR text, in order."""
    text = text.replace(path, "FILE") if path else text
    out: list[tuple[str, str]] = []
    for seg in _SEGMENT.split(text):
        seg = seg.strip()
        if not seg:
            continue
        m = _CODE.match(seg)
        code, msg = (m.group(1), seg[m.end() :]) if m else ("", seg)
        if (code, msg) not in out:
            out.append((code, msg))
    return out


def _translate(code: str, msg: str) -> tuple[str, str] | None:
    """(what is wrong, kind) for a known OpenEXR message; kind is header/truncated/pixels."""
    if "End of file" in msg or (code == "EXR_ERR_READ_IO" and "Unable to read" in msg):
        return "the file ends inside its header (it is truncated)", "truncated"
    if m := re.search(r"[Aa]ttribute '([^']*)'.*Invalid (?:negative )?size", msg):
        return f"the header attribute '{m.group(1)}' has an impossible size", "header"
    if m := re.search(r"attribute '([^']*)': Invalid type '([^']*)'", msg):
        return f"the header attribute '{m.group(1)}' has the wrong type '{m.group(2)}'", "header"
    if m := re.search(r"Invalid (data|display) window \(([^)]*)\)", msg):
        nums = re.findall(r"-?\d+", m.group(2))
        box = f"({nums[0]},{nums[1]})-({nums[2]},{nums[3]})" if len(nums) == 4 else m.group(2)
        return f"the header's {m.group(1)} window {box} is impossible", "header"
    if m := re.search(r"'compression'.*Invalid value (\d+)", msg):
        return f"the header names an unknown compression (code {m.group(1)})", "header"
    if m := re.search(r"Invalid pixel type specified \((-?\d+)\) adding channel '([^']*)'", msg):
        return (
            f"channel '{m.group(2)}' has an unknown pixel type (code {m.group(1)}; "
            "valid: 0 uint, 1 half, 2 float)",
            "header",
        )
    if m := re.search(r"Invalid (pixel sampling|perceptual linear flag).*channel '([^']*)'", msg):
        return f"channel '{m.group(2)}' has an invalid {m.group(1)} in the header", "header"
    if m := re.search(r"channel '([^']*)': .*subsampling factor", msg):
        return f"channel '{m.group(1)}' has a sampling that does not fit the data window", "header"
    if m := re.search(r"Invalid pixel aspect ratio (\S+)", msg):
        return f"the header's pixel aspect ratio {m.group(1)} is impossible", "header"
    if m := re.search(r"'([^']*)' attribute not found", msg):
        return f"the header has no '{m.group(1)}' attribute", "header"
    if "chunks were missing or corrupted" in msg or "tiles were missing" in msg:
        return "the pixel data is corrupt or truncated (chunks missing or damaged)", "pixels"
    if m := re.search(r"claims a (\d+) MB image from a (\d+) byte file", msg):
        return (
            f"the header claims a {int(m.group(1)):,} MB image but the file has only "
            f"{int(m.group(2)):,} bytes (the header is corrupt)",
            "header",
        )
    if m := re.search(r"resolution (\S+) exceeds \"limits:resolution\" = (\d+)", msg):
        return (
            f"the header claims a resolution of {m.group(1)}, over {int(m.group(2)):,} pixels "
            "on one side (the header is corrupt)",
            "header",
        )
    if code == "EXR_ERR_FILE_BAD_HEADER" or code == "EXR_ERR_BAD_CHUNK_LEADER":
        return "the header is damaged", "header"
    return None


def explain(text: str, path: str, reading: str) -> str:
    """One line (without the leading path) saying what is wrong and what to do.

    Args:
        text: the library's message (from :func:`error_text`), possibly empty.
        path: the file (removed from inside the library's message).
        reading: what was being read, e.g. ``"the header"``, ``"the pixels of part 0"``.
    """
    found = []
    unknown = []
    for code, msg in _segments(text, path):
        t = _translate(code, msg)
        if t is None:
            unknown.append(msg.replace("FILE", "the file"))
        elif t not in found:
            found.append(t)
    if found:
        # The first cause is the root: later ones are OpenEXR retrying and failing again.
        what, kind = found[0]
        advice = {
            "truncated": REWRITE,
            "pixels": REWRITE,
            "header": f"the file is damaged: {REWRITE}",
        }[kind]
        return f"cannot read {reading}: {what}; {advice}"
    if unknown:
        detail = unknown[0]
        if len(detail) > 200:
            detail = detail[:197] + "..."
        return f"cannot read {reading} (OpenEXR says: {detail}); the file may be damaged: {REWRITE}"
    return f"cannot read {reading} (OpenEXR gave no reason); the file may be damaged: {REWRITE}"
