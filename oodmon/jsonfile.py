"""Reading a JSON file that a person gave, with errors that say what was expected; writing one whole."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from oodmon.errors import ConfigError, OodmonError

__all__ = ["read_json", "write_json"]


def read_json(path: str | Path, *, name: str = "", missing: str = "", folder: str = "",
              error: type[OodmonError] = ConfigError) -> Any:
    """The JSON value in ``path``.

    Args:
        name: what the file is, the start of each message ("threshold file"); empty: the path alone.
        missing, folder: what to do when the path does not exist, or is a folder.
        error: the error raised (a missing file, a folder, or text that is not JSON).

    Example:
        >>> read_json("no-such.json", name="threshold file", missing="make one with `oodmon calibrate`")
        Traceback (most recent call last):
        ...
        oodmon.errors.ConfigError: threshold file no-such.json does not exist; make one with `oodmon calibrate`
    """
    label = f"{name} {path}" if name else str(path)
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise error(f"{label} does not exist" + (f"; {missing}" if missing else "")) from None
    except IsADirectoryError:
        raise error(f"{label} is a folder" + (f"; {folder}" if folder else "")) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as reason:
        raise error(f"{label} is not valid JSON ({reason})") from None


def write_json(path: str | Path, data: Any) -> None:
    """``data`` as JSON at ``path``, whole or not at all: written beside it, then moved over it, so a
    process killed mid-write leaves the old file or none, never half of one."""
    path = Path(path)
    temporary = path.with_suffix(path.suffix + ".part")
    temporary.write_text(json.dumps(data, indent=1))
    os.replace(temporary, path)
