"""What ``smplik batch`` will run, decided before anything heavy loads: the inputs (files, folders, globs, a
manifest), one output folder name per input, each input's job options (parsed by the job's own command),
and which inputs a rerun skips (their outputs are complete).

Light module: no torch, no numpy. Every mistake is a :class:`BatchError` (one ``error:`` line).

A manifest is a text file, one input path a line (``#`` starts a comment, blank lines are skipped), or a
``.json`` file::

    {"inputs": ["a.npz", {"path": "b.npz", "name": "take_2", "args": ["--frames", "0:300"]}]}

Relative paths (the inputs, and path options in ``args``) are taken from the manifest's folder. ``args`` are
the job's own options for that input, after the ones common to the batch.
"""

from __future__ import annotations

import enum
import glob
import hashlib
import json
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from workflows.batch.jobs import JOBS, Job, check_options

DONE_FILE = "batch_done.json"
"""Written last into an input's output folder: the folder is complete (its job, input and options)."""
REPORT_FILE = "batch_report.json"
"""The batch's report in the output folder."""
DONE_FORMAT = "smplik-batch-done"
REPORT_FORMAT = "smplik-batch-report"
MAX_MANIFEST_BYTES = 64 << 20
"""A manifest larger than this is refused (a list of paths is far smaller)."""
_PLACEHOLDER_OUT = "<smplik batch --out>"
_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?:partial|old)-\d+-[0-9a-f]{8}$")


class BatchError(ValueError):
    """A mistake in a ``smplik batch`` invocation: its inputs, manifest, options or output folder."""


@dataclass(frozen=True)
class BatchInput:
    """One input as given: a path (absolute), an optional output folder name, the job options it adds."""

    source: Path
    name: str | None = None
    args: tuple[str, ...] = ()
    base: Path | None = None
    """The folder relative paths in ``args`` are taken from (the manifest's), None: the current folder."""
    where: str = ""
    """Where the input was named (``manifest.txt line 3``), for errors."""


@dataclass(frozen=True)
class BatchTask:
    """One input's run: everything a worker needs (picklable, every path absolute)."""

    job: str
    source: str
    name: str
    out_dir: str
    params: Mapping[str, Any]
    """The job command's parsed options (click's parameter names), without its input and ``--out``."""
    identity: Mapping[str, Any]
    """What makes its output folder complete for this run (:func:`done_identity`); the done marker holds it."""


def is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def collect_inputs(job: Job, inputs: Sequence[str], manifest: Path | None) -> list[BatchInput]:
    """The inputs named on the command line (files, folders of files with the job's suffixes, glob patterns)
    and in ``manifest``, in that order, without repeats."""
    found: list[BatchInput] = []
    for text in inputs:
        path = Path(text)
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith(".")
                           and p.suffix.lower() in job.suffixes and p.name != REPORT_FILE)
            if not files:
                raise BatchError(f"{text}: the folder holds no {job.name} input ({', '.join(job.suffixes)} files).")
            found += [BatchInput(p.resolve(), where=text) for p in files]
        elif path.exists():
            found.append(BatchInput(path.resolve(), where=text))
        elif is_glob(text):
            files = sorted(Path(p) for p in glob.glob(text, recursive=True) if Path(p).is_file())
            if not files:
                raise BatchError(f"{text}: the pattern matches no file.")
            found += [BatchInput(p.resolve(), where=text) for p in files]
        else:
            raise BatchError(f"{text}: no such file or folder.")
    if manifest is not None:
        found += read_manifest(manifest)
    if not found:
        raise BatchError("no inputs: give files, folders or glob patterns, or --manifest FILE.")
    unique: dict[Path, BatchInput] = {}
    for item in found:
        unique.setdefault(item.source, item)
    return list(unique.values())


