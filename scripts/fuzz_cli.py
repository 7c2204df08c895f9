"""Random command lines of odd values: does any oodmon command answer with a traceback?

Run (under a minute for 500; one core):
    .venv/bin/python scripts/fuzz_cli.py --runs 500 [--seed 1]

Each run picks a command (every one but ``train``, ``bench`` and ``demo``, which start long work),
fills its positional arguments and one to four of its flags with values drawn from a list of odd
ones (0, -1, nan, inf, empty, 300 characters, a folder, a file that is not what is asked, /proc,
/dev/zero, a huge number...) or from the flag's choices, often beside ``--task cartpole --method M``, and runs
it in this process from an empty temporary folder. The command's answer is read as a person would
meet it: an exit code (0, or 2 with one line) is fine; an exception that escapes ``main``, or
that ``main`` catches as one it cannot explain (exit code 3, its traceback on stderr), is a
traceback, printed with its command line; this script's exit code is then 1. A run still working after
``--seconds`` (real work began: the values were good) is stopped and counted apart.

On 2026-11-27, 1,000 runs (500 of each of seeds 0 and 1, 38 s each): 995 answered, 5 stopped while
working, no traceback. On 2026-11-29, with shifts of a user's env among the odd values, seeds 0
and 1 again: 496 and 499 answered, the rest stopped while working, no traceback. Seed 7 then found
one: `run ... --spawn` where no Rerun viewer was on PATH (fixed: a warning, the run goes on); after
the fix seeds 8-11, 500 each: 1,997 answered, 3 stopped while working, no traceback. On
2026-11-30, once ``main`` caught the errors it cannot explain (exit code 3), seed 61: 496
answered, 4 stopped while working, no traceback (a planted ``ValueError`` in replay's metrics
was reported with its traceback, as before). Later that day, with sensor faults of discrete
observations among the odd values (Taxi's, FrozenLake's), seeds 66 and 67: 497 and 498 answered,
the rest stopped while working, no traceback; with the tasks' sensor faults too, seeds 68 and 69:
500 and 497 answered, the rest stopped while working, no traceback. With the stillness detector
among ``--detector``'s choices, seeds 70 and 71: 499 and 498 answered, the rest stopped while
working, no traceback. On 2026-12-01, with ``--workers`` of calibrate, validate, evaluate and
fit-detectors and validate's refusal of episodes a threshold was made from, seed 79 (300 runs):
300 answered, no traceback; seed 81 (after the workers' pipes of their own) and seed 82 (after a
worker's death said in one line), 300 runs each: 299 answered each, 1 stopped while working, no
traceback. On 2026-12-05, seed 171 (400 runs) found one: `calibrate --sb3 <300 characters>`,
whose file-name test raised the system's "File name too long" before ``main``'s handling (fixed:
the name is said as missing, in one line); after the fix the same seed: 398 answered, 2 stopped
while working, no traceback. Then `validate /dev/zero` was found by hand to read the file whole
(24 GB, until the system killed it; fixed: the JSON reader stops at 256 MB); /dev/zero is now
among the odd values and the script runs under an 8 GB address-space limit, so such a read is a
MemoryError here, a traceback. Seeds 174-177, 500 each: 1,990 answered, 10 stopped while working,
no traceback. Seeds 178 and 179 (400 each) then found `--sb3 ''` (a ValueError of pathlib's, since
the name has none to add .zip to; fixed: "." is said to be a folder); after the fix: 797 answered,
3 stopped while working, no traceback. Later that day seed 180 (400 runs: 398 answered, 2 stopped
while working, no traceback) left /dev/zero a regular file holding a threshold: run as root,
``calibrate --out /dev/zero`` moved its file over the device (found when a test read /dev/zero).
Fixed: a name that is not a regular file is refused as an output, and a writer will not move a
file over one; the script now checks /dev/null and /dev/zero after every run and stops at once,
naming the command, if either is no longer a device. Then seeds 182 and 183 (500 each): 497 and 498
answered, the rest stopped while working, no traceback; with ``--max-steps`` of calibrate,
validate and run, seed 184 (500): 496 answered, 4 stopped while working, no traceback. The
session after, seeds 185 and 186 (500 each): 498 and 497 answered, the rest stopped while working,
no traceback; after validate's clustered intervals and the counts kept on Ctrl-C, seed 187 (500):
500 answered, no traceback.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import os
import random
import resource
import signal
import sys
import tempfile
import traceback
import warnings
from collections.abc import Iterator

from oodmon.jsonfile import special_file

ODD = ["0", "-1", "1", "2", "1e9", "nan", "inf", "-inf", "", " ", "0.5", "abc", "adir", "file.txt", "/proc/x",
       "cartpole", "pendulum", "pong", "ensemble", "cartpole:length=2.0", "x" * 300, "1,2", "-0", "3.7",
       "99999999999999999999", "/dev/null", "/dev/zero", "Acrobot-v1:LINK_MASS_2=3.0", "MountainCar-v0:gravity=nan",
       "Acrobot-v1:np_random=1", "Taxi-v4:obs.noise=1.5", "Taxi-v4:obs.scale=2", "FrozenLake-v1:obs.bias=0.5",
       "Taxi-v4:obs.stuck=1", "cartpole:obs.stuck[3]=1", "cartpole:obs.bias[9]=1", "pong:motion_blur:radius=5,obs.stuck=1"]
LONG = ("train", "bench", "demo")
#: The devices among the odd values, checked after every run (their minor numbers, to restore one): as root,
#: `calibrate --out /dev/zero` moved a threshold over /dev/zero until 2026-12-05, unseen until a test read it.
DEVICES = {"/dev/null": 3, "/dev/zero": 5}
MEMORY_LIMIT = 8 * 2**30  # bytes of address space (a command here takes under 2 GB)


class StillWorking(BaseException):
    """Raised by :func:`time_limit` in a block that outlived its seconds."""


@contextlib.contextmanager
def time_limit(seconds: int) -> Iterator[None]:
    """Raise :class:`StillWorking` in the block once ``seconds`` have passed (SIGALRM: the main
    thread only); the alarm and its handler are put back as the block ends, however it ends."""
    def stop(signum, frame):
        raise StillWorking

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def limit_memory() -> None:
    """At most :data:`MEMORY_LIMIT` of address space for this process: a command that reads a file
    that never ends (/dev/zero) whole fails here with a MemoryError, a traceback, before it takes
    the machine's memory (it took 24 GB until 2026-12-05)."""
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def command_lines(runs: int, seed: int) -> list[list[str]]:
    """``runs`` random command lines (see the module docstring)."""
    from oodmon.cli import _parser

    commands = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    rng = random.Random(seed)
    lines = []
    for _ in range(runs):
        name = rng.choice([c for c in commands if c not in LONG])
        parser = commands[name]
        argv = [name]
        for action in (a for a in parser._actions if not a.option_strings and a.dest != "help"):
            argv += [rng.choice(ODD)] if action.nargs in (None, 1) else rng.sample(ODD, rng.randint(1, 2))
        argv += rng.choice([["--task", "cartpole", "--method", rng.choice(["ensemble", "dropout", "dropconnect"])], []])
        flags = [a for a in parser._actions if a.option_strings and a.dest != "help"]
        for action in rng.sample(flags, min(len(flags), rng.randint(1, 4))):
            flag = rng.choice(action.option_strings)
            if action.nargs == 0:
                argv.append(flag)
            elif action.choices and rng.random() < 0.5:
                argv += [flag, str(rng.choice(list(action.choices)))]
            else:
                argv += [flag, rng.choice(ODD)]
        lines.append(argv)
    return lines


