"""A step counter for long loops: a tqdm bar whose rate and ETA leave out compilation,
and which ends at 100% with the stop reason when the loop stops early."""

from __future__ import annotations

import sys


class ProgressBar:
    """A tqdm progress bar over at most `total` steps.

    The first step of a jit-compiled loop includes the compilation, often far slower than
    every later step; counting it would predict minutes for a run of seconds. So the bar
    says "compiling" until the first step is done and starts its clock (rate, elapsed
    time, ETA) after it. A run that stops before `total` steps ends with `steps/steps`
    and the reason, rather than a bar stuck at `steps/total`.

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
        self.bar = tqdm(total=self.total, desc=f"{desc} (compiling)", unit="step", dynamic_ncols=True, file=file)

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
        elif self.steps < self.total:
            self.bar.total = self.steps
        if reason:
            shown = self.bar.postfix
            self.bar.set_postfix_str(f"{shown}, stop: {reason}" if shown else f"stop: {reason}", refresh=False)
        self.bar.refresh()
        self.bar.close()
