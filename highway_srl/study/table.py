"""A table of the study: rows of raw values written as CSV (raw) and Markdown (formatted by each column's kind)."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable


def fmt(kind: str, value) -> str:
    if value is None or value == "" or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if kind == "pct":
        return f"{100 * value:.1f}%"
    if kind == "pp":  # a spread of a rate, in percentage points
        return f"±{100 * value:.1f}"
    if kind == "sd":
        return f"±{value:.2f}"
    if kind.startswith("f"):
        return f"{value:.{int(kind[1:])}f}"
    if kind == "int":
        return f"{int(value):,}"
    return str(value)


@dataclass
class Column:
    key: str
    header: str
    kind: str = "text"  # text | int | pct | pp | sd | f<digits>
    render: Callable[[dict], str] | None = None  # Markdown cell from the whole row, overriding kind


@dataclass
class Table:
    """Rows of raw values; CSV keeps them raw, Markdown formats them. `display` (optional) is a different
    Markdown shape of the same numbers (e.g. Table 5 wide, its CSV long)."""

    name: str
    title: str
    columns: list[Column]
    rows: list[dict]
    notes: list[str] = field(default_factory=list)
    display: "Table | None" = None

    def csv_text(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow([c.key for c in self.columns])
        for row in self.rows:
            w.writerow(["" if row.get(c.key) is None else _csv_value(row.get(c.key)) for c in self.columns])
        return buf.getvalue()

    def formatted(self) -> tuple[list[str], list[list[str]]]:
        """Headers and formatted cells of the Markdown shape (`display` if given)."""
        t = self.display or self
        cells = [[c.render(row) if c.render else fmt(c.kind, row.get(c.key)) for c in t.columns] for row in t.rows]
        return [c.header for c in t.columns], cells

    def markdown(self, heading: bool = True) -> str:
        headers, cells = self.formatted()
        lines = [f"## {self.title}", ""] if heading else []
        lines.append("| " + " | ".join(headers) + " |")
        lines.append("|" + "|".join("---" for _ in headers) + "|")
        for row in cells:
            lines.append("| " + " | ".join(s.replace("|", "\\|") for s in row) + " |")
        if self.notes:
            lines += [""] + [f"_{n}_" for n in self.notes]
        return "\n".join(lines) + "\n"

    def write(self, folder: Path) -> list[Path]:
        folder.mkdir(parents=True, exist_ok=True)
        paths = [folder / f"{self.name}.csv", folder / f"{self.name}.md"]
        write_text(paths[0], self.csv_text())
        write_text(paths[1], self.markdown())
        return paths


def _csv_value(v):
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


def write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)
