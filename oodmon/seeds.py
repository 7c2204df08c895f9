"""Named seed ranges: which episodes are used for what, so that "held out" holds.

Every range below is a half-open interval of ``reset`` seeds; ``tests/test_seeds.py`` checks
that no two overlap. Use the names, not the numbers.

Named but not ranges: training's periodic evaluations play seeds :data:`TRAINING_EVALUATION` +
steps (steps up to 2 million, so they overlap every range below), its choice among snapshots
:data:`SNAPSHOT_SELECTION` + i, and ``evaluate_variants`` (where an agent fails)
:data:`VARIANT_EVALUATION` + i. Those episodes only choose which weights to ship or which variants
to monitor, never calibrate or score a monitor; moving them changes which snapshot a retraining
ships, so it waits for the next retraining of the zoo.
"""

from __future__ import annotations

from oodmon.errors import InvalidParameterError
from oodmon.validation import is_whole

__all__ = ["BENCH_ID", "BENCH_SHIFTED", "CALIBRATION", "DEMO", "DETECTOR_FIT", "EPISODE_USES", "ID_RETURN", "MOST_SEED",
           "RANGES", "REFERENCE", "SNAPSHOT_SELECTION", "TRAINING_EVALUATION", "VALIDATION", "VARIANT_EVALUATION",
           "check_seed", "range_of", "use_words"]

#: Training's periodic evaluations: 10,000 + steps (see above: not a range).
TRAINING_EVALUATION = 10_000
#: ``evaluate_variants``, where an agent fails (``oodmon evaluate``, the bench): 10,000 + i.
VARIANT_EVALUATION = 10_000
#: The choice among a training's snapshots at export (``Recipe.select_top``): 50,000 + i.
SNAPSHOT_SELECTION = 50_000
#: ID return of a trained model (``id_return_mean``): 100,000 + i.
ID_RETURN = 100_000
#: Threshold calibration episodes (``oodmon calibrate``): 200,000 + i.
CALIBRATION = 200_000
#: The demo's monitored episodes: 300,000 + i.
DEMO = 300_000
#: The bench's ID and shifted evaluation episodes: 400,000 + i and 500,000 + i.
BENCH_ID = 400_000
BENCH_SHIFTED = 500_000
#: ID episodes the learned detectors are fitted on (``fit_detectors``): 600,000 + i.
DETECTOR_FIT = 600_000
#: Fresh ID episodes that check a threshold's false-alarm rate (``oodmon validate``): 700,000 + i.
VALIDATION = 700_000

#: ID episodes whose scores a sequential rule's p-values are taken against (``calibrate --rule
#: cusum``): 800,000 + i; apart from the calibration episodes, which must stay exchangeable with
#: a fresh one.
REFERENCE = 800_000

#: The largest first seed a run of episodes takes (``--seed`` of every command, ``check_seed``):
#: numpy's legacy seeding, which SB3's ``set_random_seed`` calls, takes none larger, and torch's
#: generators none past 2**64 (``fit_agent_detectors(seed=10**30)`` failed in them, 2026-12-05).
MOST_SEED = 2**32 - 1

#: name -> (first seed, end) of each range.
RANGES: dict[str, tuple[int, int]] = {
    "id_return": (ID_RETURN, ID_RETURN + 100_000),
    "calibration": (CALIBRATION, CALIBRATION + 100_000),
    "demo": (DEMO, DEMO + 100_000),
    "bench_id": (BENCH_ID, BENCH_ID + 100_000),
    "bench_shifted": (BENCH_SHIFTED, BENCH_SHIFTED + 100_000),
    "detector_fit": (DETECTOR_FIT, DETECTOR_FIT + 100_000),
    "validation": (VALIDATION, VALIDATION + 100_000),
    "reference": (REFERENCE, REFERENCE + 100_000),
}


#: The uses of the ID episodes a threshold was made from (``oodmon.monitor.calibration.seeds_used``),
#: in words (here, importing only oodmon's errors and number tests, for ``oodmon replay``, which
#: plays no policy).
EPISODE_USES = {"calibration": "the threshold's calibration", "reference": "the sequential rule's reference",
                "detector fitting": "the detectors' fitting"}


def use_words(use: str) -> str:
    """A use of :data:`EPISODE_USES` in words, a numbered one too (``calibration 2``: the second run
    of consecutive seeds of a threshold calibrated on logs, ``oodmon recalibrate``); another, as it is.

    Example:
        >>> use_words("calibration 2"), use_words("detector fitting"), use_words("bench")
        ("the threshold's calibration", "the detectors' fitting", 'bench')
    """
    base, _, number = use.rpartition(" ")
    return EPISODE_USES.get(use) or EPISODE_USES.get(base if number.isdigit() else use, use)


def range_of(seed: int) -> str | None:
    """The name of the range ``seed`` falls in, or ``None``.

    Example:
        >>> range_of(200_017), range_of(7)
        ('calibration', None)
    """
    return next((name for name, (low, high) in RANGES.items() if low <= seed < high), None)


def check_seed(seed: object, name: str = "seed") -> int:
    """``seed``, the first of a run of episodes' ``reset`` seeds, as a Python int: a whole number
    from 0 to :data:`MOST_SEED`, numpy's integers too (gymnasium takes Python ints only, and a
    threshold records its seeds as JSON).

    Raises:
        InvalidParameterError: anything else (a float, a negative number, 2**32), naming ``name``.

    Example:
        >>> import numpy as np
        >>> check_seed(np.int64(3)), check_seed(0)
        (3, 0)
    """
    if not is_whole(seed, minimum=0) or seed > MOST_SEED:
        raise InvalidParameterError(f"{name}={seed!r} is not allowed; give a whole number from 0 to {MOST_SEED} (the "
                                    "first episode's reset seed)")
    return int(seed)
