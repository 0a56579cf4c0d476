"""Outputs never touch inputs, and a multi-file output is all-new or all-old.

Two helpers every writing command shares:

* :func:`check_writes` compares every file a command will write (the files *inside* ``--out`` too:
  ``animation.json``, ``person_0.bvh``, ``variant_0.json``, ``scene.json``, ...) with every file it read or
  will read (the recording, the character, a scene's skeleton and image files, the model file), through
  symlinks and hard links (:func:`os.path.samefile`, else the resolved paths), and refuses with one
  :class:`OutputPathError` line naming both files.
* :func:`staged_folder` writes a command's files into a temporary sibling folder
  (``.OUT.smplik-PID-XXXXXXXX.tmp`` next to ``OUT``: relative paths from it reach the same files as from
  ``OUT``) and moves them into ``OUT`` only when the command succeeded:

  - a run that fails (an error, Ctrl-C) removes the temporary folder and every folder it created, so nothing
    is written and no empty ``OUT`` is left;
  - when ``OUT`` did not exist, the temporary folder is renamed to ``OUT`` (one atomic rename);
  - when it exists, every other file of ``OUT`` is hard-linked into the temporary folder, which then trades
    places with ``OUT`` in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``): a process killed at any
    moment leaves ``OUT`` all-old or all-new;
  - where that swap is not possible (another system or file system, ``OUT`` a symlink or over
    :data:`MAX_SWAP_ENTRIES` entries), the old files about to be replaced are hard-linked into the temporary
    folder, a commit journal is written, then the new files are renamed in one by one; an exception in between
    puts the old files back. A process killed (SIGKILL) during those renames leaves the journal: the next
    staged write to ``OUT`` (any command writing there) finishes the move first (roll forward: every new
    file is complete before the journal is written), so the folder ends all-new; one killed before the
    journal leaves ``OUT`` all-old and its temporary folder is removed by the next write.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

JOURNAL = ".smplik-commit.json"
"""The commit journal inside a temporary folder: the relative names being moved into ``OUT``."""
_BACKUP = ".smplik-old"
_STAGE_NAME = re.compile(r"^\.(?P<name>.+)\.smplik-(?P<pid>\d+)-[A-Za-z0-9_]{8}\.tmp$")
_TEST_HOOK = "_SMPLIK_TEST_COMMIT_HOOK"
"""Tests only: ``POINT:PATH``; at the commit point ``POINT`` (``swap``: the mirror made, before the folder swap;
``swapped``: after it; ``moved``: the journaled commit's first file moved) the file ``PATH`` is created and the
process waits for it to be removed, so a test can SIGKILL it there (a deterministic point)."""


class OutputPathError(ValueError):
    """An output path that would overwrite one of the command's inputs (or a folder in the way)."""


def _same(write: Path, read: Path) -> bool:
    try:
        if write.exists() and read.exists():
            return os.path.samefile(write, read)
        return write.resolve() == read.resolve()
    except (OSError, ValueError, RuntimeError):
        return False


def check_writes(writes: Iterable[str | Path], reads: Iterable[str | Path | None], *,
                 allow: Iterable[str | Path] = ()) -> None:
    """Raise :class:`OutputPathError` when a file of ``writes`` is one of ``reads`` (``None`` items ignored).

    ``allow``: inputs a command edits in place by design (``scene edit-keyframe`` without ``--out``), which
    may be written."""
    allowed = [Path(a) for a in allow]
    read_paths = [Path(r) for r in reads if r is not None and str(r)]
    read_paths = [r for r in read_paths if not any(_same(r, a) for a in allowed)]
    for w in writes:
        w = Path(w)
        for r in read_paths:
            if _same(w, r):
                raise OutputPathError(f"{w} would overwrite the input {r}: refusing to overwrite an input; give "
                                      "another output folder or file.")


def _files_under(root: Path) -> list[Path]:
    """Relative paths of the files under ``root`` (the backup folder and journal excluded), sorted."""
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = [d for d in dirnames if not (Path(dirpath) == root and d == _BACKUP)]
        for f in filenames:
            rel = (Path(dirpath) / f).relative_to(root)
            if rel != Path(JOURNAL):
                found.append(rel)
    return sorted(found)


def _move_in(stage: Path, out: Path, names: Iterable[str]) -> None:
    for name in names:
        src = stage / name
        if src.exists():
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, out / name)


