"""Training logs: one JSONL line and one CSV row per logged step, every term included."""

from __future__ import annotations

import csv
import json
from pathlib import Path


class MetricLogger:
    """Append-only CSV + JSONL logger. Columns are fixed by the first row; later new keys go to JSONL only.

    On resume, rows after ``resume_step`` (written by the interrupted run after its last checkpoint)
    are dropped so the logs match an uninterrupted run.
    """

    def __init__(self, run_dir: Path, name: str = "train", resume_step: int | None = None) -> None:
        self.jsonl = run_dir / f"{name}.jsonl"
        self.csv = run_dir / f"{name}.csv"
        self._fields: list[str] | None = None
        if resume_step is not None:
            self._truncate(resume_step)
        elif self.jsonl.exists() or self.csv.exists():
            self.jsonl.unlink(missing_ok=True)
            self.csv.unlink(missing_ok=True)
        if self.csv.exists():
            with self.csv.open() as f:
                header = f.readline().strip()
            self._fields = header.split(",") if header else None

    def _truncate(self, step: int) -> None:
        if self.jsonl.exists():
            keep = [ln for ln in self.jsonl.read_text().splitlines() if ln and json.loads(ln).get("step", 0) <= step]
            self.jsonl.write_text("".join(ln + "\n" for ln in keep))
        if self.csv.exists():
            rows = list(csv.DictReader(self.csv.open()))
            fields = rows[0].keys() if rows else None
            keep_rows = [r for r in rows if int(float(r.get("step", 0))) <= step]
            if fields:
                with self.csv.open("w", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=list(fields))
                    w.writeheader()
                    w.writerows(keep_rows)

    def log(self, row: dict[str, float | int | str]) -> None:
        with self.jsonl.open("a") as f:
            f.write(json.dumps(row, sort_keys=True) + "\n")
        if self._fields is None:
            self._fields = list(row.keys())
            with self.csv.open("w", newline="") as f:
                csv.DictWriter(f, fieldnames=self._fields).writeheader()
        with self.csv.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=self._fields, extrasaction="ignore").writerow(row)
