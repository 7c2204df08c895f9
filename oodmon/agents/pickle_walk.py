"""What oodmon's two restricted unpicklers share (:mod:`oodmon.agents.vec_normalize`'s and
:mod:`oodmon.agents.sb3_pickles`'): a damaged pickle found before anything is built, and said in
one line.

A pickle's opcodes name the lengths of what follows them; a flipped bit in a length makes an
unpickler allocate that many bytes before it reads them (a ``MemoryError``, or a stall). Walking
the opcodes first (``pickletools.genops``, which builds nothing) fails at such a length instead.

Example:
    >>> walk_opcodes(b"\\x80\\x04K\\x05.")  # the pickle of 5: walked, nothing said
    >>> try:
    ...     walk_opcodes(b"\\x80\\x04\\x8e\\xff\\xff\\xff\\xff\\xff\\xff\\xff\\x7f")  # 8-byte length, no bytes
    ... except ValueError as error:
    ...     print(one_line(error)[:40])
    expected 9223372036854775807 bytes in a 
"""

from __future__ import annotations

import pickletools
import warnings

__all__ = ["one_line", "walk_opcodes"]


def walk_opcodes(raw: bytes) -> None:
    """Walk the opcodes of the pickle ``raw`` without building anything (quietly: other bytes read
    as opcodes can warn of string escapes).

    Raises:
        Exception: whatever ``pickletools.genops`` raises on damaged bytes (``ValueError`` mostly).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in pickletools.genops(raw):
            pass


def one_line(error: BaseException) -> str:
    """``error``'s message on one line (pickle's run over several), or its type's name if it has none."""
    return " ".join(str(error).split()) or type(error).__name__
