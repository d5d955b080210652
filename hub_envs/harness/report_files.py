"""A report written as files, for every report hub-envs writes (reproduce, diff, compare). Imports nothing
heavy: ``hub-envs diff --help`` reaches it.

    >>> import tempfile, time
    >>> class Note(ReportFiles):
    ...     def to_dict(self): return {"ok": True}
    ...     def to_markdown(self): return "# note"
    >>> note = Note()
    >>> note.finish({"load": 0.5}, time.perf_counter(), out=tempfile.mkdtemp(), default=Path("notes-out"))
    >>> sorted(note.paths), sorted(note.timings), json.loads(note.to_json())
    (['json', 'markdown'], ['load', 'report', 'total'], {'ok': True})
"""

from __future__ import annotations

import json
import time
from pathlib import Path

REPORT_JSON = "report.json"
REPORT_MD = "report.md"
REPORT_PNG = "report.png"


class ReportFiles:
    """A report as files: ``report.json`` (machines), ``report.md`` (people) and ``report.png`` when the report
    has a plot (:meth:`plot` returns its path; None without one, or without matplotlib, the ``plots`` extra)."""

    paths: dict[str, str]
    timings: dict[str, float]

    def plot(self, path: Path) -> Path | None:
        return None

    def to_dict(self) -> dict:
        raise NotImplementedError

    def to_json(self) -> str:
        """Canonical JSON of :meth:`to_dict` (sorted keys, fixed indentation; NaN refused)."""
        return json.dumps(self.to_dict(), indent=2, sort_keys=True, allow_nan=False) + "\n"

    def to_markdown(self) -> str:
        raise NotImplementedError

    def write(self, out: str | Path) -> dict[str, str]:
        """Write the files into ``out`` (created); return their paths (also in ``self.paths``).

        Args:
            out: the folder of the report (created with its parents).

        Returns:
            The paths written, by kind: ``"json"``, ``"markdown"`` and, when the report has a plot, ``"png"``.

        Raises:
            ValueError: the report holds a NaN or an infinity (its JSON would not be JSON).
        """
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        png = self.plot(out / REPORT_PNG)
        self.paths = {"json": str(out / REPORT_JSON), "markdown": str(out / REPORT_MD)}
        if png is not None:
            self.paths["png"] = str(png)
        (out / REPORT_MD).write_text(self.to_markdown(), encoding="utf-8")  # the Markdown links the PNG by name
        (out / REPORT_JSON).write_text(self.to_json(), encoding="utf-8")
        return dict(self.paths)

    def finish(self, timings: dict[str, float], t0: float, *, out: str | Path | None, default: Path, write: bool = True) -> None:
        """Record ``timings`` (seconds; they go into the files), write the files into ``out`` (default:
        ``default``) unless ``write`` is False, then add the time that took (``report``) and the time since
        ``t0`` (``total``), which the files written by then do not hold.

        Args:
            timings: seconds per stage of the run, by stage name.
            t0: ``time.perf_counter()`` at the start of the run.
            out: the folder to write the files into, or None for ``default``.
            default: the folder used when ``out`` is None (see :func:`default_out_dir`).
            write: False records the timings and writes nothing.

        Raises:
            ValueError: the report holds a NaN or an infinity (see :meth:`write`).
        """
        self.timings = {k: round(v, 4) for k, v in timings.items()}
        if write:
            t = time.perf_counter()
            self.write(Path(out) if out is not None else default)
            self.timings["report"] = round(time.perf_counter() - t, 4)
        self.timings["total"] = round(time.perf_counter() - t0, 4)


def default_out_dir(root: str | Path, repo_id: str) -> Path:
    """``root/<user>/<name>``, the default folder of a report about ``repo_id`` (no ``..`` or empty parts).

    Args:
        root: the folder of all such reports (e.g. ``"reproduce-out"``).
        repo_id: the repo the report is about, ``user/name``.

    Returns:
        The folder, under ``root`` whatever ``repo_id`` holds.

    >>> default_out_dir("reproduce-out", "alice/../hover").as_posix()
    'reproduce-out/alice/hover'
    """
    return Path(root).joinpath(*[p for p in repo_id.split("/") if p not in ("", ".", "..")])


def seeds_text(seeds: list) -> str:
    """Seeds as a report shows them: all of up to four, else the first, the last and how many.

    Args:
        seeds: the seeds, in order.

    Returns:
        The text (``"-"`` for none).

    >>> seeds_text([0, 1, 2]), seeds_text(list(range(10))), seeds_text([])
    ('0, 1, 2', '0…9 (10)', '-')
    """
    if not seeds:
        return "-"
    return f"{seeds[0]}…{seeds[-1]} ({len(seeds)})" if len(seeds) > 4 else ", ".join(map(str, seeds))


def save_figure(fig, path: str | Path, *, dpi: int = 100) -> Path:
    """Save a matplotlib figure as a report's PNG (laid out tight, unless it has its own layout) and close it; its path.

    Args:
        fig: a ``matplotlib.figure.Figure``.
        path: the PNG file to write.
        dpi: its resolution.

    Returns:
        ``path``, as a ``Path``.
    """
    import matplotlib.pyplot as plt  # heavy: matplotlib

    if fig.get_layout_engine() is None:
        fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
