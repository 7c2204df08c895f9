"""``python -m oodmon``: the same as the ``oodmon`` command."""

import sys

from oodmon.cli import console

sys.exit(console())
