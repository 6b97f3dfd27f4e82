"""The written report: sections of text, markdown tables and figures, saved atomically."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from orange_plan.atomic import atomic_path


@dataclass(frozen=True)
class Table:
    """A markdown table: caption, column headers, rows of already formatted cells."""

    caption: str
    header: list[str]
    rows: list[list[str]]

    def markdown(self) -> str:
        lines = [f"**{self.caption}**", "", "| " + " | ".join(self.header) + " |",
                 "|" + "---|" * len(self.header)]
        lines += ["| " + " | ".join(row) + " |" for row in self.rows]
        return "\n".join(lines)


@dataclass(frozen=True)
class Section:
    """One experiment: title, paragraphs, tables and the figure file (relative to the report)."""

    title: str
    paragraphs: list[str]
    tables: list[Table] = field(default_factory=list)
    figure: str | None = None
    data: dict = field(default_factory=dict)

    def markdown(self) -> str:
        parts = [f"## {self.title}", *self.paragraphs]
        if self.figure:
            parts.append(f"![{self.title}]({self.figure})")
        parts += [t.markdown() for t in self.tables]
        return "\n\n".join(parts)


def write_report(path: str | Path, title: str, preamble: list[str],
                 sections: list[Section]) -> Path:
    """Write the markdown report (atomic)."""
    text = "\n\n".join([f"# {title}", *preamble, *(s.markdown() for s in sections)]) + "\n"
    with atomic_path(path, suffix=".md") as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
