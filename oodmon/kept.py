"""The files where an interrupted command keeps the episodes it played whole, and from which the
same command goes on.

``calibrate`` keeps its calibration episodes' scores (:func:`oodmon.monitor.calibrate_agent`'s
``kept``), and the detectors it fitted before them (:func:`keep_detectors`); the detectors' fitting
its fitting episodes (:func:`oodmon.monitor.detectors.fit_detectors`'s ``kept``). A file is a
``.npz`` of arrays beside ``made_by``, the settings that made them (as JSON): a command of other
settings does not read it. Nothing in it is unpickled.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["KeptEpisodesWarning", "KeptFit", "SamplingTrail", "keep_detectors", "read_kept", "read_kept_detectors",
           "state_array", "state_of", "unreadable", "write_kept"]


class KeptEpisodesWarning(UserWarning):
    """A file of kept episodes that another command made (another policy, detector, seed or world),
    or that is no such file: it is not read, and is replaced if this command is interrupted too."""


def read_kept(path: str | Path, made_by: dict[str, Any], kind: str, *, stacklevel: int = 3) -> dict[str, np.ndarray]:
    """The arrays an interrupted ``kind`` (``"calibration"``, ``"fitting"``) kept in ``path`` (all but
    ``made_by``), where it was ``made_by`` the same settings; ``{}`` where there is no such file, and
    with a :class:`KeptEpisodesWarning` where it is another's or unreadable (a pickled object in it:
    numpy's ``allow_pickle=False`` refuses it)."""
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        with np.load(path, allow_pickle=False) as kept:
            theirs = json.loads(str(kept["made_by"]))
            arrays = {name: kept[name] for name in kept.files if name != "made_by"}
    # A damaged file makes zipfile and numpy's header parser raise errors of many kinds (measured by
    # scripts/fuzz_readers.py: BadZipFile, a bad CRC, NotImplementedError for a flipped compression
    # method, tokenize's TokenError); every one means the same: no episodes to go on from.
    except Exception as error:  # noqa: BLE001
        unreadable(path, kind, str(error), stacklevel=stacklevel + 1)
        return {}
    differ = _differs(theirs, made_by)
    if differ:
        warnings.warn(f"{path} holds the episodes of another {kind} ({differ}); it is not read, and is replaced",
                      KeptEpisodesWarning, stacklevel=stacklevel)
        return {}
    return arrays


def _differs(theirs: Any, made_by: dict[str, Any]) -> str:
    """What of ``made_by`` a kept file's own settings ``theirs`` differ in, in words (``""``: none).

    Example:
        >>> _differs({"seed": 1, "policy": "p"}, {"seed": 2, "policy": "p"}), _differs({"seed": 1}, {"seed": 1})
        ('its seed differs', '')
    """
    if theirs == json.loads(json.dumps(made_by)):  # (as JSON holds them: tuples as lists)
        return ""
    other = sorted(k for k in made_by if theirs.get(k) != made_by[k]) if isinstance(theirs, dict) else ["all"]
    return f"its {', '.join(other) or 'settings'} differ{'s' if len(other) == 1 else ''}"


def unreadable(path: str | Path, kind: str, why: str, *, stacklevel: int = 3) -> None:
    """The warning :func:`read_kept` gives a file that is no such file (``why``): for a caller whose
    arrays do not add up."""
    warnings.warn(f"{path} holds no {kind} episodes an interrupted {kind} kept ({why}); it is not read, and is "
                  "replaced", KeptEpisodesWarning, stacklevel=stacklevel)


