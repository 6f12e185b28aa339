"""The viewer panel's text: what the scene is, how it was made and how good it is (Markdown)."""

from __future__ import annotations

from lumos3d_cli.viewer.scene_folder import ViewerScene


def _seconds(value: float) -> str:
    return f"{value:.1f} s" if value >= 1 else f"{1000 * value:.0f} ms"


def _geometry_source(summary: dict) -> str | None:
    """summary.json's "geometry": a name, or an object naming its source."""
    geometry = summary.get("geometry")
    if isinstance(geometry, str):
        return geometry
    if isinstance(geometry, dict):
        for key in ("source", "method", "name"):
            if isinstance(geometry.get(key), str):
                return geometry[key]
    return None


def splat_count_line(total: int, shown: int, max_splats: int) -> str:
    """How many Gaussians the browser gets; says so when it is a subsample."""
    if shown == total:
        return f"**{total:,} Gaussians**"
    return (f"**{shown:,} of {total:,} Gaussians** shown: the browser gets at most {max_splats:,} "
            f"(the most opaque and largest; change with `--max-splats`)")


def summary_rows(summary: dict) -> list[tuple[str, str]]:
    """(label, value) rows from summary.json: views, geometry, mode, timings, metrics."""
    rows: list[tuple[str, str]] = []
    views = summary.get("views_used", len(summary.get("views", [])) or None)
    if views is not None:
        inputs = summary.get("inputs")
        rows.append(("views", f"{views} of {inputs} photos" if isinstance(inputs, int) and inputs != views else str(views)))
    geometry = _geometry_source(summary)
    if geometry:
        rows.append(("geometry", geometry))
    made_by = [key for key in ("mode", "preset", "device") if summary.get(key)]  # e.g. low-light · balanced · cpu
    if made_by:
        rows.append(("run", " · ".join(str(summary[key]) for key in made_by)))
    seconds = summary.get("seconds")
    if isinstance(seconds, dict) and isinstance(seconds.get("total"), (int, float)):
        stages = ", ".join(f"{k} {_seconds(v)}" for k, v in seconds.items() if k != "total" and isinstance(v, (int, float)))
        rows.append(("time", f"{_seconds(seconds['total'])} ({stages})" if stages else _seconds(seconds["total"])))
    metrics = summary.get("metrics")
    mean = metrics.get("mean") if isinstance(metrics, dict) else None
    if isinstance(mean, dict):
        for key, label, digits in (("psnr", "PSNR (dB)", 2), ("ssim", "SSIM", 3), ("lpips", "LPIPS", 3)):
            if isinstance(mean.get(key), (int, float)):
                rows.append((f"{label} vs reference", f"{mean[key]:.{digits}f}"))
    return rows


def panel_markdown(scene: ViewerScene, shown: int, max_splats: int) -> str:
    """The panel: file name, splat count (and subsample), summary table, notes."""
    lines = [f"**{scene.scene_path.name}** · {splat_count_line(len(scene.gaussians), shown, max_splats)}"]
    if scene.cameras is not None:
        lines[0] += f" · {len(scene.cameras)} cameras"
    if scene.points is not None:
        lines[0] += f" · {len(scene.points.xyz):,} SfM points"
    rows = summary_rows(scene.summary) if scene.summary else []
    if rows:
        lines += ["", "| | |", "|---|---|"] + [f"| {label} | {value} |" for label, value in rows]
    if scene.cameras is not None:
        lines += ["", "Click a camera to look through it."]
    lines += [""] + [f"*{note}*  " for note in scene.notes]
    return "\n".join(lines).rstrip()
