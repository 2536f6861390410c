"""A step counter for long loops: a tqdm bar whose rate and ETA leave out compilation,
and which ends at 100% with the stop reason when the loop stops early."""

from __future__ import annotations

import sys

# While running, the time left is an upper bound: a stopping rule may end the run early.
_RUNNING = "{desc}{percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}, at most {remaining} left, {rate_fmt}{postfix}]"
_DONE = "{desc}{percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}, {rate_fmt}{postfix}]"


class ProgressBar:
    """A tqdm progress bar over at most `total` steps.

    The first step of a jit-compiled loop includes the compilation, often far slower than
    every later step; counting it would predict minutes for a run of seconds. So the bar
    says "compiling" until the first step is done and starts its clock (rate, elapsed
    time, time left) after it. The time left is shown as an upper bound ("at most"), since
    stopping rules may end the run before `total` steps; a run that stops early ends with
    `steps/steps` and the reason, rather than a bar stuck at `steps/total`.

    **Arguments:**

    - `total`: int, the largest number of steps.
    - `desc`: the label in front of the bar.
    - `file`: where to write (default: tqdm's, stderr).
    """

    def __init__(self, total: int, desc: str = "minimize", file=None):
        from tqdm import tqdm

        self.total = int(total)
        self.desc = desc
        self.steps = 0
        self.bar = tqdm(total=self.total, desc=f"{desc} (compiling)", unit="step", dynamic_ncols=True, file=file,
                        bar_format=_RUNNING)

    def update(self, postfix: dict | None = None) -> None:
        """Counts one step; `postfix` is shown after the bar (e.g. the energy)."""
        if self.steps == 0:
            self.bar.reset(total=self.total)  # the clock starts after the compiling step
            self.bar.set_description(self.desc, refresh=False)
        self.steps += 1
        if postfix:
            self.bar.set_postfix(postfix, refresh=False)
        self.bar.update(1)

    def close(self, reason: str | None = None) -> None:
        """Closes the bar, at 100% when fewer than `total` steps ran, with the stop reason
        (left out while an exception propagates, e.g. when called in a `finally`)."""
        if sys.exc_info()[0] is not None:
            reason = None
        else:
            self.bar.bar_format = _DONE
            self.bar.total = min(self.steps, self.total)
        if reason:
            shown = self.bar.postfix
            self.bar.set_postfix_str(f"{shown}, stop: {reason}" if shown else f"stop: {reason}", refresh=False)
        self.bar.refresh()
        self.bar.close()
