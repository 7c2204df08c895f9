"""What a bench runs (:class:`BenchConfig`), what it returns (:class:`BenchResult`), and the
paper's names for our methods and variants."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from oodmon.envs.grid import Variant, parse_variant, select_variants
from oodmon.envs.shift import EnvShift, OtherEnv, own_variant, shifts_an_env
from oodmon.errors import ConfigError, unknown
from oodmon.names import PLAIN_METHOD, TASKS
from oodmon.paper import paper_auc_per_trial
from oodmon.versions import machine

if TYPE_CHECKING:
    from oodmon.agents.recipes import Recipe
    from oodmon.replay import MonitorMetrics

__all__ = ["ONSETS", "PAPER_METHOD", "PROTOCOLS", "BenchConfig", "BenchResult", "Row", "paper_label"]

#: The bench's protocols: the paper's (shifted from step 0, per-step AUROC) and the monitor's own.
PROTOCOLS = ("paper", "monitor")
#: Per task, the range [low, high) a shifted episode's onset is drawn from under the monitor's
#: protocol: after the ID start-up (Pendulum's agents have swung the pole up by step 100 of 200),
#: early enough that the rest of the episode can show the failure. Pong: decisions into the game.
ONSETS = {"cartpole": (20, 200), "pendulum": (100, 150), "pong": (100, 1000)}

#: Our method names as the paper's tables name them.
PAPER_METHOD = {"dropout": "mc_dropout", "dropconnect": "mc_dropconnect", "ensemble": "ensemble"}


def check_own_env_bench(env: str, protocol: str, onsets, variants, obs_noise: float, said: str = "") -> None:
    """The bench of an env oodmon has no variants of (your own ``env``) needs the monitor's
    protocol, the steps its shifts may begin at and shifts of your own, and no ``obs_noise``.

    Raises:
        ConfigError: naming each of them that is missing (``said``: how the env was given, ``--env ``).
    """
    missing = [say for wrong, say in (
        (protocol != "monitor", "the monitor's protocol (--protocol monitor)"),
        (onsets is None, "the steps its shifts may begin at (e.g. --onsets 20,100)"),
        (variants == "paper", f"shifts of your own (--variants {env}:NAME=VALUE, numeric attributes of its env, or "
                              f"sensor faults such as {env}:obs.noise=0.01)"),
        (bool(obs_noise), "no --obs-noise (noise in every episode is an option of oodmon's envs: a shift's noise "
                          "is the sensor fault obs.noise=STD)")) if wrong]
    if missing:
        raise ConfigError(f"{said}{env} is an env oodmon has no variants of: bench it with " + "; ".join(missing))


@dataclass(frozen=True)
class BenchConfig:
    """What to run. ``variants`` is ``"paper"`` or a list of spec strings."""

    task: str
    methods: tuple[str, ...] = ("dropout", "dropconnect", "ensemble")
    trials: int = 5
    variants: str | tuple[str, ...] = "paper"
    episodes: int = 5
    id_episodes: int = 10
    eval_episodes: int = 3
    calibration_episodes: int = 45  # the fewest that bound the rate at far 0.05 with confidence 0.9
    far: float = 0.05
    confidence: float | None = 0.9  # see oodmon.monitor.threshold; None: the rate bounded on average only
    score: str = "chosen_std"  # the paper's; pre_squash_std detects far better on Pendulum
    window: int = 1  # the alarm rule's averaging window (alarms only; the AUROCs score single steps)
    out: str = "runs/bench"
    workers: int = 0  # 0: all cores
    train_steps: int | None = None  # override the recipes' steps for trials > 0 (smoke tests)
    executor: str = "local"  # "local" (worker processes) or "ray" (tasks on a Ray cluster)
    address: str | None = None  # the Ray cluster; None starts a local one
    bind: str = "127.0.0.1"  # the address a local Ray cluster listens on: loopback unless opened on purpose
    detectors: tuple[str, ...] = ("spread",)  # whose per-step AUROC is reported; learned ones are fitted per trial
    alarm_detector: str = "spread"  # the detector the monitor's alarm reads
    obs_noise: float = 0.0  # sensor noise in every monitored env (fit, calibration, cells), see envs
    fit_episodes: int = 0  # ID episodes the learned detectors are fitted on (0: the task's default)
    dynamics_updates: int | None = None  # the dynamics fit's cap of Adam updates (dynamics.MAX_UPDATES; None: none)
    protocol: str = "paper"  # or "monitor": random onsets, alarms before failure (see the module docstring)
    rule: str = "consecutive"  # the alarm rule: consecutive, cusum or martingale (oodmon.monitor.sequential)
    consecutive: int | None = None  # m of the consecutive rule (None: 3 for spread, 1 for a learned detector)
    all_variants: bool = False  # monitor every variant, not only those the agent fails on (Pong: no failure to wait for)
    sb3: tuple[str, ...] = ()  # your own SB3 model files instead of oodmon agents (the method "sb3", one trial)
    env_id: str | None = None  # the gymnasium env id the sb3 models act in
    mean: bool = False  # deploy the sb3 ensemble's mean decision, not the first model's
    vec_normalize: str | None = None  # the sb3 models' VecNormalize statistics file, or "none" (see load_sb3)
    frame_stack: int | None = None  # the n_stack of the VecFrameStack the sb3 models were trained inside
    imports: tuple[str, ...] = ()  # the user's modules imported before the sb3 files are read (see load_sb3)
    unsafe_load_pickles: bool = False  # load the sb3 files as SB3 does, running code they hold (see load_sb3)
    policy: str | None = None  # your own policy of any kind, MODULE:NAME, instead (the method "plain", one trial)
    samples: int | None = None  # MC samples per decision of Dropout and DropConnect agents (None: each one's recipe)
    members: int | None = None  # members of each ensemble trial (None: the recipe's; others train trial 0 too)
    masks: str | None = None  # MC masks of Dropout and DropConnect agents: sampled or fixed (None: each model's)
    net_arch: tuple[int, ...] | None = None  # hidden widths of every trial (None: the recipe's; others train trial 0 too)
    onsets: tuple[int, int] | None = None  # [low, high) of the monitor protocol's onsets (None: the task's, ONSETS)
    failure: str | None = None  # what fails in your own env (oodmon.replay.failures.FAILURES; None: not told)
    warmup: int = 0  # the alarm looks at no finite score of an episode's first N steps (oodmon.monitor.alarms)
    fit_explore: float = 0.0  # the share of the fitting steps that take a random action (fit_detectors' explore)

    def __post_init__(self) -> None:
        from oodmon.monitor.threshold import DETECTOR_NAMES

        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"protocol={self.protocol!r} is not allowed; use {' or '.join(PROTOCOLS)}")
        from oodmon.monitor.sequential import RULES

        if self.rule not in RULES:
            raise ConfigError(f"rule={self.rule!r} is not allowed; choose one of {', '.join(RULES)}")

        from oodmon.monitor.alarms import check_warmup, check_window

        check_window(self.window)  # here, not in run_bench: before the CLI makes --out
        check_warmup(self.warmup, self.rule)
        for name in (*self.detectors, self.alarm_detector):
            if name not in DETECTOR_NAMES:
                raise ConfigError(unknown("detector", name, DETECTOR_NAMES))
        if self.alarm_detector not in self.detectors:
            raise ConfigError(f"the alarm reads the {self.alarm_detector} detector: add it to the detectors")
        from oodmon.monitor.detectors.dynamics import MAX_UPDATES, check_max_updates
        from oodmon.monitor.detectors.fitting import check_explore

        check_max_updates(self.dynamics_updates, "dynamics_updates")
        check_explore(self.fit_explore, "fit_explore")
        fitting = [name for name, given in (("fit_episodes", self.fit_episodes),
                                            ("dynamics_updates", self.dynamics_updates != MAX_UPDATES),
                                            ("fit_explore", self.fit_explore)) if given]
        if fitting and not self.learned:  # (the fit_episodes were ignored so before 2026-12-02)
            raise ConfigError(f"{' and '.join(fitting)} shape{'' if len(fitting) > 1 else 's'} the fit of the learned "
                              f"detectors, and this bench fits none (detectors: {', '.join(self.detectors)}): add "
                              "dynamics or combined to the detectors")
        if self.onsets is not None:
            if self.protocol != "monitor" or len(self.onsets) != 2 or not 0 <= self.onsets[0] < self.onsets[1]:
                raise ConfigError(f"onsets={self.onsets}: the steps [low, high) the monitor's protocol draws each shifted "
                                  "episode's onset from, whole numbers 0 <= low < high (protocol monitor only)")
            object.__setattr__(self, "onsets", tuple(int(step) for step in self.onsets))  # frozen; JSON gives a list
        if self.failure is not None:
            from oodmon.replay.failures import check_failure

            check_failure(self.failure)
            if not self.own_env:
                raise ConfigError(f"failure={self.failure!r} says what fails in your own env; oodmon tells {self.task}'s "
                                  "failures itself")
        if self.own_env:
            if not self.users_own:
                raise ConfigError(f"unknown task {self.task!r}; choose one of {', '.join(TASKS)}, or bench your own "
                                  "SB3 models (sb3) or policy (policy) in their own env (env_id)")
            check_own_env_bench(self.task, self.protocol, self.onsets, self.variants, self.obs_noise)
        if self.sb3 and self.policy:
            raise ConfigError("sb3 models or a policy: give one of them")
        if self.users_own:
            kind, method = ("sb3 models", "sb3") if self.sb3 else ("a policy", PLAIN_METHOD)
            if self.env_id is None:
                raise ConfigError(f"{kind}: give env_id, the gymnasium env id it acts in (e.g. CartPole-v1)")
            if self.methods != (method,) or self.trials != 1:
                raise ConfigError(f"{kind}: benched as one method ({method!r}) and one trial, nothing is trained")
        if not self.sb3 and (self.vec_normalize is not None or self.frame_stack is not None or self.unsafe_load_pickles
                             or self.imports):
            raise ConfigError("vec_normalize, frame_stack, imports and unsafe_load_pickles are how sb3 models are read "
                              "and see the env: give them with sb3 models only")
        if not self.users_own:  # (your own policy's actions are known when its env is made)
            from oodmon.agents.recipes import recipe_for
            from oodmon.monitor.scores import check_score

            for method in self.methods:  # an unknown score or one not of the task's actions, before hours of training
                check_score(self.score, recipe_for(self.task, method).algorithm)
        if not self.users_own and "spread" not in self.detectors:
            raise ConfigError("the bench's agents all have samples: keep spread among the detectors")
        from oodmon.monitor.threshold import conformal_rank

        conformal_rank(self.calibration_episodes, self.far, self.confidence)  # enough episodes, before any work
        if self.samples is not None and (self.samples < 2 or self.users_own):
            raise ConfigError(f"samples={self.samples}: MC samples per decision of oodmon's Dropout and DropConnect "
                              "agents, 2 or more (not for --sb3 models)")
        from oodmon.names import MASKS

        if self.masks is not None and (self.masks not in MASKS or (self.masks != "sampled" and len(self.sb3) > 1)
                                       or self.policy or self.methods == ("ensemble",)):  # (an ensemble has none)
            raise ConfigError(f"masks={self.masks!r}: the MC masks of Dropout and DropConnect agents (oodmon's, or one "
                              f"--sb3 model with dropout), {' or '.join(MASKS)}")
        if self.members is not None and (self.members < 2 or self.users_own or "ensemble" not in self.methods):
            raise ConfigError(f"members={self.members}: the size of oodmon's ensembles, 2 or more, for a bench of the "
                              "ensemble method (not for --sb3 models)")
        if self.net_arch is not None:
            from oodmon.agents.recipes import recipe_for

            if self.users_own or not self.net_arch or min(self.net_arch) < 1 or any(
                    recipe_for(self.task, method).cnn for method in self.methods):
                raise ConfigError(f"net_arch={self.net_arch}: the hidden widths of oodmon's CartPole and Pendulum "
                                  "agents' networks, whole numbers >= 1 (not for --sb3 models, nor Pong's CNN agents)")
            object.__setattr__(self, "net_arch", tuple(int(width) for width in self.net_arch))  # frozen; JSON gives a list

    def recipe(self, method: str) -> Recipe:
        """The recipe the bench trains ``method``'s trials by: the shipped one, its ensembles of
        ``members`` members where given (member k is trained with the same seed at any size), cut to
        ``train_steps`` where given."""
        from oodmon.agents.recipes import recipe_for

        recipe = recipe_for(self.task, method)
        if method == "ensemble" and self.members is not None:
            recipe = replace(recipe, n_members=self.members)
        if self.net_arch is not None:
            recipe = replace(recipe, net_arch=list(self.net_arch))
        return recipe if self.train_steps is None else recipe.shortened(self.train_steps)

    def _other_members(self, method: str) -> bool:
        from oodmon.agents.recipes import recipe_for

        return method == "ensemble" and self.members not in (None, recipe_for(self.task, method).n_members)

    def _other_widths(self, method: str) -> bool:
        from oodmon.agents.recipes import recipe_for

        return self.net_arch is not None and list(self.net_arch) != list(recipe_for(self.task, method).net_arch)

    def resized(self, method: str) -> bool:
        """Whether ``method``'s trials are ensembles of another size, or networks of other hidden
        widths, than the shipped recipe's: then no trial is the zoo's agent, and their models and
        logs have folders of their own."""
        return self._other_members(method) or self._other_widths(method)

    def model_name(self, method: str) -> str:
        """``method``'s name in the bench's folders: ``ensemble-members20`` for resized ensembles,
        ``dropconnect-net64x64`` for networks of hidden widths [64, 64]."""
        name = f"{method}-members{self.members}" if self._other_members(method) else method
        return f"{name}-net{'x'.join(map(str, self.net_arch))}" if self._other_widths(method) else name

    @property
    def m(self) -> int:
        """m of the consecutive rule the thresholds are calibrated for."""
        from oodmon.monitor.alarms import default_consecutive

        return default_consecutive(self.alarm_detector) if self.consecutive is None else self.consecutive

    @property
    def learned(self) -> tuple[str, ...]:
        """The detectors to fit per trial (``combined`` brings its members)."""
        names = [d for d in self.detectors if d != "spread"]
        if "combined" in names and self.task == "pong":
            names = [d for d in names if d != "dynamics"]
        return tuple(names)

    def cache_key(self) -> str:
        """What the cached thresholds and logs of a (method, trial) depend on beyond the weights:
        score, alarm rule, target rate and confidence, calibration episodes, detectors (the version
        of their fitting and the episodes they are fitted on), sensor noise, MC samples per decision and masks."""
        parts = [self.score, f"far{self.far:g}", f"n{self.calibration_episodes}",
                 "marginal" if self.confidence is None else f"conf{self.confidence:g}"]
        if self.window != 1:
            parts.append(f"w{self.window}")
        if self.m != 3:
            parts.append(f"m{self.m}")
        if self.rule != "consecutive":
            parts.append(self.rule)
        if self.warmup:
            parts.append(f"warm{self.warmup}")
        if self.learned:
            from oodmon.monitor.detectors.dynamics import JUMP_VALUES, MAX_UPDATES
            from oodmon.monitor.detectors.fitting import FIT_VERSION, brings_default_set, default_fit_steps

            # the fitting's version: what an older oodmon fitted and scored is not reused; your own
            # env's default fitting plays on until its steps (oodmon's tasks: none, key unchanged);
            # your own env's readings may jump, which the dynamics model takes as inputs since
            # 2026-11-29 (JUMP_VALUES): an own env's older fits are not reused (every reading of
            # oodmon's tasks is continuous, their fits the same: key unchanged); nor are those from
            # before drift joined your own env's default set (the same day); nor, where combined
            # brings the default set and that may hold pictures (Pong, your own env), those from
            # before stillness joined it (2026-11-30); nor Pong's from before its fits took 90 whole
            # games instead of the first 1,000 steps of 6 and its default set gained vanishing
            # (2026-12-01)
            steps = 0 if self.fit_episodes else default_fit_steps(self.task)
            defaults = brings_default_set(self.detectors)
            parts.append("+".join(self.detectors) + f"-alarm-{self.alarm_detector}-fit{FIT_VERSION}"
                         + (f"-on{self.fit_episodes}" if self.fit_episodes else "")
                         + (f"-steps{steps}" if steps else "") + (f"-jump{JUMP_VALUES}-drift" if self.own_env else "")
                         + ("-still" if defaults and (self.own_env or self.task == "pong") else "")
                         + ("-vanish" if self.task == "pong" else "")
                         + ("" if self.dynamics_updates == MAX_UPDATES else f"-updates{self.dynamics_updates}")
                         + (f"-explore{self.fit_explore:g}" if self.fit_explore else ""))
        if self.obs_noise:
            parts.append(f"noise{self.obs_noise:g}")
        if self.samples is not None:
            parts.append(f"k{self.samples}")
        if self.masks is not None:
            parts.append(f"{self.masks}-masks")
        return "-".join(parts)

    def what_made_the_numbers(self) -> dict:
        """The settings a result depends on (not where it ran: out, workers, executor)."""
        from oodmon.monitor.detectors.dynamics import MAX_UPDATES

        # (numpy's numbers a Python caller gave as plain ones: the results file is JSON)
        return {k: list(v) if isinstance(v, tuple) else v.item() if isinstance(v, np.generic) else v
                for k, v in asdict(self).items()
                if k not in ("out", "workers", "executor", "address", "bind", "imports", "unsafe_load_pickles")
                and not (k in ("warmup", "policy", "fit_explore") and not v)  # none: as results from before it say
                and not (k == "dynamics_updates" and v == MAX_UPDATES)}  # the default: as results from before it say

    @property
    def users_own(self) -> bool:
        """Whether the bench plays your own SB3 models or policy (one trial, nothing trained) instead of oodmon's agents."""
        return bool(self.sb3 or self.policy)

    @property
    def own_env(self) -> bool:
        """Whether the task is your own env (a gymnasium id oodmon has no variants of), whose
        variants are shifts of its attributes (:mod:`oodmon.envs.shift`)."""
        return self.task not in TASKS

    def onset_range(self) -> tuple[int, int]:
        """The [low, high) the monitor's protocol draws each shifted episode's onset from."""
        return self.onsets or ONSETS[self.task]

    def variant_list(self) -> list[Variant | EnvShift | OtherEnv]:
        """The shifted variants the bench plays: oodmon's variants of its task (``"paper"``: the
        paper's grid); in your own env, shifts of its attributes; and where your own policy acts in
        gymnasium's env of one of oodmon's tasks (``env_id`` ``CartPole-v1``), shifts of that env's
        other attributes too (``CartPole-v1:theta_threshold_radians=0.1``), as ``oodmon run`` takes
        them (:func:`~oodmon.envs.own_variant`, which refuses the task's physics there: those are
        ``cartpole:...``); and another registered env's id (:class:`~oodmon.envs.shift.OtherEnv`,
        shifted from each reset: the onsets are none of its).

        Raises:
            SpecError, UnknownParameterError: a spec that does not parse.
            ConfigError: a variant of another task or env, or the ID env.
        """
        if self.own_env:
            shifts = [own_variant(spec.strip(), self.task) for spec in self.variants]
        elif self.users_own and self.variants != "paper":
            shifts = [own_variant(spec.strip(), self.env_id) if shifts_an_env(spec)
                      else select_variants(self.task, [spec], shifted_only=True)[0] for spec in self.variants]
        else:
            return select_variants(self.task, self.variants, shifted_only=True)
        for shift in shifts:
            if shift.is_id:
                raise ConfigError(f"{shift.spec} in the variants: the bench runs its ID episodes itself; give "
                                  "the shifts only")
        return shifts

    def check_env_shifts(self) -> None:
        """Make the env of each shift of an env's attributes once: an attribute it lacks (a misspelt
        name), said before the fitting and calibration, not when its cell comes (minutes later); and
        of another env (:class:`~oodmon.envs.shift.OtherEnv`): one gymnasium makes, of the spaces of
        the env the policy acts in.

        Raises:
            UnknownParameterError, InvalidParameterError, ConfigError: as :meth:`EnvShift.make`; an
                env of other spaces.
        """
        from oodmon.envs.checks import space_mismatch
        from oodmon.envs.registration import make_env

        for variant in self.variant_list():
            if isinstance(variant, OtherEnv):
                own, other = make_env(self.env_id or self.task), variant.make()
                what = space_mismatch(own, other)
                own.close(), other.close()
                if what is not None:
                    raise ConfigError(f"--variants {variant.spec}: its {what} is {getattr(other, what)}, and "
                                      f"{self.env_id or self.task}'s, which the policy acts in, {getattr(own, what)}")
            elif isinstance(variant, EnvShift):
                variant.make().close()


