"""Reports: a Markdown table like the paper's Table I on stdout and in ``results.md``, plus JSON and CSV."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any, Sequence

COLUMNS = (("EPE3D", "EPE3D (m)↓"), ("Acc3DS", "Acc3DS↑"), ("Acc3DR", "Acc3DR↑"), ("Outliers3D", "Outliers3D↓"),
           ("EPE3D_static", "EPE3D static↓"), ("EPE3D_moving", "EPE3D moving↓"),
           ("EPE3D_threeway", "EPE3D 3-way↓"), ("EPE3D_norm_dynamic", "dyn. norm. EPE↓"),
           ("EPE3D_z0-20", "EPE3D z<20 m↓"), ("EPE3D_z20-35", "EPE3D z 20–35 m↓"),
           ("EPE3D_z35+", "EPE3D z≥35 m↓"),
           ("seconds_per_scene", "time/scene (s)"))
# Also in results.csv / .json (not in the Markdown table): EPE3D_bg_static, EPE3D_fg_static, EPE3D_fg_dynamic.


def _cell(row: dict[str, Any], key: str) -> str:
    v = row.get(key)
    if v is None:
        return "–"
    std = row.get(f"{key}_std")
    text = f"{v:.4f}" if key != "seconds_per_scene" else f"{v:.3f}"
    return f"{text} ± {std:.4f}" if std is not None else text


def markdown_table(rows: Sequence[dict[str, Any]], title: str | None = None) -> str:
    """The methods × metrics table (columns absent from every row are left out)."""
    cols = [(k, h) for k, h in COLUMNS if any(r.get(k) is not None for r in rows)]
    lines = []
    if title:
        lines += [f"### {title}", ""]
    lines.append("| Method | " + " | ".join(h for _, h in cols) + " |")
    lines.append("|---|" + "---|" * len(cols))
    for r in rows:
        lines.append(f"| {r['method']} | " + " | ".join(_cell(r, k) for k, _ in cols) + " |")
    return "\n".join(lines) + "\n"


def provenance() -> dict[str, Any]:
    """Package versions, git revision and command line, saved with every report (docs/design.md §1)."""
    import sys

    from core.runinfo import git_revision, package_versions

    return {"versions": package_versions(), "git": git_revision(describe=True), "argv": sys.argv}


def write_reports(out_dir: Path, rows: Sequence[dict[str, Any]], details: dict[str, Any], title: str) -> Path:
    """Write ``results.md``, ``results.json`` (title, rows, details, provenance) and ``results.csv`` (the
    rows); return the folder."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "results.md").write_text(markdown_table(rows, title))
    payload = {"title": title, "rows": list(rows), **details, **provenance()}
    (out_dir / "results.json").write_text(json.dumps(payload, indent=2, default=str) + "\n")
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with (out_dir / "results.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    return out_dir
