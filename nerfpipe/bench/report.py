"""The benchmark's outputs: ``bench.json``, ``bench.md`` (a table per group) and ``psnr_time.png``."""

from __future__ import annotations

import json
import os
from pathlib import Path
from statistics import fmean, stdev
from typing import Any


def psnr_at(result: dict[str, Any], seconds: float) -> dict[str, Any] | None:
    """The evaluation of the model after ``seconds`` of training: the copy taken at that checkpoint, or
    the end of training when it finished earlier; None when the budget stopped it before."""
    for p in result["points"]:
        if p["mark"] == seconds:
            return p
    last = max(result["points"], key=lambda p: p["seconds"], default=None)
    if last is not None and result["finished"] and last["seconds"] <= seconds:
        return last
    return None


def _label(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 60 else f"{seconds / 60:g} min"


def configurations(results: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """The results grouped by configuration, in the order they came: one list of runs (seeds) each."""
    runs: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in results:
        runs.setdefault((r["group"], r["name"]), []).append(r)
    return list(runs.values())


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value)."""
    return fmean(values), stdev(values) if len(values) > 1 else 0.0


def _at(runs: list[dict[str, Any]], seconds: float) -> list[dict[str, Any]] | None:
    points = [psnr_at(r, seconds) for r in runs]
    return None if any(p is None for p in points) else points  # type: ignore[return-value]


def markdown(doc: dict[str, Any]) -> str:
    """A Markdown table per group: PSNR / SSIM at each checkpoint, then speed and memory.

    With several seeds a configuration's cells are mean ± standard deviation over its runs, and the
    ablations gain a column: the difference of the final mean PSNR from the complete model's, ± its
    standard error, so a difference can be read against the spread over seeds.
    """
    marks = doc["checkpoints"]
    lines = []
    grouped = configurations(doc["results"])
    seeded = any(len(runs) > 1 for runs in grouped)
    for group in ("presets", "ablations"):
        rows = [runs for runs in grouped if runs[0]["group"] == group]
        if not rows:
            continue
        reference = next((runs for runs in rows if runs[0]["name"] == "complete"), None) if seeded else None
        lines.append(f"**{group}** (held-out PSNR dB / SSIM after the given training time)\n")
        header = ["configuration", *(_label(m) for m in marks), *(["Δ PSNR"] if reference else []), "steps",
                  "samples/ray", "samples/s", "render s/image", "peak memory"]
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "|".join([":--"] + ["--:"] * (len(header) - 1)) + "|")
        for runs in rows:
            cells = [runs[0]["name"]]
            for m in marks:
                points = _at(runs, m)
                if points is None:
                    cells.append("–")
                    continue
                psnr, spread = mean_std([p["psnr"] for p in points])
                ssim = fmean(p["ssim"] for p in points)
                cells.append(f"{psnr:.2f}" + (f" ± {spread:.2f}" if seeded else "") + f" / {ssim:.3f}")
            if reference:
                cells.append(_difference(runs, reference, marks[-1]))

            def mean(key: str) -> float:
                return fmean(r[key] for r in runs)

            done = f" (done at {mean('train_seconds'):.0f} s)" if all(r["finished"] for r in runs) else ""
            renders = [r["render_seconds_per_image"] for r in runs if r["render_seconds_per_image"] is not None]
            cells += [f"{round(mean('steps'))}{done}", f"{mean('samples_per_ray'):.1f}",
                      f"{round(mean('samples_per_s')):,}", f"{fmean(renders):.2f}" if renders else "–",
                      f"{max(r['peak_memory_bytes'] for r in runs) / 2**30:.2f} GiB"]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    first = doc["results"][0] if doc["results"] else None
    if first is not None:
        size = first.get("image_size")
        lines.append(f"{first['train_images']} training views, {first['heldout']} held-out views"
                     + (f" at {size[0]}x{size[1]}" if size else "") + f", on {first['device']}.")
        if seeded:
            seeds = sorted({r.get("seed", 0) for r in doc["results"]})
            lines.append(f"Mean ± standard deviation over seeds {', '.join(map(str, seeds))} (train.seed); "
                         f"Δ PSNR: the mean's difference from the complete model's after {_label(marks[-1])}, "
                         "± its standard error.")
    return "\n".join(lines) + "\n"


def _difference(runs: list[dict[str, Any]], reference: list[dict[str, Any]], seconds: float) -> str:
    if runs is reference:
        return "reference"
    ours, theirs = _at(runs, seconds), _at(reference, seconds)
    if ours is None or theirs is None:
        return "–"
    (a, sa), (b, sb) = mean_std([p["psnr"] for p in ours]), mean_std([p["psnr"] for p in theirs])
    error = (sa**2 / len(ours) + sb**2 / len(theirs)) ** 0.5
    return f"{a - b:+.2f} ± {error:.2f}"


def plot(doc: dict[str, Any], path: Path) -> None:
    """Held-out PSNR against training time, one line per configuration (ablations dashed); with several
    seeds, the line is their mean at each checkpoint and a band spans their lowest to highest."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=110)
    for runs in configurations(doc["results"]):
        style = {"linestyle": "-" if runs[0]["group"] == "presets" else "--", "label": runs[0]["name"]}
        if len(runs) == 1:
            pts = sorted(runs[0]["points"], key=lambda p: p["seconds"])
            ax.plot([p["seconds"] / 60 for p in pts], [p["psnr"] for p in pts], marker="o", markersize=3, **style)
            continue
        at = {m: points for m in doc["checkpoints"] if (points := _at(runs, m)) is not None}
        minutes, values = [m / 60 for m in at], [[p["psnr"] for p in points] for points in at.values()]
        line, = ax.plot(minutes, [fmean(v) for v in values], marker="o", markersize=3, **style)
        ax.fill_between(minutes, [min(v) for v in values], [max(v) for v in values], color=line.get_color(),
                        alpha=0.15, linewidth=0)
    ax.set_xlabel("training time (min)")
    ax.set_ylabel("held-out PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=1, loc="lower right")  # PSNR rises with time: that corner stays empty
    fig.tight_layout()
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    os.replace(tmp, path)


def write_outputs(folder: Path, doc: dict[str, Any]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in (("bench.json", json.dumps(doc, indent=1)), ("bench.md", markdown(doc))):
        tmp = folder / f".{name}.tmp"
        tmp.write_text(text)
        os.replace(tmp, folder / name)
    if doc["results"]:
        plot(doc, folder / "psnr_time.png")
