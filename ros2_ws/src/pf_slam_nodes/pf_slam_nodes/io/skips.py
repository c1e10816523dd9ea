"""Skipped input, counted and reported the same way by every reader and converter.

A recoverable fault in one line, row or image (wrong field count, non-numeric, NaN, a truncated
PNG ...) skips that item: its reason is counted in ``skipped`` (``{reason key: count}``, printed in
the conversion summary) and the first ``MAX_LINE_WARNINGS`` per file are named in ``warnings`` as
``file:line: what was wrong; line skipped``; past that, one line per file says how many more
were not listed.
"""

from __future__ import annotations

__all__ = ["MAX_LINE_WARNINGS", "SkipLog"]

#: Per-file warnings kept in full; beyond this only the counts grow.
MAX_LINE_WARNINGS = 100


class SkipLog:
    """Counts skips into ``skipped`` and names them into ``warnings`` (both shared, not copied).

    Parameters
    ----------
    skipped : dict
        ``{reason key: count}`` to increment (a reader's or a ``ConvertReport``'s).
    warnings : list
        Human-readable lines to append to.
    """

    def __init__(self, skipped: dict, warnings: list) -> None:
        self.skipped, self.warnings = skipped, warnings
        self._per_file: dict[str, int] = {}

    def skip(self, where: str, line_no: int | None, reason: str, key: str | None = None, what: str = "line") -> None:
        """Count one skipped ``what`` of file ``where`` (at ``line_no``, if it has lines).

        ``key`` is the ``skipped`` entry to increment (default: ``reason``).
        """
        key = reason if key is None else key
        self.skipped[key] = self.skipped.get(key, 0) + 1
        n = self._per_file[where] = self._per_file.get(where, 0) + 1
        if n <= MAX_LINE_WARNINGS:
            at = where if line_no is None else f"{where}:{line_no}"
            self.warnings.append(f"{at}: {reason}; {what} skipped")

    def finish(self) -> None:
        """Append one line per file whose skips were not all listed (call once, at the end)."""
        for where, n in self._per_file.items():
            if n > MAX_LINE_WARNINGS:
                self.warnings.append(f"{where}: {n - MAX_LINE_WARNINGS} more skipped not listed")
        self._per_file.clear()
