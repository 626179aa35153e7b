"""The benchmark's tables and plot from a hand-made result, and the choice of configurations."""

from __future__ import annotations

import pytest

from nerfpipe.bench.configs import CONFIGS, select
from nerfpipe.bench.report import markdown, psnr_at, write_outputs


def result(name: str, group: str, points: list[tuple[float | None, float, float]], finished: bool) -> dict:
    return {
        "name": name, "group": group, "finished": finished, "steps": 100, "train_seconds": points[-1][1],
        "samples_per_ray": 12.345, "samples_per_s": 123456, "render_seconds_per_image": 0.5,
        "peak_memory_bytes": 3 * 2**29, "train_images": 100, "heldout": 5, "image_size": [100, 100], "device": "CPU",
        "points": [{"mark": m, "seconds": s, "step": 10, "psnr": p, "ssim": p / 100} for m, s, p in points],
    }


def test_psnr_at_takes_the_checkpoint_or_the_finished_model() -> None:
    slow = result("slow", "presets", [(30.0, 30.4, 20.0), (60.0, 60.2, 22.0)], finished=False)
    quick = result("quick", "presets", [(30.0, 30.1, 21.0), (None, 45.0, 24.0)], finished=True)
    assert psnr_at(slow, 30.0)["psnr"] == 20.0 and psnr_at(slow, 60.0)["psnr"] == 22.0
    assert psnr_at(slow, 120.0) is None  # the budget stopped it: no figure, not the last one
    assert psnr_at(quick, 60.0)["psnr"] == 24.0 and psnr_at(quick, 30.0)["psnr"] == 21.0


def test_markdown_and_plot(tmp_path) -> None:
    doc = {"capture": "lego", "budget": 60.0, "checkpoints": [30.0, 60.0], "results": [
        result("fast", "presets", [(30.0, 30.4, 20.0), (60.0, 60.2, 22.5)], finished=False),
        result("no PE", "ablations", [(30.0, 30.1, 18.0), (None, 45.0, 19.0)], finished=True),
    ]}
    text = markdown(doc)
    assert "| configuration | 30 s | 1 min | steps |" in text
    assert "| fast | 20.00 / 0.200 | 22.50 / 0.225 | 100 | 12.3 | 123,456 | 0.50 | 1.50 GiB |" in text
    assert "| no PE | 18.00 / 0.180 | 19.00 / 0.190 | 100 (done at 45 s) |" in text
    assert text.index("**presets**") < text.index("**ablations**")
    write_outputs(tmp_path, doc)
    assert (tmp_path / "bench.md").read_text() == text
    assert (tmp_path / "psnr_time.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*tmp*"))


def test_seeds_give_mean_spread_and_difference_from_the_complete_model(tmp_path) -> None:
    def seeded(name: str, psnrs: list[float]) -> list[dict]:
        runs = [result(name, "ablations", [(60.0, 60.1, p)], finished=False) for p in psnrs]
        for seed, run in enumerate(runs):
            run["seed"] = seed
        return runs

    doc = {"capture": "lego", "budget": 60.0, "checkpoints": [60.0],
           "results": seeded("complete", [21.0, 21.2, 21.4]) + seeded("no PE", [17.0, 17.3, 17.6])}
    text = markdown(doc)
    assert "| configuration | 1 min | Δ PSNR | steps |" in text
    # mean 21.2, sample standard deviation 0.2; SSIM is PSNR / 100 here
    assert "| complete | 21.20 ± 0.20 / 0.212 | reference | 100 |" in text
    # -3.9 dB, standard error sqrt(0.2² / 3 + 0.3² / 3) = 0.208
    assert "| no PE | 17.30 ± 0.30 / 0.173 | -3.90 ± 0.21 | 100 |" in text
    assert "over seeds 0, 1, 2" in text
    write_outputs(tmp_path, doc)
    assert (tmp_path / "psnr_time.png").stat().st_size > 1000


def test_select_expands_groups_and_refuses_unknown_names() -> None:
    assert [c.name for c in select(["fast", "presets"])][:2] == ["fast", "draft"]
    ablations = select(["ablations"])
    assert len(ablations) == 8 and ablations[0].name == "complete"
    # each ablation changes one thing of the complete model; row 4 also its N_c and networks, as the paper's (256, -)
    base = CONFIGS["complete"].overrides()
    for config in ablations[1:]:
        changed = {k for k, v in config.overrides().items() if base.get(k) != v}
        assert len(changed) == 1 or config.name == "no hierarchical", (config.name, changed)
    # row 4 evaluates the field as often a ray as the complete model's N_c + (N_c + N_f), with one network
    no_hierarchical = CONFIGS["no hierarchical"].overrides()
    assert base["field.fine_network"] and not no_hierarchical["field.fine_network"]
    assert not no_hierarchical["sampler.hierarchical"]
    n_c, n_f = base["sampler.n_coarse"], base["sampler.n_fine"]
    assert no_hierarchical["sampler.n_coarse"] == n_c + (n_c + n_f) == 64
    with pytest.raises(KeyError, match="turbo"):
        select(["turbo"])
