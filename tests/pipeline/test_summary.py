"""A stage's summary: written flat (a group's figures at the top level), read back equal, a key it does not
know left out and a figure it lacks at its default; a stage's ``describe`` is its summary's."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from nerfpipe.pipeline.summary import Summary


@dataclass(frozen=True)
class Speed(Summary):
    rays: int = 0
    rays_per_s: float = 0.0


@dataclass(frozen=True)
class Trained(Summary):
    steps: int = 0
    speed: Speed = Speed()
    psnr: float | None = None
    decisions: list[str] | None = None

    def describe(self) -> list[str]:
        return [f"{self.steps} steps, {self.speed.rays} rays"] if self.steps else []


def test_a_summary_is_written_flat_and_read_back_equal() -> None:
    summary = Trained(steps=300, speed=Speed(76_800, 256.0), psnr=24.5, decisions=["grid field"])
    doc = summary.to_json()
    assert doc == {"steps": 300, "rays": 76_800, "rays_per_s": 256.0, "psnr": 24.5, "decisions": ["grid field"]}
    assert Trained.from_json(doc) == summary
    # an older manifest: a figure it lacks takes its default, a key no longer known is left out
    old = Trained.from_json({"steps": 10, "rays": 5, "retired": True})
    assert old == Trained(steps=10, speed=Speed(rays=5)) and old.psnr is None


def test_a_stages_describe_is_its_summarys() -> None:
    from nerfpipe.stages.render import RenderStage, RenderSummary

    manifest = {"summary": RenderSummary(frames=45, path="orbit", seconds_per_frame=0.5, resolution=[640, 360],
                                         fps=15, device="cpu").to_json()}
    assert RenderStage().describe(Path("."), manifest) == [
        "45 frames of 640x360 at 15 fps, 0.50 s a frame on cpu", "path: orbit"]
    assert RenderStage().describe(Path("."), {}) == []  # a result without a summary says nothing
