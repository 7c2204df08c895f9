"""The sha256 of a file, as every record of oodmon spells it (weights, detectors, users' models),
of weights in memory (a ``state_dict()``), whether a recorded policy hash names other weights, and
a tensor file written whole beside the JSON that records its sha256."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.jsonfile import check_replaceable, write_json
from oodmon.outputs import is_write_error, write_failure

__all__ = ["file_sha256", "other_weights", "state_sha256", "write_hashed_tensors"]


def file_sha256(path: str | Path) -> str:
    """The hex sha256 of the file at ``path``.

    Example:
        >>> import tempfile
        >>> with tempfile.NamedTemporaryFile() as f:
        ...     file_sha256(f.name)[:16]
        'e3b0c44298fc1c14'
    """
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def state_sha256(state: Mapping[str, Any]) -> str:
    """The hex sha256 of weights in memory, names to tensors or arrays (a ``state_dict()``): each
    name and its numbers' bytes, in the names' order. It stands for an SB3 model in memory, which
    has no file, and for a plain policy's weights.

    Example:
        >>> import numpy as np
        >>> a = state_sha256({"w": np.ones(3)})
        >>> a == state_sha256({"w": np.ones(3)}), a == state_sha256({"w": np.ones(3, np.float32)})
        (True, False)
    """
    digest = hashlib.sha256()
    for name, value in sorted(state.items()):
        digest.update(name.encode())
        digest.update((value.detach().cpu().numpy() if hasattr(value, "detach") else np.asarray(value)).tobytes())
    return digest.hexdigest()


def other_weights(recorded: str | None, current: str | None, aliases: Sequence[str] = ()) -> bool:
    """Whether a threshold or fitted detectors that recorded the policy hash ``recorded`` were made
    for other weights than the policy of hash ``current`` (or of its ``aliases``, other hashes of
    the same weights); a hash not recorded on either side (``None``, ``""``, ``"unknown"``) is not
    compared.

    Example:
        >>> other_weights("sha256:aa", "sha256:bb"), other_weights("sha256:aa", "sha256:bb", ["sha256:aa"])
        (True, False)
        >>> other_weights("unknown", "sha256:bb"), other_weights("sha256:aa", None)
        (False, False)
    """
    unrecorded = (None, "", "unknown")
    return recorded not in unrecorded and current not in unrecorded and recorded not in {current, *aliases}


def write_hashed_tensors(tensor_path: Path, json_path: Path, write_tensors: Callable[[str], None],
                         metadata: dict[str, Any], *, sort_keys: bool = False) -> None:
    """The tensors ``write_tensors(path)`` writes, at ``tensor_path``, and ``metadata`` with their
    ``safetensors_sha256`` as JSON at ``json_path`` (a saved agent, a detector set).

    Both are written beside their names (``.part``), then moved over them back to back: a process
    killed or a disk filled while writing leaves the pair that was there whole, and no part file;
    only a kill between the two moves leaves a pair whose hash disagrees, which the readers refuse.
    """
    check_replaceable(tensor_path)
    check_replaceable(json_path)
    tensor_part, json_part = tensor_path.with_name(tensor_path.name + ".part"), json_path.with_name(json_path.name + ".part")
    written = tensor_path
    try:
        write_tensors(str(tensor_part))
        written = json_path
        write_json(json_part, {**metadata, "safetensors_sha256": file_sha256(tensor_part)}, sort_keys=sort_keys)
        os.replace(tensor_part, tensor_path)
        os.replace(json_part, json_path)
    except BaseException as error:
        tensor_part.unlink(missing_ok=True)
        json_part.unlink(missing_ok=True)
        if is_write_error(error):
            raise write_failure(written, error) from None  # a full disk: one line naming the file
        raise