def recover_stale_stages(out_dir: str | Path) -> list[Path]:
    """Finish or drop the temporary folders left next to ``out_dir`` by killed writers (module docstring);
    returns the folders handled. Folders of a live process are left alone."""
    from smplik.atomic import process_alive  # lazy: smplik.atomic imports numpy, --help must not
    out = Path(os.path.abspath(out_dir))
    handled: list[Path] = []
    candidates = []
    for folder in (out.parent, out):  # next to OUT, or inside it (a parent we cannot write)
        with contextlib.suppress(OSError):
            candidates += list(folder.glob(f".{_glob_escape(out.name)}.smplik-*.tmp"))
    for stage in candidates:
        m = _STAGE_NAME.match(stage.name)
        if m is None or m["name"] != out.name or not stage.is_dir() or process_alive(int(m["pid"])):
            continue
        journal = stage / JOURNAL
        with contextlib.suppress(OSError, ValueError):
            if journal.is_file() and out.is_dir():  # killed mid-commit: every new file is complete, finish
                _move_in(stage, out, json.loads(journal.read_text("utf-8")))
        shutil.rmtree(stage, ignore_errors=True)
        handled.append(stage)
    return handled


def _glob_escape(name: str) -> str:
    import glob

    return glob.escape(name)


class Stage:
    """The temporary folder of :func:`staged_folder`: write into :attr:`dir`; :meth:`final` names a file's
    place in ``OUT``; :meth:`add_reads` adds input files discovered during the work (a scene's skeletons)."""

    def __init__(self, out: Path, dir: Path, reads: list[Path], allow: list[Path]) -> None:
        self.out, self.dir, self.reads, self.allow = out, dir, reads, allow

    def add_reads(self, *paths: str | Path | None) -> None:
        self.reads.extend(Path(p) for p in paths if p is not None and str(p))

    def final(self, path: str | Path) -> Path:
        """``path`` (inside :attr:`dir`) -> where it lands in ``OUT``; other paths unchanged."""
        path = Path(path)
        try:
            return self.out / path.relative_to(self.dir)
        except ValueError:
            return path

    def check(self, names: Iterable[str | Path]) -> None:
        """:func:`check_writes` for files ``names`` (relative to ``OUT``) before they are made."""
        check_writes([self.out / n for n in names], self.reads, allow=self.allow)


def _check_out_folder(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise OutputPathError(f"{out}: exists and is not a folder; give an output folder.")
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise NotADirectoryError(errno.ENOTDIR, f"{parent} is a file, not a folder", str(out))
            break


@contextlib.contextmanager
def staged_folder(out_dir: str | Path, *, reads: Iterable[str | Path | None] = (),
                  allow: Iterable[str | Path] = ()) -> Iterator[Stage]:
    """Yield a :class:`Stage` whose folder replaces/fills ``out_dir`` when the block succeeds (module
    docstring); ``reads``: the command's input files, checked against every file written (more with
    :meth:`Stage.add_reads`)."""
    given = Path(out_dir)
    out = Path(os.path.abspath(given))  # "." and ".." resolved (not symlinks): the sibling has a name
    _check_out_folder(out)
    recover_stale_stages(out)
    created: list[Path] = []
    for parent in reversed(out.parents):  # the missing folders above OUT, made now, removed on failure
        if not parent.exists():
            parent.mkdir()
            created.append(parent)
    prefix = f".{out.name}.smplik-{os.getpid()}-"
    try:
        stage_dir = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=out.parent))
    except PermissionError:  # OUT's parent is not ours (``--out .`` in a home folder): stage inside OUT
        if not out.is_dir():
            raise
        stage_dir = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=out))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(stage_dir, 0o777 & ~umask)
    stage = Stage(given, stage_dir, [Path(r) for r in reads if r is not None and str(r)], [Path(a) for a in allow])
    try:
        yield stage
        names = _files_under(stage_dir)
        if not names:  # nothing written: no (empty) folder either
            raise _NothingWritten
        stage.check(names)
        for n in names:
            if (out / n).is_dir():
                raise OutputPathError(f"{out / n}: is a folder; cannot write the file {n} there.")
        _commit(stage_dir, out, [str(n) for n in names])
    except BaseException as exc:
        shutil.rmtree(stage_dir, ignore_errors=True)
        for folder in reversed(created):
            with contextlib.suppress(OSError):
                folder.rmdir()
        if not isinstance(exc, _NothingWritten):
            raise


