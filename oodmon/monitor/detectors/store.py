"""A set of detectors as the monitor runs them, and its files.

``detectors.safetensors`` holds every fitted detector's arrays (keys ``<detector>/<array>``);
``detectors.json`` holds their settings, what they were fitted for (task, observation shape,
the policy's weights) and the sha256 of the tensor file, checked at load. Nothing is unpickled.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from oodmon.errors import ConfigError
from oodmon.jsonfile import read_json
from oodmon.monitor.detectors.base import Detector, StepContext
from oodmon.monitor.detectors.combined import CombinedDetector
from oodmon.monitor.detectors.drift import DriftDetector
from oodmon.monitor.detectors.dynamics import DynamicsDetector
from oodmon.monitor.detectors.features import FeaturesDetector
from oodmon.monitor.detectors.frames import FramesDetector
from oodmon.monitor.detectors.motion import MotionDetector
from oodmon.monitor.detectors.scaled_spread import ScaledSpreadDetector
from oodmon.monitor.detectors.spread import SpreadDetector
from oodmon.monitor.detectors.stillness import StillnessDetector
from oodmon.monitor.detectors.transitions import TransitionsDetector
from oodmon.monitor.detectors.vanishing import VanishingDetector
from oodmon.hashing import other_weights, write_hashed_tensors
from oodmon.validation import not_a_file

__all__ = ["DETECTORS", "DetectorSet"]

#: Detector classes by name.
DETECTORS: dict[str, type[Detector]] = {
    "spread": SpreadDetector, "dynamics": DynamicsDetector, "features": FeaturesDetector, "frames": FramesDetector,
    "combined": CombinedDetector, "scaled_spread": ScaledSpreadDetector, "drift": DriftDetector,
    "transitions": TransitionsDetector, "stillness": StillnessDetector, "motion": MotionDetector,
    "vanishing": VanishingDetector,
}
FORMAT = "oodmon.detectors"
FORMAT_VERSION = 1


class DetectorSet:
    """Detectors run together at each step, in order, ``combined`` last (it reads the others).

    Args:
        detectors: at most one of each name.
        fitted_for: what the learned ones were fitted for: ``task``, ``obs_shape``, ``policy_hash``
            and how (``episodes``, ``seed``, ``obs_noise``); recorded in the files.
    """

    def __init__(self, detectors: Sequence[Detector], *, fitted_for: Mapping[str, Any] | None = None) -> None:
        names = [d.name for d in detectors]
        if len(set(names)) != len(names):
            raise ConfigError(f"one detector of each name: got {names}")
        self._detectors = {d.name: d for d in sorted(detectors, key=lambda d: d.name == "combined")}
        self.fitted_for = dict(fitted_for or {})
        drift, dynamics = self._detectors.get("drift"), self._detectors.get("dynamics")
        if drift is not None and dynamics is not None:
            drift.read_from(dynamics)  # one forward pass of a step serves both
        combined = self._detectors.get("combined")
        if combined is not None:
            missing = [m for m in combined.members if m not in self._detectors]
            if missing:
                raise ConfigError(f"the combined detector combines {', '.join(missing)}, which the set lacks")

    @property
    def names(self) -> list[str]:
        return list(self._detectors)

    def __getitem__(self, name: str) -> Detector:
        if name not in self._detectors:
            raise ConfigError(f"no {name!r} detector here; this monitor has {', '.join(self._detectors) or 'none'}")
        return self._detectors[name]

    def __contains__(self, name: object) -> bool:
        return name in self._detectors

    def __iter__(self) -> Iterator[Detector]:
        return iter(self._detectors.values())

    def __len__(self) -> int:
        return len(self._detectors)

    def with_detector(self, detector: Detector) -> DetectorSet:
        """A set with ``detector`` added (or replacing the one of its name)."""
        kept = [d for d in self if d.name != detector.name]
        return DetectorSet([*kept, detector], fitted_for=self.fitted_for)

    def for_score(self, score: str) -> tuple[DetectorSet, str | None]:
        """The set with its ``spread`` computed by ``score``, and why ``combined`` was left out, if it was.

        A fitted ``combined`` detector ranks ``spread`` among the ID scores of the score it was fitted
        with; against another score those ranks mean nothing, so it is left out (refit it with the
        score you want: ``fit_detectors(..., score=...)``, ``oodmon fit-detectors --score``). A set without
        ``spread``, or whose ``spread`` already has ``score``, comes back as it is.
        """
        if "spread" not in self or self["spread"].score_name == score:
            return self, None
        fitted = self["spread"].score_name
        changed = self.with_detector(SpreadDetector(score))
        if "combined" not in self or "spread" not in self["combined"].members:
            return changed, None
        why = (f"the fitted combined detector ranks the spread by {fitted!r}, not by {score!r}; refit the detectors with "
               f"that score (`oodmon fit-detectors --score {score}`, fit_detectors(..., score={score!r})) or use score "
               f"{fitted!r}")
        return changed.subset([name for name in changed.names if name != "combined"]), why

    def for_masks(self, masks: str | None) -> tuple[DetectorSet, str | None]:
        """The set without what read another policy's samples, and why, if anything was left out.

        ``scaled_spread``, and a ``combined`` that ranks ``spread`` or ``scaled_spread``, were fitted
        on the samples of an MC policy with ``sampled`` or ``fixed`` masks (``fitted_for["masks"]``;
        sets fitted before fixed masks existed hold sampled ones); on the other kind their values
        mean nothing. ``masks`` ``None``: the policy is no MC agent, nothing to compare.
        """
        fitted = self.fitted_for.get("masks", "sampled")
        if masks is None or fitted is None or masks == fitted:
            return self, None
        reading = {"spread", "scaled_spread"}
        dropped = [name for name in self.names if name == "scaled_spread"
                   or (name == "combined" and reading & set(self["combined"].members))]
        if not dropped:
            return self, None
        why = (f"the fitted {' and '.join(dropped)} detector(s) read an MC policy's samples with {fitted} masks, and this "
               f"policy's are {masks}; fit them with its masks (`oodmon fit-detectors --masks {masks}`)")
        return self.subset([name for name in self.names if name not in dropped]), why

    def subset(self, names: Sequence[str]) -> DetectorSet:
        """The detectors ``names`` and whatever they read (``combined``'s members)."""
        wanted = set(names)
        if "combined" in wanted and "combined" in self:
            wanted |= set(self["combined"].members)
        return DetectorSet([self[name] for name in self.names if name in wanted], fitted_for=self.fitted_for)

    def fingerprint(self, name: str) -> str | None:
        """``sha256:...`` of what detector ``name`` learned and of the learned detectors it reads
        (``combined``'s members), or ``None`` for ``spread``, which learns nothing (its score is the
        threshold's ``score``). A threshold records it (:attr:`Threshold.detectors_hash`)."""
        return self.fingerprints().get(self[name].name)  # (an unknown name: said by self[name])

    def fingerprints(self) -> dict[str, str]:
        """:meth:`fingerprint` of every learned detector, by name, each detector's arrays hashed once."""
        own = {d.name: d.fingerprint() for d in self if d.learned}
        prints = dict(own)
        if "combined" in own:
            members = sorted(m for m in self["combined"].members if m in own)
            if members:
                joined = " ".join(own[n] for n in ["combined", *members])
                prints["combined"] = "sha256:" + hashlib.sha256(joined.encode()).hexdigest()
        return prints

    @property
    def needs_estimate(self) -> bool:
        return any(d.needs_estimate for d in self)

    def reset(self) -> None:
        for detector in self:
            detector.reset()

    def score(self, context: StepContext) -> dict[str, float]:
        """Every detector's score at this step, by name, written into ``context.scores`` as it goes
        (a detector sees those computed before it) and returned."""
        scores = context.scores
        if not isinstance(scores, dict):
            raise ConfigError("StepContext.scores must be a dict the detectors can fill")
        for name, detector in self._detectors.items():
            scores[name] = detector.score(context)
        return scores

    def check_fits(self, *, task: str | None, obs_shape: Sequence[int] | None, policy_hash: str | None,
                   aliases: Sequence[str] = ()) -> list[str]:
        """How the policy about to be watched differs from the one the detectors were fitted for
        (``aliases``: other hashes of the same weights that fit as well)."""
        found = []
        mine = self.fitted_for
        if mine.get("task") and task and mine["task"] != task:
            found.append(f"the detectors were fitted for task {mine['task']!r}, not {task!r}")
        if mine.get("obs_shape") is not None and obs_shape is not None and tuple(mine["obs_shape"]) != tuple(obs_shape):
            found.append(f"the detectors were fitted on observations of shape {tuple(mine['obs_shape'])}, "
                         f"not {tuple(obs_shape)}")
        if other_weights(mine.get("policy_hash"), policy_hash, aliases):
            from oodmon.monitor.threshold import model_files, sb3_arguments

            files = model_files(mine.get("models"))
            named = "" if not files else \
                f": on those of {len(files)} model file{'s' if len(files) > 1 else ''}, --sb3 {sb3_arguments(files)}"
            found.append("the detectors were fitted on another policy's episodes (its weights, or a plain policy's "
                         f"name or code, differ){named}")
        return found

    # -- files ---------------------------------------------------------------------------------------
    def save(self, directory: str | Path) -> Path:
        """Write ``detectors.safetensors`` and ``detectors.json`` into ``directory``.

        Both are written beside their names (``.part``) and then moved over them one right after the
        other: a process killed or a disk filled while writing leaves the set that was there whole
        (an ``--overwrite`` refit of a threshold's detectors, say); only a kill between the two
        moves leaves a set whose hash disagrees, which :meth:`load` refuses."""
        from safetensors.numpy import save_file

        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        tensors = {f"{d.name}/{key}": np.ascontiguousarray(value) for d in self for key, value in d.tensors().items()}
        meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "fitted_for": self.fitted_for,
                "detectors": [{"name": d.name, "config": d.config()} for d in self]}
        write_hashed_tensors(directory / "detectors.safetensors", directory / "detectors.json",
                             lambda path: save_file(tensors, path), meta)
        return directory

    @classmethod
    def load(cls, directory: str | Path) -> DetectorSet:
        """Read a set written by :meth:`save`.

        Raises:
            ConfigError: missing, damaged or altered files, or a detector oodmon does not know.
        """
        from safetensors import SafetensorError
        from safetensors.numpy import load as load_tensors

        directory = Path(directory)
        meta_path, tensor_path = directory / "detectors.json", directory / "detectors.safetensors"
        if not directory.is_dir():  # (it said "<it>/detectors.json does not exist" of a threshold's JSON given)
            what = "does not exist" if not directory.exists() else "is a file, not a folder"
            beside = Path(f"{directory}.detectors")
            hint = f"; those a threshold's calibration fitted are beside it: {beside}" if beside.is_dir() else ""
            raise ConfigError(f"{directory} {what}: fitted detectors are a folder with detectors.json and "
                              f"detectors.safetensors (`oodmon fit-detectors` writes them){hint}")
        for path in (meta_path, tensor_path):
            if not path.is_file():
                raise ConfigError(f"{path} {not_a_file(path)}: fitted detectors are a folder with detectors.json and "
                                  "detectors.safetensors (`oodmon fit-detectors` writes them)")
        meta = read_json(meta_path)
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise ConfigError(f"{meta_path} is not a detectors file of oodmon")
        if meta.get("format_version", 0) > FORMAT_VERSION:
            raise ConfigError(f"{meta_path} has format version {meta['format_version']}; this oodmon reads up to "
                              f"{FORMAT_VERSION}: upgrade oodmon")
        data = tensor_path.read_bytes()
        if hashlib.sha256(data).hexdigest() != meta.get("safetensors_sha256"):
            raise ConfigError(f"{tensor_path} does not have the sha256 detectors.json records: damaged or altered")
        try:
            tensors = load_tensors(data)
        except SafetensorError as error:
            raise ConfigError(f"{tensor_path} is damaged ({error})") from None
        detectors = []
        for entry in meta.get("detectors", []):
            name = entry.get("name")
            if name not in DETECTORS:
                raise ConfigError(f"{meta_path} names detector {name!r}; oodmon knows {', '.join(DETECTORS)}")
            prefix = f"{name}/"
            own = {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}
            try:
                detectors.append(DETECTORS[name].from_state(entry.get("config", {}), own))
            except ConfigError:
                raise
            except (TypeError, KeyError, ValueError, AttributeError) as error:  # a setting missing, misnamed or mistyped
                raise ConfigError(f"{meta_path}: the {name} detector's settings are not valid "
                                  f"({type(error).__name__}: {error})") from None
        return cls(detectors, fitted_for=meta.get("fitted_for", {}))
