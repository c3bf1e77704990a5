"""A run's episode rows on disk as they finish, so a crash loses nothing and a run can be resumed.

`DIR/episodes.jsonl` holds one line per finished episode, `{"key": ..., "row": {...}}` (the row without its
trajectory); `DIR/failures.jsonl` one line per failed attempt, `{"key", "attempt", "error", "final"}`.
Each line is flushed and synced when written: the files are complete up to the last finished episode.
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

ROWS_FILE, FAILURES_FILE = "episodes.jsonl", "failures.jsonl"


class EpisodeJournal:
    """Append-only record of one run's finished episodes and failed attempts in `out_dir`."""

    def __init__(self, out_dir):
        self.out_dir = Path(out_dir)
        self.rows_path = self.out_dir / ROWS_FILE
        self.failures_path = self.out_dir / FAILURES_FILE

    def exists(self) -> bool:
        return self.rows_path.exists()

    def finished_rows(self) -> dict[str, dict]:
        """Rows recorded so far, by episode key. A line cut short by a crash is skipped (and said so)."""
        rows: dict[str, dict] = {}
        if not self.rows_path.exists():
            return rows
        text = self.rows_path.read_text()
        if text and not text.endswith("\n"):  # cut short mid-line: end it, so the next row starts a line
            with self.rows_path.open("a") as file:
                file.write("\n")
        for number, line in enumerate(text.splitlines(), start=1):
            try:
                entry = json.loads(line)
                rows[entry["key"]] = entry["row"]
            except (json.JSONDecodeError, KeyError, TypeError):
                print(f"{self.rows_path}:{number}: unreadable line skipped; that episode runs again", file=sys.stderr)
        return rows

    def record_row(self, key: str, row: dict) -> None:
        self._append(self.rows_path, {"key": key, "row": {k: v for k, v in row.items() if k != "trajectory"}})

    def record_failure(self, key: str, attempt: int, error: str, final: bool) -> None:
        self._append(self.failures_path, {"key": key, "attempt": attempt, "error": error, "final": final})

    def failures(self) -> list[dict]:
        if not self.failures_path.exists():
            return []
        return [json.loads(line) for line in self.failures_path.read_text().splitlines() if line.strip()]

    def _append(self, path: Path, entry: dict) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        with path.open("a") as file:
            file.write(json.dumps(entry) + "\n")
            file.flush()
            os.fsync(file.fileno())  # cheap next to an episode, and what makes "never lost" true