def write_kept(path: str | Path, made_by: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` and ``made_by`` to ``path`` whole or not at all
    (:func:`oodmon.outputs.write_whole`), uncompressed: written in the moment Ctrl-C leaves.

    Raises:
        ValueError: an array of Python objects (numpy would pickle it, and it is not read back).
    """
    from oodmon.outputs import write_whole

    objects = sorted(name for name, array in arrays.items() if np.asarray(array).dtype.hasobject)
    if objects:
        raise ValueError(f"{objects[0]} holds Python objects, which oodmon does not keep")

    def write(part: Path) -> None:
        with open(part, "wb") as out:  # (a file, not a name: np.savez would add .npz to the part's name)
            np.savez(out, made_by=np.array(json.dumps(made_by)), **arrays)

    write_whole(Path(path), write)


def keep_detectors(folder: str | Path, made_by: dict[str, Any], detectors: Any, state: dict | None = None) -> bool:
    """Write the fitted ``detectors`` (a :class:`~oodmon.monitor.detectors.DetectorSet`) into
    ``folder`` beside ``kept.json`` (``made_by``; ``state``: where an MC policy's draws stood
    after the fit; how many epochs each learned detector trained): what ``calibrate`` fitted
    before its calibration stopped, which the same command reads instead of fitting again. Whether
    they were written (a full disk: said in a warning, the interrupt goes on as one)."""
    from oodmon.outputs import write_whole

    folder = Path(folder)
    # how many epochs each learned detector trained: a loaded set does not know it, and calibrate's
    # note that a cap of updates ended a fit early (fitting_notes) reads it
    trained = {d.name: d.epochs_trained for d in detectors if getattr(d, "epochs_trained", None) is not None}
    try:
        detectors.save(folder)
        write_whole(folder / "kept.json", lambda part: part.write_text(
            json.dumps({"made_by": made_by, "sampling_state": state, "epochs_trained": trained})))
    except OSError as error:
        warnings.warn(f"the detectors fitted before the calibration are not kept: {error}", stacklevel=3)
        return False
    return True


def read_kept_detectors(folder: str | Path, made_by: dict[str, Any]) -> tuple[Any, dict | None]:
    """The detectors :func:`keep_detectors` kept in ``folder`` where the same settings ``made_by``
    fitted them, and where the policy's draws stood after the fit (``None``: it draws nothing);
    ``(None, None)`` where there is no such folder, or (with a :class:`KeptEpisodesWarning`) it
    is another fit's or a damaged one. Read as every fitted set is read: tensors and JSON."""
    from oodmon.errors import ConfigError
    from oodmon.jsonfile import read_json
    from oodmon.monitor.detectors import DetectorSet
    from oodmon.validation import is_whole

    folder = Path(folder)
    if not (folder / "kept.json").is_file():
        return None, None
    try:
        kept = read_json(folder / "kept.json")
        theirs, state = kept["made_by"], kept["sampling_state"]
        detectors = DetectorSet.load(folder)
        for name, epochs in kept.get("epochs_trained", {}).items():  # (a folder kept before 2026-12-06: none)
            if name in detectors:
                if not is_whole(epochs) or epochs > detectors[name].epochs:
                    raise ValueError(f"{name} trained {epochs!r} of its {detectors[name].epochs} epochs")
                detectors[name].epochs_trained = epochs
    except (ConfigError, OSError, KeyError, TypeError, ValueError, AttributeError) as error:
        warnings.warn(f"{folder} holds no detectors an interrupted calibration kept ({error}); it is not read, and is "
                      "replaced", KeptEpisodesWarning, stacklevel=3)
        return None, None
    differ = _differs(theirs, made_by)
    if differ:
        warnings.warn(f"{folder} holds the detectors of another fit ({differ}); it is not read, and is replaced",
                      KeptEpisodesWarning, stacklevel=3)
        return None, None
    return detectors, state


class SamplingTrail:
    """Where an MC estimator's draws stand after each episode played in this process: kept with the
    episodes, so that a command that goes on from them draws on from there, as one never stopped
    (side by side each episode draws from a stream of its own, :mod:`oodmon.side_by_side`, and
    an estimator that draws nothing, an ensemble, needs none).

    Example:
        >>> import numpy as np, torch.nn as nn
        >>> from oodmon.agents.estimators import MCEstimator
        >>> from oodmon.agents.layers import add_dropout
        >>> est = MCEstimator(add_dropout(nn.Sequential(nn.Linear(4, 8), nn.ReLU(), nn.Linear(8, 2)), 0.5), seed=0)
        >>> trail, start = SamplingTrail(est, workers=1), est.sampling_state
        >>> _ = est.estimate(np.ones(4, np.float32)); trail.after_episode()
        >>> trail.state_after(0, start) == start, trail.state_after(1) == est.sampling_state != start
        (True, True)
        >>> SamplingTrail(est, workers=2).sampler is None  # side by side: each episode's own stream
        True
    """

    def __init__(self, estimator: Any, workers: int) -> None:
        self.sampler = estimator if workers == 1 and getattr(estimator, "draws", False) else None
        self.states: list[dict] = []

    @property
    def state(self) -> dict | None:
        """Where the estimator's draws stand now (``None``: it draws nothing, or plays side by side)."""
        return None if self.sampler is None else self.sampler.sampling_state

    def after_episode(self) -> None:
        """Note the state after an episode played whole here (call it as each one ends)."""
        if self.sampler is not None:
            self.states.append(self.state)

    def state_after(self, count: int, before: dict | None = None) -> dict | None:
        """The state after the first ``count`` episodes noted (``before``: the state they began
        from, for none), or ``None`` where nothing is noted."""
        if self.sampler is None:
            return None
        return self.states[count - 1] if count else before

    def resume(self, state: dict | None) -> None:
        """Draw on from ``state`` (a kept one; ``None``: from where the estimator stands)."""
        if state is not None and self.sampler is not None:
            self.sampler.sampling_state = state

    def progress(self, on_progress: Any) -> Any:
        """``on_progress`` (or nothing) that notes the state first: a command's progress is told
        once after each episode it plays in one process."""
        def noted(stage: str, done: int, total: int) -> None:
            self.after_episode()
            if on_progress is not None:
                on_progress(stage, done, total)

        return noted


def state_array(state: dict | None) -> dict[str, np.ndarray]:
    """``state`` as a kept file's array (none for ``None``)."""
    return {} if state is None else {"sampling_state": np.array(json.dumps(state))}


def state_of(arrays: dict[str, np.ndarray]) -> dict | None:
    """The sampling state a kept file holds, or ``None``."""
    return json.loads(str(arrays["sampling_state"])) if "sampling_state" in arrays else None


class KeptFit:
    """The detectors a calibration fits first (into ``folder``, ``<threshold>.detectors``), fitted so
    that nothing is lost when it stops: the fit's episodes played whole are kept in
    ``<folder>.kept.npz`` (:func:`~oodmon.monitor.detectors.fit_detectors`' ``kept``), and the set,
    once fitted, in ``<folder>.kept/`` when the calibration after it stops (:meth:`keep`), with where
    an MC policy's draws stood after the fit; the same calibration reads it instead of fitting again,
    and draws on from there. ``settings``: what the fit is of and with (the policy's hash, the
    detectors asked for, episodes...): a set kept with others is not read. ``oodmon calibrate`` and
    :func:`oodmon.watch` (with ``save=``) fit so.
    """

    def __init__(self, folder: str | Path, settings: dict[str, Any]) -> None:
        self.folder, self.settings = Path(folder), settings
        self.episodes_file = self.folder.with_name(self.folder.name + ".kept.npz")
        self.detectors_folder = self.folder.with_name(self.folder.name + ".kept")
        self.detectors: Any = None
        self.drawn: dict | None = None
        self.reused = False

    def fit(self, estimator: Any, fit: Any) -> Any:
        """The kept set where there is one of these settings (``estimator``, the policy's, then draws
        on from where the fit left it), else ``fit(episodes_file)``'s, a fit that keeps its episodes
        there when stopped (and reads them when going on)."""
        # (as in one process, side by side too: the episodes' own streams are drawn from where the fit left it)
        trail = SamplingTrail(estimator, workers=1)
        self.detectors, self.drawn = read_kept_detectors(self.detectors_folder, self.settings)
        self.reused = self.detectors is not None
        if self.reused:
            trail.resume(self.drawn)
            return self.detectors
        self.detectors = fit(self.episodes_file)
        self.episodes_file.unlink(missing_ok=True)
        self.drawn = trail.state
        return self.detectors

    def keep(self) -> bool:
        """Keep the set fitted (the calibration after it stopped); whether it was written."""
        return self.detectors is not None and keep_detectors(self.detectors_folder, self.settings, self.detectors,
                                                             self.drawn)

    def clear(self) -> None:
        """Remove the kept set: the calibration ended, its set written beside the threshold."""
        import shutil

        shutil.rmtree(self.detectors_folder, ignore_errors=True)
