"""The benchmark's outputs: ``bench.json``, ``bench.md`` (a table per group) and ``psnr_time.png``."""

from __future__ import annotations

import json
import os
from pathlib import Path
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


def markdown(doc: dict[str, Any]) -> str:
    """A Markdown table per group: PSNR / SSIM at each checkpoint, then speed and memory."""
    marks = doc["checkpoints"]
    lines = []
    for group in ("presets", "ablations"):
        rows = [r for r in doc["results"] if r["group"] == group]
        if not rows:
            continue
        lines.append(f"**{group}** (held-out PSNR dB / SSIM after the given training time)\n")
        header = ["configuration", *(_label(m) for m in marks), "steps", "samples/ray", "samples/s", "render s/image",
                  "peak memory"]
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "|".join([":--"] + ["--:"] * (len(header) - 1)) + "|")
        for r in rows:
            cells = [r["name"]]
            for m in marks:
                p = psnr_at(r, m)
                cells.append("–" if p is None else f"{p['psnr']:.2f} / {p['ssim']:.3f}")
            done = "" if not r["finished"] else f" (done at {r['train_seconds']:.0f} s)"
            cells += [f"{r['steps']}{done}", f"{r['samples_per_ray']:.1f}", f"{r['samples_per_s']:,}",
                      "–" if r["render_seconds_per_image"] is None else f"{r['render_seconds_per_image']:.2f}",
                      f"{r['peak_memory_bytes'] / 2**30:.2f} GiB"]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    first = doc["results"][0] if doc["results"] else None
    if first is not None:
        size = first.get("image_size")
        lines.append(f"{first['train_images']} training views, {first['heldout']} held-out views"
                     + (f" at {size[0]}x{size[1]}" if size else "") + f", on {first['device']}.")
    return "\n".join(lines) + "\n"


def plot(doc: dict[str, Any], path: Path) -> None:
    """Held-out PSNR against training time, one line per configuration (ablations dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=110)
    for r in doc["results"]:
        pts = sorted(r["points"], key=lambda p: p["seconds"])
        ax.plot([p["seconds"] / 60 for p in pts], [p["psnr"] for p in pts], marker="o", markersize=3,
                linestyle="-" if r["group"] == "presets" else "--", label=r["name"])
    ax.set_xlabel("training time (min)")
    ax.set_ylabel("held-out PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
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
