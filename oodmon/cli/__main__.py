"""``python -m oodmon.cli``: the same as ``python -m oodmon`` and the ``oodmon`` command (as when the
CLI was one module)."""

import sys

from oodmon.cli import console

sys.exit(console())
