"""Reading a JSON file that a person gave, with errors that say what was expected; writing one whole."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

from oodmon.errors import ConfigError, OodmonError

__all__ = ["MOST_JSON_BYTES", "check_replaceable", "read_json", "special_file", "write_json"]

#: The most bytes :func:`read_json` reads. The largest JSON oodmon writes is a bench's results
#: (165 KB in results/); a path that never ends (``/dev/zero``, given as a threshold) was read
#: whole into memory until the system killed the command, 24 GB later (2026-12-05).
MOST_JSON_BYTES = 256 * 2**20


def read_json(path: str | Path, *, name: str = "", missing: str = "", folder: str = "",
              error: type[OodmonError] = ConfigError) -> Any:
    """The JSON value in ``path``.

    Args:
        name: what the file is, the start of each message ("threshold file"); empty: the path alone.
        missing, folder: what to do when the path does not exist, or is a folder.
        error: the error raised (a missing file, a folder, text that is not JSON, or more than
            :data:`MOST_JSON_BYTES`).

    Example:
        >>> read_json("no-such.json", name="threshold file", missing="make one with `oodmon calibrate`")
        Traceback (most recent call last):
        ...
        oodmon.errors.ConfigError: threshold file no-such.json does not exist; make one with `oodmon calibrate`
    """
    label = f"{name} {path}" if name else str(path)
    try:
        with open(path, "rb") as file:
            raw = file.read(MOST_JSON_BYTES + 1)
        if len(raw) > MOST_JSON_BYTES:
            raise error(f"{label} holds more than {MOST_JSON_BYTES // 2**20} MB, far more than any JSON file oodmon "
                        "writes: not the file meant?")
        return json.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise error(f"{label} does not exist" + (f"; {missing}" if missing else "")) from None
    except IsADirectoryError:
        raise error(f"{label} is a folder" + (f"; {folder}" if folder else "")) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as reason:
        raise error(f"{label} is not valid JSON ({reason})") from None


#: What a name that is not a regular file stands for, by its kind in ``stat``.
_SPECIAL = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
            (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket"))


def special_file(path: str | Path) -> str | None:
    """What ``path`` is where it names something other than a regular file that a move would put a
    file in place of (``"a character device"``: ``/dev/null``; a folder, a named pipe, a socket),
    else ``None`` (a regular file, a symbolic link, which a move replaces and not its target, or
    nothing).

    Example:
        >>> special_file("/dev/null"), special_file("no-such.json")
        ('a character device', None)
    """
    try:
        mode = os.lstat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None
    return next((kind for test, kind in _SPECIAL if test(mode)), None)


def check_replaceable(path: str | Path, label: str = "") -> None:
    """Raise :class:`ConfigError` where ``path`` is not a regular file (:func:`special_file`), which
    a file oodmon writes would be moved over (``os.replace``: as root, ``calibrate --out /dev/zero``
    turned /dev/zero into a threshold file, 2026-12-05): every writer that moves a file into place
    checks its name first, before it writes anything. ``label`` names it in the message (default:
    the path, e.g. ``--out /dev/null``)."""
    kind = special_file(path)
    if kind is not None:
        raise ConfigError(f"{label or path} is {kind}, not a file: oodmon writes a file whole by moving a new one "
                          "over its name, which would put a file in its place; give a file name")


def write_json(path: str | Path, data: Any, *, sort_keys: bool = False) -> None:
    """``data`` as JSON at ``path`` (indented, a newline at its end), whole or not at all: written
    beside it, then moved over it, so a process killed mid-write, or a full disk, leaves the old file
    or none, never half of one.

    Raises:
        OSError: the file cannot be written; its message names ``path`` (a full disk's ``write()``
            error names no file), and nothing is left beside it.
    """
    path = Path(path)
    check_replaceable(path)
    temporary = path.with_suffix(path.suffix + ".part")
    try:
        temporary.write_text(json.dumps(data, indent=1, sort_keys=sort_keys) + "\n")
        os.replace(temporary, path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        raise OSError(error.errno, error.strerror or str(error), str(path)) from None
