"""How the depth sweep (`geometry.photo_consistency`) searches: torch-free, so that the presets
can be read before torch is imported (`pipeline.early_registration`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DepthSweepSettings:
    """neighbours: the nearest cameras (by centre) each view is compared with; span: the largest
    relative depth change tried; hypotheses: depths tried per pixel (odd: the current depth is
    one); radius: the NCC window's half size in depth-map pixels; best: the neighbours whose
    scores are averaged per hypothesis; min_score: the NCC a new depth needs; min_contrast: how
    much higher its score must be than the lowest of the swept depths (a score that hardly
    changes with depth, as between views close together for the depth they see, says nothing
    about the depth); min_angle, max_angle: the triangulation angles (degrees, at the view's
    median depth) a neighbour must see the view's scene at; max_disagreement: how far (relative)
    a new depth may lie from the swept depth of some neighbour where it lands in that neighbour
    (0: no such check). Defaults chosen on
    the development scenes (pipeline.presets.DEPTH_SWEEP says how)."""

    neighbours: int = 4
    span: float = 0.25
    hypotheses: int = 17
    radius: int = 3
    best: int = 2
    min_score: float = 0.5
    min_contrast: float = 0.5
    min_angle: float = 3.0
    max_angle: float = 15.0
    max_disagreement: float = 0.02

    def __post_init__(self) -> None:
        if self.neighbours < 1 or not 1 <= self.best <= self.neighbours:
            raise ValueError(f"neighbours={self.neighbours} must be >= 1 and best={self.best} in [1, neighbours]")
        if not 0 < self.span < 1:
            raise ValueError(f"span={self.span} must be in (0, 1)")
        if self.hypotheses < 3 or self.hypotheses % 2 == 0:
            raise ValueError(f"hypotheses={self.hypotheses} must be odd and >= 3 (the current depth is the middle one)")
        if self.radius < 1:
            raise ValueError(f"radius={self.radius} must be >= 1")
        if not 0 <= self.min_contrast <= 2:
            raise ValueError(f"min_contrast={self.min_contrast} must be in [0, 2]")
        if not 0 <= self.min_angle < self.max_angle <= 180:
            raise ValueError(f"min_angle={self.min_angle}, max_angle={self.max_angle}: use 0 <= min_angle < max_angle <= 180")
        if not 0 <= self.max_disagreement < 1:
            raise ValueError(f"max_disagreement={self.max_disagreement} must be in [0, 1)")
        if not -1 <= self.min_score <= 1:
            raise ValueError(f"min_score={self.min_score} must be in [-1, 1]")
