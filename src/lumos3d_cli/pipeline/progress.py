"""How a job reports progress: named stages with a number of steps. The CLI draws them as
progress bars; Python callers pass nothing (or their own object) and get no output."""

from __future__ import annotations

from typing import Protocol


class JobProgress(Protocol):
    def start(self, stage: str, total: int) -> None:
        """A stage of `total` steps begins."""

    def advance(self, stage: str, steps: int = 1) -> None:
        """`steps` more steps of `stage` are done."""


class SilentProgress:
    """Progress that is not shown."""

    def start(self, stage: str, total: int) -> None:
        pass

    def advance(self, stage: str, steps: int = 1) -> None:
        pass