class _NothingWritten(Exception):
    """A staged block that wrote no file (nothing to commit)."""


MAX_SWAP_ENTRIES = 10_000
"""Most entries of an existing ``OUT`` (files and folders, recursively) mirrored for an atomic folder swap; a
larger folder (``--out .`` in a home folder) gets the journaled file-by-file commit."""
_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap the folders ``a`` and ``b`` in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``); False where
    the system or the file system cannot."""
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0


def _mirror_others(stage: Path, out: Path, names: list[str]) -> bool:
    """Hard-link every file of ``out`` that the command does not replace into ``stage`` (folders recreated), so
    that ``stage`` is the whole new ``out``; False when that is not possible (too many entries, a link that cannot
    be made, a special file)."""
    new = set(names)
    count = 0
    for dirpath, dirnames, filenames in os.walk(out):
        rel_dir = Path(dirpath).relative_to(out)
        for d in dirnames:
            count += 1
            if Path(dirpath, d).is_symlink():
                return False
            (stage / rel_dir / d).mkdir(exist_ok=True)
        for f in filenames:
            count += 1
            if count > MAX_SWAP_ENTRIES:
                return False
            rel = str(rel_dir / f) if str(rel_dir) != "." else f
            if rel in new:
                continue
            try:
                os.link(Path(dirpath, f), stage / rel, follow_symlinks=False)
            except OSError:
                return False
    return True


def _commit(stage: Path, out: Path, names: list[str]) -> None:
    if not out.exists():
        try:
            os.rename(stage, out)  # one atomic step: OUT appears whole
            return
        except OSError:
            out.mkdir(parents=True, exist_ok=True)
    if stage.parent == out.parent and not out.is_symlink() and _mirror_others(stage, out, names):
        with contextlib.suppress(OSError):
            shutil.copystat(out, stage)  # OUT keeps its mode
        _test_pause("swap")
        if _exchange(stage, out):  # one atomic step: OUT is all-new (its other files kept, as links)
            _test_pause("swapped")
            shutil.rmtree(stage, ignore_errors=True)  # now the old folder
            return
        for name in _files_under(stage):  # the mirror is not used: drop the links again
            if str(name) not in names:
                (stage / name).unlink(missing_ok=True)
    backup = stage / _BACKUP
    old = [n for n in names if (out / n).is_file()]
    for n in old:  # the files about to be replaced, kept until every new file is in
        (backup / n).parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(out / n, backup / n)
        except OSError:
            shutil.copy2(out / n, backup / n)
    journal = stage / JOURNAL
    tmp = stage / (JOURNAL + ".tmp")
    tmp.write_text(json.dumps(names), "utf-8")
    os.replace(tmp, journal)  # from here a killed commit is finished by the next writer
    moved: list[str] = []
    try:
        for i, n in enumerate(names):
            (out / n).parent.mkdir(parents=True, exist_ok=True)
            os.replace(stage / n, out / n)
            moved.append(n)
            if i == 0:
                _test_pause("moved")
    except BaseException:
        journal.unlink(missing_ok=True)
        for n in moved:  # put the old files back (new files that replaced nothing are removed)
            if (backup / n).exists():
                os.replace(backup / n, out / n)
            else:
                (out / n).unlink(missing_ok=True)
        raise
    shutil.rmtree(stage, ignore_errors=True)


def _test_pause(point: str) -> None:
    hook = os.environ.get(_TEST_HOOK, "")
    if not hook.startswith(point + ":"):
        return
    import time

    flag = Path(hook[len(point) + 1:])
    flag.write_text(str(os.getpid()))
    while flag.exists():  # the test kills us here
        time.sleep(0.01)