def run(argv: list[str], seconds: int) -> str | None:
    """"stopped" for a run that outlived ``seconds``, the traceback of one that escaped ``main`` (or
    that ``main`` printed, exit code 3), or None."""
    from oodmon.cli import main

    err = io.StringIO()
    try:
        with time_limit(seconds), contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err), \
                warnings.catch_warnings():
            warnings.simplefilter("ignore")
            code = main(argv)
        # 3: main caught an exception it cannot explain and printed its traceback (since 2026-11-30)
        return "\n".join(err.getvalue().splitlines()[-8:]) if code == 3 else None
    except StillWorking:
        return "stopped"
    except BaseException:  # noqa: BLE001  (what this script looks for)
        return traceback.format_exc(limit=-3)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seconds", type=int, default=8, help="stop a run still working after this long (default 8)")
    args = parser.parse_args()
    limit_memory()
    counts: collections.Counter[str] = collections.Counter()
    tracebacks = []
    with tempfile.TemporaryDirectory() as folder:
        os.chdir(folder)
        with open("file.txt", "w") as f:
            f.write("hello")
        os.mkdir("adir")
        for argv in command_lines(args.runs, args.seed):
            outcome = run(argv, args.seconds)
            counts["answered" if outcome is None else "stopped (working)" if outcome == "stopped" else "traceback"] += 1
            if outcome not in (None, "stopped"):
                tracebacks.append(f"oodmon {' '.join(argv)}\n{outcome}")
            harmed = [device for device in DEVICES if special_file(device) != "a character device"]
            if harmed:  # the worst finding there is: stop at once, say which command did it
                print(f"oodmon {' '.join(argv)}\nreplaced or removed {', '.join(harmed)}: restore it (as root: "
                      f"rm -f {harmed[0]}; mknod -m 666 {harmed[0]} c 1 {DEVICES[harmed[0]]}) before anything else")
                return 1
    for text in tracebacks[:20]:
        print(text)
    print(", ".join(f"{n} {what}" for what, n in counts.most_common()) + f" of {args.runs} command lines")
    return 1 if tracebacks else 0


if __name__ == "__main__":
    sys.exit(main())
