"""A report written as files, for every report hub-envs writes (reproduce, diff). Imports nothing heavy:
``hub-envs diff --help`` reaches it.

    >>> import tempfile
    >>> class Note(ReportFiles):
    ...     def to_json(self): return "{}"
    ...     def to_markdown(self): return "# note"
    >>> sorted(Note().write(tempfile.mkdtemp()))
    ['json', 'markdown']
"""

from __future__ import annotations

from pathlib import Path

REPORT_JSON = "report.json"
REPORT_MD = "report.md"
REPORT_PNG = "report.png"


class ReportFiles:
    """A report as files: ``report.json`` (machines), ``report.md`` (people) and ``report.png`` when the report
    has a plot (:meth:`plot` returns its path; None without one, or without matplotlib, the ``plots`` extra)."""

    paths: dict[str, str]

    def plot(self, path: Path) -> Path | None:
        return None

    def to_json(self) -> str:
        raise NotImplementedError

    def to_markdown(self) -> str:
        raise NotImplementedError

    def write(self, out: str | Path) -> dict[str, str]:
        """Write the files into ``out`` (created); return their paths (also in ``self.paths``)."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        png = self.plot(out / REPORT_PNG)
        self.paths = {"json": str(out / REPORT_JSON), "markdown": str(out / REPORT_MD)}
        if png is not None:
            self.paths["png"] = str(png)
        (out / REPORT_MD).write_text(self.to_markdown(), encoding="utf-8")  # the Markdown links the PNG by name
        (out / REPORT_JSON).write_text(self.to_json(), encoding="utf-8")
        return dict(self.paths)
