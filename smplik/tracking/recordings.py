"""Any tracker recording by its kind: ``smplik-trackers`` JSON and SteamVR JSON lines (:mod:`smplik.tracking.io`)
or a VR CSV recording (:mod:`smplik.tracking.csv_io`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from smplik.tracking.csv_io import read_csv_trackers
from smplik.tracking.io import TrackerFileError, TrackerSignals, read_steamvr_jsonl, signals_from_dict
from smplik.validation import read_json


def read_trackers(path: str | Path, **options: Any) -> TrackerSignals:
    """Read a tracker file: ``smplik-trackers`` JSON, a SteamVR JSON-lines log (``.jsonl``) or a VR CSV recording
    (``.csv``, or any file that is not JSON but has a CSV header of device columns:
    :func:`smplik.tracking.csv_io.read_csv_trackers`). ``options``: ``controller`` (CSV and JSON lines) and the CSV
    reader's ``units``, ``time_unit``, ``axes``; given for a file they do not apply to, they are refused."""
    path = Path(path)
    csv_only = sorted(k for k in ("units", "time_unit", "axes") if options.get(k) is not None)
    unknown = sorted(set(options) - {"units", "time_unit", "axes", "controller"})
    if unknown:
        raise TypeError(f"read_trackers: unknown option {unknown[0]!r}")
    if path.suffix.lower() == ".csv":
        return read_csv_trackers(path, **options)
    if csv_only:
        raise TrackerFileError(f"{path}: --csv-{csv_only[0].replace('_', '-')} is for CSV recordings (.csv).")
    if path.suffix.lower() == ".jsonl":
        return read_steamvr_jsonl(path, controller=options.get("controller") or "none")
    if options.get("controller") is not None:
        raise TrackerFileError(f"{path}: --controller is for device recordings (.csv, .jsonl); a smplik-trackers "
                               "file holds the wrists themselves.")
    try:
        data = read_json(path, TrackerFileError, what="tracker file")
    except TrackerFileError as exc:
        head = _first_line(path)
        if head is None or "," not in head or head.lstrip().startswith(("{", "[")):
            raise
        try:
            return read_csv_trackers(path)
        except TrackerFileError as csv_exc:
            raise TrackerFileError(f"{exc} It is not a VR CSV recording either: {csv_exc}") from None
    return signals_from_dict(data, str(path))


def _first_line(path: Path) -> str | None:
    """The file's first line (at most 4 KB), or None when it cannot be read as text."""
    try:
        with open(path, "rb") as f:
            return f.read(4096).decode("utf-8", errors="strict").splitlines()[0]
    except (OSError, UnicodeDecodeError, IndexError):
        return None
