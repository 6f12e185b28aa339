"""When refinement stops: the loss over all views, estimated from each view's latest loss, has
not fallen by a relative tolerance for a number of steps."""

from __future__ import annotations

import math


class EarlyStop:
    """Feed `update({view: loss})` after every step; `should_stop` turns true once every view has a
    loss and their mean has not gone below (1 - tolerance) x the last mark for `patience` steps.

    One view per step makes the raw loss jump with the view's content; the mean of every view's
    latest loss moves only with the fit, so the rule reads the trend, not which view came up."""

    def __init__(self, views: int, patience: int, tolerance: float):
        self.latest = [math.nan] * views
        self.patience = patience
        self.tolerance = tolerance
        self.mark = math.inf
        self.steps_since_mark = 0

    @property
    def running_loss(self) -> float:
        """Mean of every view's latest loss (NaN until every view has one)."""
        return sum(self.latest) / len(self.latest)

    def update(self, losses: dict[int, float]) -> None:
        """The losses of the views rendered in one step."""
        for view, loss in losses.items():
            self.latest[view] = loss
        running = self.running_loss
        if math.isnan(running):
            return
        if running < self.mark * (1 - self.tolerance):
            self.mark = running
            self.steps_since_mark = 0
        else:
            self.steps_since_mark += 1

    def restart(self) -> None:
        """Forget the best loss so far: after the scene changed (densification), the next
        `patience` steps are judged against where it is now, not stopped before they settle."""
        self.mark = math.inf
        self.steps_since_mark = 0

    @property
    def should_stop(self) -> bool:
        return self.steps_since_mark >= self.patience
