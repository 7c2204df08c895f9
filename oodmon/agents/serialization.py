"""The model format: ``model.safetensors`` (tensors only) beside ``model.json`` (metadata).

Loading never unpickles: safetensors holds raw tensors, JSON holds the rest. ``model.json``
records the sha256 of ``model.safetensors`` (``safetensors_sha256``) and loading checks it, so
flipped bytes (a bad copy, a tampered file) fail loudly instead of loading as a worse agent. A
file that is damaged, belongs to another task, or does not match the architecture its metadata
describes gives a :class:`~oodmon.errors.ModelFormatError` saying which and what to do.
"""

from __future__ import annotations

import hashlib
import warnings
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load, save_file

from oodmon.agents.networks import build_modules
from oodmon.errors import ModelFormatError
from oodmon.hashing import write_hashed_tensors
from oodmon.jsonfile import read_json
from oodmon.validation import not_a_file

__all__ = ["FORMAT_VERSION", "load_modules", "read_metadata", "save_modules"]

FORMAT_VERSION = 1
_REQUIRED = ("format_version", "task", "method", "algorithm", "architecture", "seed")


def save_modules(directory: str | Path, modules: torch.nn.Module, metadata: dict[str, Any], *, half: bool = False) -> Path:
    """Write ``modules``' tensors and ``metadata`` into ``directory``; return the directory.

    Args:
        half: store floating tensors as float16 (they load back as float32). Halves the size;
            use it where the agent's return does not change (checked by the caller).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tensors = {
        name: (t.detach().half() if half and t.is_floating_point() else t.detach()).contiguous().cpu()
        for name, t in modules.state_dict().items()
    }
    meta = {"format_version": FORMAT_VERSION, **metadata, "dtype": "float16" if half else "float32"}
    write_hashed_tensors(directory / "model.safetensors", directory / "model.json",
                         lambda path: save_file(tensors, path), meta, sort_keys=True)  # whole, or the agent before
    return directory


def read_metadata(directory: str | Path, *, task: str | None = None) -> dict[str, Any]:
    """The metadata of a saved model, checked; ``task`` also checks that it is that task's model."""
    path = Path(directory) / "model.json"
    if not path.is_file():
        raise ModelFormatError(f"{path} {not_a_file(path)}: a model directory holds model.json and model.safetensors")
    metadata = read_json(path, error=ModelFormatError)  # not JSON: the model's metadata is damaged
    missing = [key for key in _REQUIRED if key not in metadata]
    if not isinstance(metadata, dict) or missing:
        raise ModelFormatError(f"{path} lacks {', '.join(missing)}: not an oodmon model's metadata")
    if metadata["format_version"] != FORMAT_VERSION:
        raise ModelFormatError(
            f"{path} has format_version {metadata['format_version']!r}; this oodmon reads version {FORMAT_VERSION}"
        )
    if task is not None and metadata["task"] != task:
        raise ModelFormatError(f"{path} is a {metadata['task']} model, not a {task} model")
    return metadata


def load_modules(directory: str | Path, *, task: str | None = None) -> tuple[torch.nn.Module, dict[str, Any]]:
    """Load a saved model's modules (float32, eval mode) and its metadata.

    Raises:
        ModelFormatError: missing or damaged files (a sha256 other than the one ``model.json``
            records), another task's model, or tensors that do not match the architecture in the
            metadata.

    Warns:
        UserWarning: ``model.json`` records no sha256 (a model saved before oodmon recorded it):
            the tensors cannot be checked. Save it again to add one.
    """
    directory = Path(directory)
    metadata = read_metadata(directory, task=task)
    path = directory / "model.safetensors"
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ModelFormatError(f"{path} cannot be read ({error.strerror or error}); the file is missing") from None
    expected = metadata.get("safetensors_sha256")
    if expected is None:
        warnings.warn(f"{directory / 'model.json'} records no safetensors_sha256: the tensors in {path} cannot be "
                      "checked for damage", UserWarning, stacklevel=2)
    elif hashlib.sha256(data).hexdigest() != expected:
        raise ModelFormatError(f"{path} has sha256 {hashlib.sha256(data).hexdigest()[:16]}..., but model.json records "
                               f"{str(expected)[:16]}...: the file is damaged or was changed; copy the model again")
    try:
        tensors = load(data)
    except (SafetensorError, OSError, ValueError) as error:
        raise ModelFormatError(f"{path} cannot be read as safetensors ({error}); the file is damaged") from None
    try:
        modules = build_modules(metadata["architecture"])
    except ModelFormatError as error:
        raise ModelFormatError(f"{directory / 'model.json'}: {error}") from None
    expected = modules.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    wrong = sorted(k for k in set(expected) & set(tensors) if tensors[k].shape != expected[k].shape)
    if missing or unexpected or wrong:
        details = "; ".join(
            f"{label}: {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}"
            for label, names in (("missing", missing), ("unexpected", unexpected), ("wrong shape", wrong))
            if names
        )
        raise ModelFormatError(f"{path} does not match the architecture in model.json ({details})")
    modules.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in tensors.items()})
    return modules.eval(), metadata
