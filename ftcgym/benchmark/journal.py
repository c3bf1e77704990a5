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
CONFIG_FILE = "sweep_config.json"  # the sweep config the rows were flown with (`sweep._claim_out_dir`)


class EpisodeJournal:
    """Append-only record of one run's finished episodes and failed attempts in `out_dir`."""

    def __init__(self, out_dir):
        self.out_dir = Path(out_dir)
        self.rows_path = self.out_dir / ROWS_FILE
        self.failures_path = self.out_dir / FAILURES_FILE

    def exists(self) -> bool:
        return self.rows_path.exists()

    def finished_rows(self) -> dict[str, dict]:
        """Rows recorded so far, by episode key. A line cut short by a crash is skipped (and said so); a key
        recorded twice with different rows is a ValueError naming it (two runs wrote this journal), the same
        row twice is kept once."""
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
                key, row = entry["key"], entry["row"]
            except (json.JSONDecodeError, KeyError, TypeError):
                print(f"{self.rows_path}:{number}: unreadable line skipped; that episode runs again", file=sys.stderr)
                continue
            if key in rows and _canonical(rows[key]) != _canonical(row):
                raise ValueError(f"{self.rows_path}:{number}: episode {key!r} is recorded twice with different "
                                 "rows; the journal mixes two runs, so neither can be trusted")
            rows[key] = row
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


def _canonical(row) -> str:
    """A row as comparable text: JSON with sorted keys, so NaN equals NaN and key order does not matter."""
    return json.dumps(row, sort_keys=True)