@dataclass(frozen=True)
class Row:
    """One (method, variant, detector): our per-step AUROC per trial beside the paper's, and the
    same trials' AUPR and FPR at 95% TPR (the paper's other two metrics)."""

    method: str
    variant: str
    aurocs: dict[int, float]
    paper: list[float] | None
    detector: str = "spread"
    auprs: dict[int, float] = field(default_factory=dict)
    fprs: dict[int, float] = field(default_factory=dict)

    @property
    def mean(self) -> float:
        return float(np.mean(list(self.aurocs.values())))

    @property
    def std(self) -> float:
        return float(np.std(list(self.aurocs.values())))


@dataclass(frozen=True)
class BenchResult:
    rows: list[Row]
    failing: dict[str, dict[int, list[str]]]
    detection: dict[str, dict[str, float | None]]
    #: The monitor's protocol only: the alarm's figures per (method, variant), trials pooled.
    alarms: list[MonitorMetrics] = field(default_factory=list)
    #: Per method and trial, the model's ID return as its training measured it (``id_return_mean``,
    #: 20 episodes; ``None`` for SB3 files, which carry none): whether each trial solves the task.
    id_returns: dict[str, dict[int, float | None]] = field(default_factory=dict)
    #: Per method and trial, the sha256 of the weights that played (the model's, or the SB3 files'),
    #: and the fingerprints of the detectors the bench fitted for them, by detector
    #: (``DetectorSet.fingerprints``): ``bench --baseline`` says where a baseline's numbers are of
    #: other weights or of other fits.
    weights: dict[str, dict[int, str]] = field(default_factory=dict)
    fitted: dict[str, dict[int, dict[str, str]]] = field(default_factory=dict)

    def to_json(self, config: BenchConfig | None = None, command: str | None = None) -> dict:
        """The result as data (``bench --json``): per row the per-trial AUROC, AUPR and FPR at 95%
        TPR and their means; with ``config``, what made them (``bench --baseline`` checks it)."""
        data: dict = {}
        if command is not None:
            data["command"] = command
        if config is not None:
            data["config"] = config.what_made_the_numbers()
        data |= {
            "rows": [asdict(r) | {"mean": r.mean, "std": r.std, "aupr_mean": _mean(r.auprs), "fpr95_mean": _mean(r.fprs)}
                     for r in self.rows],
            "failing": self.failing,
            "monitor": self.detection,
            "id_returns": self.id_returns,
            "weights": self.weights,
            "fitted": self.fitted,
            "machine": machine(),
        }
        if self.alarms:
            from oodmon.replay import monitor_summary

            data["alarms"] = [m.to_dict() for m in [*self.alarms, *monitor_summary(self.alarms)]]
        return data


