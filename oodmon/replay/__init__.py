"""What judges afterwards: metrics, the paper's tables and regression checks from recorded logs.

Not built yet: see the replay issue. It reads log files only, never a live process.
"""

__all__: list[str] = []