def read_manifest(path: Path) -> list[BatchInput]:
    """A manifest's inputs (module docstring); each must exist."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise BatchError(f"--manifest {path}: {exc.strerror or exc}.") from None
    if not path.is_file():
        raise BatchError(f"--manifest {path}: not a file.")
    if size > MAX_MANIFEST_BYTES:
        raise BatchError(f"--manifest {path}: {size} bytes; a manifest is at most {MAX_MANIFEST_BYTES} bytes.")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise BatchError(f"--manifest {path}: not UTF-8 text.") from None
    base = path.resolve().parent
    if path.suffix.lower() == ".json":
        return _json_manifest(path, text, base)
    items = []
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        items.append(_manifest_item(path, f"line {number}", line, None, (), base))
    if not items:
        raise BatchError(f"--manifest {path}: no input lines.")
    return items


def _json_manifest(path: Path, text: str, base: Path) -> list[BatchInput]:
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise BatchError(f"--manifest {path}: invalid JSON ({exc}).") from None
    entries = data.get("inputs") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise BatchError(f'--manifest {path}: expected {{"inputs": [path or {{"path", "name", "args"}}, ...]}} '
                         "with at least one input.")
    items = []
    for i, entry in enumerate(entries):
        where = f"inputs[{i}]"
        if isinstance(entry, str):
            entry = {"path": entry}
        if not isinstance(entry, dict) or not isinstance(entry.get("path"), str) or not entry["path"].strip():
            raise BatchError(f"--manifest {path}: {where}: expected a path or an object with a \"path\" string.")
        unknown = sorted(set(entry) - {"path", "name", "args"})
        if unknown:
            raise BatchError(f"--manifest {path}: {where}: unknown key(s) {unknown}; allowed: path, name, args.")
        name, args = entry.get("name"), entry.get("args", [])
        if name is not None and not isinstance(name, str):
            raise BatchError(f"--manifest {path}: {where}.name: expected a string.")
        if not isinstance(args, list) or not all(isinstance(a, str) for a in args):
            raise BatchError(f"--manifest {path}: {where}.args: expected a list of strings (the job's options).")
        items.append(_manifest_item(path, where, entry["path"], name, tuple(args), base))
    return items


def _manifest_item(manifest: Path, where: str, text: str, name: str | None, args: tuple[str, ...],
                   base: Path) -> BatchInput:
    source = Path(text) if Path(text).is_absolute() else base / text
    if not source.exists():
        raise BatchError(f"--manifest {manifest} {where}: {text}: no such file or folder.")
    if name is not None:
        check_name(name, f"--manifest {manifest} {where}: name")
    return BatchInput(source.resolve(), name, args, base, f"{manifest} {where}")


def check_name(name: str, what: str) -> str:
    """``name`` when it is usable as one output folder's name."""
    if not name or name in (".", "..") or "/" in name or "\\" in name or name.startswith(".") or "\0" in name \
            or name == REPORT_FILE or len(name.encode()) > 200:
        raise BatchError(f"{what} {name!r} is not a folder name (no '/', not hidden, at most 200 bytes).")
    return name


def output_names(sources: Sequence[Path]) -> list[str]:
    """One folder name per input: the file's stem; inputs whose stems collide are named by their folders
    relative to their common folder (``clip_a/results.pkl`` -> ``clip_a``) when their file names agree, else
    by their relative paths (``a/x.npz`` -> ``a__x``); a remaining clash keeps the suffix (``x.npz`` -> ``x_npz``)."""
    stems = [_safe(s.stem or s.name) for s in sources]
    names = list(stems)
    clashing = [i for i, s in enumerate(stems) if stems.count(s) > 1]
    if clashing:
        common = Path(os.path.commonpath([str(sources[i].parent) for i in clashing]))
        same_file = len({sources[i].name for i in clashing}) == 1
        for i in clashing:
            rel = sources[i].parent.relative_to(common)
            parts = [*rel.parts] if same_file and rel.parts else [*rel.parts, sources[i].stem]
            names[i] = _safe("__".join(parts))
    clashing = [i for i, name in enumerate(names) if names.count(name) > 1]
    for i in clashing:
        names[i] = _safe(f"{names[i]}_{sources[i].suffix.lstrip('.')}" if sources[i].suffix else names[i])
    seen: dict[str, int] = {}
    for i, name in enumerate(names):  # still equal (x.npz and x.npz under other names): number them
        if name in seen:
            seen[name] += 1
            names[i] = f"{name}_{seen[name]}"
        else:
            seen[name] = 0
    return names