def _mean(values: dict[int, float | None]) -> float | None:
    present = [v for v in values.values() if v is not None]
    return float(np.mean(present)) if present else None


def paper_label(task: str, method: str, spec: str) -> str | None:
    """The label of ``spec`` in the paper's per-trial table for ``method``, if it has one.

    Example:
        >>> paper_label("cartpole", "ensemble", "cartpole:length=2.0")
        'length=2.0'
        >>> paper_label("cartpole", "dropconnect", "cartpole:masscart=9.0")
        'masscart=9.0 (text says pole mass 9)'
        >>> paper_label("cartpole", "dropout", "cartpole:masscart=3.0")
        'masspole_or_masscart=3.0 (paper label: mass of the cart 3; text says pole)'
    """
    if method not in PAPER_METHOD:  # your own SB3 models: the paper has no figures for them
        return None
    table = paper_auc_per_trial().get(task, {}).get(PAPER_METHOD[method], {})
    variant = parse_variant(spec)
    if variant.faults:  # the paper faulted no sensor
        return None
    if variant.task == "pong":
        key = f"{variant.corruption}@{variant.severity}"
    else:
        name, value = variant.params[0]
        key = f"{name}={value!r}"
    keys = [key]
    if variant.task != "pong" and variant.params[0][0] in ("masscart", "masspole"):
        keys.append(f"masspole_or_masscart={variant.params[0][1]!r}")  # a label the paper's text and table disagree on
    for label in table:
        if any(label == k or label.startswith(k + " ") for k in keys):
            return label
    return None
