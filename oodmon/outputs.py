"""Output files: checks that a path can be written, made before any work that would be lost
otherwise; file names made from specs; figures saved.

A run that writes its log at the end of minutes of episodes, or a calibration that writes its
threshold after all of them, should fail at once when the path cannot be written: a folder in
its place, a parent that is a file, a name too long, a place the user may not write, or a path
that is also one of the command's inputs (writing it would destroy the input).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path

from oodmon.errors import ConfigError
from oodmon.jsonfile import check_replaceable

__all__ = ["PICTURE_SUFFIXES", "check_output_dir", "check_output_file", "check_picture_file", "replaced_file",
           "is_write_error", "safe_filename", "save_figure", "write_failure", "write_whole"]


def _same(a: Path, b: Path) -> bool:
    return a.resolve() == b.resolve()


def check_output_file(path: str | Path, *, parameter: str,
                      inputs: Iterable[tuple[str, str | Path | None]] = ()) -> Path:
    """``path`` as a :class:`~pathlib.Path` if a file can be written there, else :class:`ConfigError`.

    Creates the missing parent folders (the write would create them too) and nothing else: a file
    made to test the path is removed again.

    Args:
        path: the file to be written.
        parameter: the option that named it, for the message (``--mcap``).
        inputs: ``(option, path)`` of the command's inputs and of its other outputs; ``path`` may
            be none of them. ``None`` paths are ignored.

    Example:
        >>> import shutil, tempfile
        >>> folder = tempfile.mkdtemp()
        >>> check_output_file(folder, parameter="--out")
        Traceback (most recent call last):
        ...
        oodmon.errors.ConfigError: --out ... is a folder; give a file name
        >>> shutil.rmtree(folder)
    """
    path = Path(path)
    if not str(path).strip():
        raise ConfigError(f"{parameter} {str(path)!r} is empty; give a file name")
    try:
        return _check_file(path, parameter, inputs)
    except OSError as error:  # the name itself is unusable (too long, ...)
        raise ConfigError(f"{parameter} {path} cannot be written ({_reason(error)})") from None


#: The picture formats oodmon writes (OpenCV and matplotlib both write these).
PICTURE_SUFFIXES = (".png", ".jpg", ".jpeg")


def check_picture_file(path: str | Path, *, parameter: str,
                       inputs: Iterable[tuple[str, str | Path | None]] = ()) -> Path:
    """:func:`check_output_file` for a picture: a name without a suffix gets ``.png`` (the name
    returned is the file that will be written), a suffix of another format is a :class:`ConfigError`.

    Example:
        >>> import shutil, tempfile
        >>> folder = tempfile.mkdtemp()
        >>> check_picture_file(Path(folder) / "shot", parameter="--out").name
        'shot.png'
        >>> shutil.rmtree(folder)
    """
    path = Path(path)
    if not path.suffix and str(path).strip():
        path = path.with_name(path.name + ".png")
    elif path.suffix.lower() not in PICTURE_SUFFIXES:
        raise ConfigError(f"{parameter} {path}: write a picture as {', '.join(PICTURE_SUFFIXES)}, not "
                          f"{path.suffix or 'an empty name'}")
    return check_output_file(path, parameter=parameter, inputs=inputs)


def _check_file(path: Path, parameter: str, inputs: Iterable[tuple[str, str | Path | None]]) -> Path:
    for name, other in inputs:
        if other is not None and _same(path, Path(other)):
            raise ConfigError(f"{parameter} {path} is also {name}; writing it would overwrite that file: "
                              "give another path")
    if path.is_dir():
        raise ConfigError(f"{parameter} {path} is a folder; give a file name")
    check_replaceable(path, f"{parameter} {path}")  # a write moves a file over the name: /dev/zero would become one
    _make_parent(path, parameter)
    existed = path.exists()
    try:
        with open(path, "ab"):
            pass
    except OSError as error:
        raise ConfigError(f"{parameter} {path} cannot be written ({_reason(error)})") from None
    if not existed:
        path.unlink(missing_ok=True)
    return path


def replaced_file(path: str | Path, *, parameter: str, holds: str, read: Callable[[Path], object]) -> object | None:
    """What an output file a command will replace holds, as ``read`` reads it (``None``: no file
    there). A file there that ``read`` refuses (:class:`ConfigError`) is refused, with its reason:
    a command that writes ``holds`` (a threshold, a baseline) replaces only such a file, not a
    model or a log at a name typed wrong. Call it before the work.

    Example:
        >>> import shutil, tempfile
        >>> log = Path(tempfile.mkdtemp()) / "run.mcap"
        >>> _ = log.write_bytes(b"an MCAP log")
        >>> def read_threshold(path):
        ...     raise ConfigError(f"{path.name} is not valid JSON")
        >>> replaced_file(log, parameter="--out", holds="threshold", read=read_threshold)
        Traceback (most recent call last):
        ...
        oodmon.errors.ConfigError: --out ... exists and holds no threshold (run.mcap is not valid JSON): ...
        >>> shutil.rmtree(log.parent)
    """
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with warnings.catch_warnings():  # fields a newer oodmon wrote: such a file all the same
            warnings.simplefilter("ignore")
            return read(path)
    except ConfigError as error:
        raise ConfigError(f"{parameter} {path} exists and holds no {holds} ({error}): it would be replaced; give "
                          "another path (or remove that file first)") from None


def check_output_dir(path: str | Path, *, parameter: str, create: bool = True) -> Path:
    """``path`` as a :class:`~pathlib.Path` if it is (or can be made) a writable folder, else
    :class:`ConfigError`. Creates it; ``create=False``: only checks that it can be (makes it, then
    removes what it made), for a folder that its writer makes once it has something to put there
    (a calibration's detectors: made first, an interrupted calibration left it empty beside the
    threshold it did not write, 2026-12-06).

    Example:
        >>> import os, shutil, tempfile
        >>> folder = tempfile.mkdtemp()
        >>> check_output_dir(os.path.join(folder, "plots"), parameter="--plots").is_dir()
        True
        >>> check_output_dir(os.path.join(folder, "a", "later"), parameter="--out", create=False).exists()
        False
        >>> os.listdir(folder)
        ['plots']
        >>> shutil.rmtree(folder)
    """
    path = Path(path)
    if not str(path).strip():
        raise ConfigError(f"{parameter} {str(path)!r} is empty; give a folder")
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{parameter} {path} is a file; give a folder")
    missing = [folder for folder in (path, *path.parents) if not folder.exists()]  # deepest first
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"{parameter} {path} cannot be made a folder ({_reason(error)})") from None
    writable = os.access(path, os.W_OK | os.X_OK)
    if not create:  # made to see that it can be, and removed again
        for folder in missing:
            with contextlib.suppress(OSError):  # ('a/..' of 'a/../b', or another process's file in it since)
                folder.rmdir()
    if not writable:
        raise ConfigError(f"{parameter} {path} cannot be written (permission denied)")
    return path


def _make_parent(path: Path, parameter: str) -> None:
    for ancestor in path.parents:
        if ancestor.exists():
            if not ancestor.is_dir():
                raise ConfigError(f"{parameter} {path} cannot be written: {ancestor} is a file, not a folder")
            break
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"{parameter} {path} cannot be written ({_reason(error)})") from None


def _reason(error: OSError) -> str:
    if error.errno == errno.ENAMETOOLONG:
        return "the file name is too long"
    return error.strerror or str(error)


def write_whole(path: Path, write: Callable[[Path], object], *, part: Path | None = None) -> None:
    """What ``write(part)`` writes, at ``path``: written at ``part`` (default ``<path>.part``) and
    moved over ``path``, so that a kill or a full disk mid-write leaves the file before, never half
    of one, and no part file. A failed write is an :class:`OSError` naming ``path`` and the space
    left on its disk: torch's and safetensors' writers raise errors of their own for a full disk
    (measured: ``RuntimeError: [enforce fail at inline_container.cc:672] . unexpected pos ...`` and
    ``SafetensorError: ... No space left on device``), which reached the user as tracebacks.

    Example:
        >>> import shutil, tempfile
        >>> path = Path(tempfile.mkdtemp()) / "x.txt"
        >>> write_whole(path, lambda part: part.write_text("whole"))
        >>> path.read_text(), sorted(p.name for p in path.parent.iterdir())
        ('whole', ['x.txt'])
        >>> shutil.rmtree(path.parent)
    """
    check_replaceable(path)
    part = path.with_name(path.name + ".part") if part is None else part
    try:
        write(part)
        os.replace(part, path)
    except BaseException as error:
        part.unlink(missing_ok=True)
        if is_write_error(error):
            raise write_failure(path, error) from None
        raise


def is_write_error(error: BaseException) -> bool:
    """Whether ``error`` is a writer's failure to write (a full disk): an :class:`OSError`, or the
    errors torch's and safetensors' writers raise instead of one."""
    from safetensors import SafetensorError

    return isinstance(error, (OSError, RuntimeError, SafetensorError))


def write_failure(path: Path, error: BaseException) -> OSError:
    """An :class:`OSError` saying that ``path`` could not be written, why, and how much room its disk has."""
    reason = _reason(error) if isinstance(error, OSError) else " ".join(str(error).split())[:160]
    folder = next((p for p in Path(path).absolute().parents if p.exists()), Path("/"))
    free = shutil.disk_usage(folder).free / 1e6
    failure = OSError(f"{path} could not be written ({reason}; {free:.1f} MB free on its disk)")
    failure.errno = getattr(error, "errno", None) or errno.EIO  # the message is the one line oodmon prints
    return failure


def safe_filename(text: str) -> str:
    """``text`` (a spec, a method, a label) as a file name: every run of characters other than
    letters, digits, ``_``, ``.`` and ``-`` becomes one ``_``.

    Example:
        >>> safe_filename("cartpole:length=2.0"), safe_filename("pong:motion_blur@3")
        ('cartpole_length_2.0', 'pong_motion_blur_3')
    """
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def save_figure(fig, path: str | Path) -> Path:
    """Save a matplotlib figure to ``path`` (its folder made), laid out tightly, and close it; whole
    or not at all (:func:`write_whole`: a full disk left an empty PNG and an error naming no file)."""
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fig.tight_layout()
        write_whole(path, lambda part: fig.savefig(part, format=path.suffix[1:] or None))  # the part's suffix is .part
    finally:
        plt.close(fig)
    return path