def _safe(text: str) -> str:
    text = re.sub(r"[^A-Za-z0-9._+-]", "_", text).lstrip(".") or "input"
    return text if text != REPORT_FILE else "input_" + text


# --------------------------------------------------------------------------------------------- job options


def job_command(job: Job) -> Any:
    """The click command of ``job`` (loaded as ``smplik`` loads it; its module imports nothing heavy)."""
    from smplik.cli.tree import click_command
    from workflows.batch.jobs import JOB_COMMANDS

    command = click_command(JOB_COMMANDS[job.command[0]](), job.command[0])
    for word in job.command[1:]:
        command = command.commands[word]
    if getattr(command, "commands", None):  # a group of one command (invert-shape's typer app)
        command = next(iter(command.commands.values()))
    return command


def parse_job_options(job: Job, args: Sequence[str], source: Path, *, base: Path | None = None,
                      common: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The job command's parameters for ``args`` (its options) on the input ``source``: click's values by
    parameter name (the input and ``--out`` left out), checked as the command checks them before its work.
    Path options are made absolute: relative to ``base`` for the values that differ from ``common`` (the raw
    values of the batch's common options, :func:`raw_job_options`: a manifest input's own options), else to the
    current folder. Options naming a file to write (``--preview``, ``--render``) must be bare file names: each
    input's folder gets one."""
    params = raw_job_options(job, args, source)
    for name, value in params.items():
        if isinstance(value, Path) and name not in job.output_files and not value.is_absolute():
            own = common is not None and common.get(name) != value
            params[name] = ((base if own and base is not None else Path.cwd()) / value).resolve()
    try:
        check_options(job.name, params)
    except click_exception() as exc:
        raise BatchError(f"{job.name} options: {' '.join(exc.format_message().split())}") from None
    return params


def click_exception() -> type:
    """The ``ClickException`` of the click that typer runs on (typer may vendor its own copy of click)."""
    import typer

    return next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")


def raw_job_options(job: Job, args: Sequence[str], source: Path) -> dict[str, Any]:
    """The job command's parameters for ``args`` as its click parser gives them (paths as given)."""
    import typer

    if "--help" in args:
        raise BatchError(f"{job.name} options: --help is not a job option here; see "
                         f"'smplik {' '.join(job.command)} --help'.")
    command = job_command(job)
    words = [str(source), "--out", _PLACEHOLDER_OUT, *args]
    try:
        ctx = command.make_context(" ".join(("smplik", *job.command)), words, resilient_parsing=False)
    except typer.Exit:  # an eager option that exits (none but --help today)
        raise BatchError(f"{job.name} options {list(args)}: not options to run with.") from None
    except click_exception() as exc:
        raise BatchError(f"{job.name} options: {' '.join(exc.format_message().split())}") from None
    params = dict(ctx.params)
    if str(params.pop("out")) != _PLACEHOLDER_OUT:
        raise BatchError(f"{job.name} options: --out is the batch's own option (one folder per input under it); "
                         "give it before '--'.")
    params.pop(job.input_param)
    for name in job.output_files:
        value = params.get(name)
        if value is not None and (Path(value).name != str(value) or str(value) in ("", ".", "..")):
            option = "--render" if name == "render_png" else f"--{name.replace('_', '-')}"
            raise BatchError(f"{job.name} options: {option} {value}: give a file name; each input's folder gets "
                             "one (a path is not allowed).")
    return params


def canonical(params: Mapping[str, Any]) -> dict[str, Any]:
    """``params`` as plain JSON values (paths as strings, enums as their values), keys sorted."""
    def plain(v: Any) -> Any:
        if isinstance(v, enum.Enum):
            return v.value
        if isinstance(v, Path):
            return str(v)
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v

    return {k: plain(params[k]) for k in sorted(params)}


# --------------------------------------------------------------------------------------------- complete outputs


def done_identity(job: str, source: Path, params: Mapping[str, Any]) -> dict[str, Any]:
    """What a complete output folder was made from: the job, the input (its path, size and modification
    time) and the options. A rerun skips an input whose folder's done marker holds the same."""
    info = source.stat()
    options = canonical(params)
    digest = hashlib.sha256(json.dumps(options, sort_keys=True).encode()).hexdigest()[:16]
    return {"job": job, "input": str(source), "input_size": info.st_size, "input_mtime_ns": info.st_mtime_ns,
            "options": options, "options_sha256": digest}


def read_done(folder: Path) -> dict[str, Any] | None:
    """The done marker of an output folder, or None when absent or unreadable."""
    try:
        data = json.loads((folder / DONE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) and data.get("format") == DONE_FORMAT else None


def is_complete(folder: Path, identity: Mapping[str, Any]) -> dict[str, Any] | None:
    """The done marker when ``folder`` is complete for ``identity`` (the marker matches, and every output it
    lists is there), else None."""
    done = read_done(folder)
    if done is None or any(done.get(k) != v for k, v in identity.items()):
        return None
    outputs = done.get("outputs")
    if not isinstance(outputs, list) or not all(isinstance(o, str) and (folder / o).is_file() for o in outputs):
        return None
    return done


def tidy_leftovers(out: Path, names: Sequence[str]) -> None:
    """Leftovers of a batch that was killed (SIGKILL, a power cut) for these names: a half-written
    ``.NAME.partial-*`` folder is removed; a ``.NAME.old-*`` folder (a complete output moved aside just before
    its replacement was renamed into place) is put back when ``NAME`` is missing, else removed."""
    import shutil

    wanted = set(names)
    try:
        entries = list(out.iterdir())
    except OSError:
        return
    for entry in sorted(entries):
        m = _TEMP_NAME.match(entry.name)
        if m is None or m["name"] not in wanted or not entry.is_dir():
            continue
        final = out / m["name"]
        if ".old-" in entry.name and not final.exists():
            os.rename(entry, final)
        else:
            shutil.rmtree(entry, ignore_errors=True)


def plan_tasks(job: Job, items: Sequence[BatchInput], out: Path, args: Sequence[str]) -> list[BatchTask]:
    """One task per input: its output folder name, its parsed options, its done identity."""
    out = out.resolve()
    names = output_names([i.source for i in items])
    names = [item.name if item.name is not None else name for item, name in zip(items, names, strict=True)]
    seen: dict[str, BatchInput] = {}
    for item, name in zip(items, names, strict=True):
        if name in seen:
            raise BatchError(f"{seen[name].source} and {item.source} would both write {out / name}; give them "
                             "different names in a JSON manifest.")
        seen[name] = item
    common = parse_job_options(job, args, items[0].source)
    raw_common = raw_job_options(job, args, items[0].source) if any(item.args for item in items) else {}
    tasks = []
    for item, name in zip(items, names, strict=True):
        if item.args:
            try:
                params = parse_job_options(job, [*args, *item.args], item.source, base=item.base,
                                           common=raw_common)
            except BatchError as exc:
                raise BatchError(f"{item.where}: {exc}") from None
        else:
            params = common
        tasks.append(BatchTask(job.name, str(item.source), name, str(out / name), params,
                               done_identity(job.name, item.source, params)))
    return tasks


def job_by_name(name: str) -> Job:
    if name not in JOBS:
        raise BatchError(f"unknown job {name!r}; choose one of: {', '.join(JOBS)}.")
    return JOBS[name]
