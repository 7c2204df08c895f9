"""``oodmon bench``: the paper's protocol, run under the monitor and scored by replaying its logs.

For one task, each method and each trial:

1. a model: trial 0 is the shipped agent (if the zoo has one); other trials are trained with their
   seed (cached, resumable);
2. the variants where it fails (the paper's step 3), from ``evaluate_variants`` on a few episodes;
3. a threshold calibrated on held-out ID episodes (so that the logs carry alarms too);
4. cells: ID episodes, and episodes of every failing variant (shifted from step 0, as in the
   paper), each cell a monitored run writing one MCAP log;
5. the scores, by replaying those logs: per-step AUROC per (method, trial, variant).

With ``protocol="monitor"`` (the monitor's own benchmark) step 4 changes: each shifted episode
starts in the ID world and shifts at a random onset (uniform in the task's :data:`ONSETS`, or in
``onsets``, drawn per episode from its seed), and there are at least as many ID episodes as a
false-alarm rate needs (200 by default in the CLI). Replay then gives, per variant, the share of
episodes alarmed before they failed and the delays from the onset
(``oodmon.replay.compute_monitor_metrics``), and the false-alarm rate with its interval.
Thresholds, fitted detectors and failing variants are shared with the paper's protocol; the logs
live apart (``.../monitor/``, ``.../monitor-onsets<low>-<high>/`` for other onsets). Your own SB3
models in an env oodmon has no variants of (``sb3``, ``env_id`` and ``task`` its id) are benched
this way only, on shifts of their env's attributes (:mod:`oodmon.envs.shift`), every one monitored
(no failure is told for such an env).

The report puts, per variant, our AUROC mean and std over trials beside the paper's, and the
best AUROC per method beside the paper's best. A cell whose log is complete is not run again,
so an interrupted bench resumes; cells run in ``workers`` processes, or as Ray tasks on a Ray
cluster (``executor="ray"``, ``address``; Ray is the optional extra ``oodmon[ray]``).

A result is data (``BenchResult.to_json(config)``: per trial AUROC, AUPR and FPR at 95% TPR, the
settings): ``oodmon bench --results FILE`` writes it, and ``--baseline FILE`` checks a later run
against it (:mod:`oodmon.bench.baseline`). Trial models train in ``workers`` processes at once.

Your own stable-baselines3 models (``sb3=(paths...)``, ``env_id``) are benched as the one method
``sb3`` with one trial: nothing is trained, and the paper has no figures for them; so is a policy
of any kind (``policy="MODULE:NAME"``, ``env_id``; :mod:`oodmon.agents.plain`), as the method
``plain``, its cache kept while its name, its module's file and its weights (if it has some) are unchanged.
"""

from __future__ import annotations

from oodmon.bench.baseline import BASELINE_TOLERANCE, bench_falls, bench_metrics, check_same_settings, load_bench_result
from oodmon.bench.cache import PlainPolicy, Sb3Models
from oodmon.bench.cells import episode_onset
from oodmon.bench.config import ONSETS, PAPER_METHOD, PROTOCOLS, BenchConfig, BenchResult, Row, paper_label
from oodmon.bench.report import (alarms_per_variant, best_per_method, paper_only_variants, print_monitor_report,
                                 print_paper_report, unfailed_variants)
from oodmon.bench.run import run_bench

__all__ = ["BASELINE_TOLERANCE", "ONSETS", "PAPER_METHOD", "PROTOCOLS", "BenchConfig", "BenchResult", "PlainPolicy", "Row",
           "Sb3Models", "alarms_per_variant", "bench_falls", "bench_metrics", "best_per_method", "check_same_settings",
           "episode_onset", "load_bench_result", "paper_label", "paper_only_variants", "print_monitor_report",
           "print_paper_report", "run_bench", "unfailed_variants"]
