"""Where ``smplik batch`` runs its inputs: a local process pool, or Ray actors (local or on a cluster).

Both engines run the same worker code: :func:`init_worker` (one thread, the job's model loaded once) and
:func:`run_task` (one input into a temporary folder beside its output folder, renamed into place when the job
succeeded; removed when it failed). So the same inputs give the same files on both engines.

A worker's state is this module's :data:`_STATE` (a process pool's worker or a Ray actor is one process).
"""

from __future__ import annotations

import os
import secrets
import shutil
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workflows.batch.plan import DONE_FILE, DONE_FORMAT, BatchTask

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")
"""Set to 1 in every worker before torch, numpy or numba load: one thread per worker, whatever the engine."""


@dataclass(frozen=True)
class InputResult:
    """One input's outcome (a row of ``batch_report.json``)."""

    input: str
    name: str
    status: str
    """``done``, ``failed`` or ``skipped`` (complete from an earlier run)."""
    error: str | None = None
    """The one-line error of a failed input."""
    seconds: float = 0.0
    outputs: tuple[str, ...] = ()
    """The files written, relative to the input's output folder (the done marker last)."""
    notes: tuple[str, ...] = ()
    """What the command would have printed: notes and warnings about the input."""
    traceback: str | None = None
    """A failure that is not a user error (a bug): its traceback."""
    fatal: bool = field(default=False, compare=False)
    """The worker could not load the job's model: the batch stops."""

    def to_dict(self) -> dict[str, Any]:
        row = {"input": self.input, "name": self.name, "status": self.status, "error": self.error,
               "seconds": round(self.seconds, 4), "outputs": list(self.outputs), "notes": list(self.notes)}
        if self.traceback is not None:
            row["traceback"] = self.traceback
        return row


_STATE: dict[str, Any] = {"models": {}, "errors": {}}


def one_thread() -> None:
    """One thread for this worker (torch, OpenMP, BLAS, numba)."""
    for name in THREAD_VARIABLES:
        os.environ[name] = "1"
    import torch

    torch.set_num_threads(1)


def init_worker(job: str, params: dict[str, Any], *, ignore_interrupt: bool = False) -> None:
    """A worker's start: one thread; the job's model for the batch's common options loaded (an error is kept
    and reported with the first input, which stops the batch). ``ignore_interrupt``: Ctrl-C is the driver's
    (a pool's workers share the terminal's process group; the driver stops them)."""
    if ignore_interrupt:
        import signal

        signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_thread()
    from workflows.batch.jobs import model_key

    key = model_key(job, params)
    _STATE["common_key"] = key
    if key is not None:
        try:
            _model(key)
        except Exception:  # kept in _STATE["errors"]: the first input reports it
            pass


def _model(key: tuple) -> Any:
    from workflows.batch.jobs import load_model

    models, errors = _STATE["models"], _STATE["errors"]
    if key in errors:
        raise errors[key]
    if key not in models:
        try:
            models[key] = load_model(key)
        except Exception as exc:
            errors[key] = exc
            raise
    return models[key]


def _error_line(exc: BaseException) -> tuple[str, str | None]:
    """(one-line error, traceback or None): a user error's line, else the exception's type and message."""
    from smplik.cli.errors import error_message, is_user_error
    from workflows.batch.plan import click_exception

    if isinstance(exc, click_exception()):
        return " ".join(exc.format_message().split()), None
    if is_user_error(exc) or isinstance(exc, ValueError):
        return error_message(exc), None
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text, "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))


def _files(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def replace_folder(tmp: Path, final: Path) -> None:
    """Put the complete folder ``tmp`` at ``final``: a folder already there is moved aside first and removed
    after (:func:`workflows.batch.plan.tidy_leftovers` puts it back if the process dies in between)."""
    old = None
    if final.is_symlink() or final.exists():
        if not final.is_dir() or final.is_symlink():
            raise FileExistsError(17, "is in the way of the input's output folder (not a folder)", str(final))
        old = final.parent / f".{final.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
        os.rename(final, old)
    os.rename(tmp, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def run_task(task: BatchTask) -> InputResult:
    """Run one input into its output folder, atomically: the job writes into ``.NAME.partial-PID-XXXX`` beside
    it; the done marker is written last; the folder is renamed into place. A failure leaves no folder (an earlier
    complete one stays) and becomes the result's one-line error; only Ctrl-C propagates."""
    import json
    import warnings

    from workflows.batch.jobs import model_key, run_job

    start = time.perf_counter()
    final = Path(task.out_dir)
    tmp = final.parent / f".{final.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
    key = model_key(task.job, task.params)
    fatal = key is not None and key == _STATE.get("common_key") and key in _STATE["errors"]
    try:
        model = None if key is None else _model(key)
        tmp.mkdir(parents=True)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = run_job(task.job, model, Path(task.source), tmp, task.params)
        notes = (*result.notes, *(f"warning: {w.message}" for w in caught))
        outputs = _files(tmp)
        done = {"format": DONE_FORMAT, "version": 1, **task.identity, "outputs": outputs}
        (tmp / DONE_FILE).write_text(json.dumps(done, indent=2) + "\n", encoding="utf-8")
        replace_folder(tmp, final)
        return InputResult(task.source, task.name, "done", seconds=time.perf_counter() - start,
                           outputs=(*outputs, DONE_FILE), notes=tuple(dict.fromkeys(notes)))
    except KeyboardInterrupt:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    except Exception as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        line, trace = _error_line(exc)
        return InputResult(task.source, task.name, "failed", line, time.perf_counter() - start, traceback=trace,
                           fatal=fatal)


def warm_params(tasks: Sequence[BatchTask]) -> tuple[str, dict[str, Any]]:
    """(job, options) whose model every worker loads when it starts: those of the most inputs (a manifest's
    per-input options may name another model, loaded when an input needs it)."""
    from collections import Counter

    from workflows.batch.jobs import model_key

    keys = [model_key(t.job, t.params) for t in tasks]
    common = Counter(keys).most_common(1)[0][0]
    task = tasks[keys.index(common)]
    return task.job, dict(task.params)


def died(task: BatchTask, how: str) -> InputResult:
    """The result of an input whose worker process died under it (killed, out of memory, a crash)."""
    return InputResult(task.source, task.name, "failed",
                       f"the worker process died while running this input or one beside it ({how}); rerun to retry")


OnResult = Callable[[InputResult], None]


# --------------------------------------------------------------------------------------------- local engine


def run_local(tasks: Sequence[BatchTask], workers: int, on_result: OnResult) -> None:
    """Run ``tasks`` on a pool of ``workers`` processes (started fresh, ``spawn``; at most one input each at a
    time). A worker that dies fails the inputs in flight and the pool is started again for the rest."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    if not tasks:
        return
    queue = deque(tasks)
    context = multiprocessing.get_context("spawn")
    while queue:
        pool = ProcessPoolExecutor(max_workers=min(workers, len(queue)), mp_context=context,
                                   initializer=_init_pool_worker, initargs=warm_params(tasks))
        in_flight: dict[Any, BatchTask] = {}
        broken = False
        try:
            while queue or in_flight:
                while queue and len(in_flight) < workers:
                    task = queue.popleft()
                    in_flight[pool.submit(run_task, task)] = task
                finished, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                for future in finished:
                    task = in_flight.pop(future)
                    try:
                        on_result(future.result())
                    except BrokenProcessPool as exc:
                        on_result(died(task, str(exc) or "process pool broken"))
                        broken = True
                if broken:
                    for task in in_flight.values():
                        on_result(died(task, "process pool broken"))
                    in_flight.clear()
                    break
        except BaseException:  # Ctrl-C, or the batch stopped (a model that cannot load): stop the workers now
            _stop_workers(pool)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _init_pool_worker(job: str, params: dict[str, Any]) -> None:
    init_worker(job, params, ignore_interrupt=True)


def _stop_workers(pool: Any) -> None:
    """Terminate a process pool's workers (their half-written ``.partial`` folders are removed by the driver)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=10)


# --------------------------------------------------------------------------------------------- Ray engine


class BatchWorker:
    """A Ray actor: one worker holding the job's model (:func:`init_worker`), running inputs (:func:`run_task`)."""

    def __init__(self, job: str, params: dict[str, Any]) -> None:
        init_worker(job, params)

    def run(self, task: BatchTask) -> InputResult:
        return run_task(task)


def ray_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("ray") is not None


def run_ray(tasks: Sequence[BatchTask], workers: int | None, on_result: OnResult, *,
            address: str | None = None) -> int:
    """Run ``tasks`` on Ray actors (:class:`BatchWorker`, one CPU each, spread over the nodes): connect to
    the cluster at ``address`` (or ``$RAY_ADDRESS``), or use the Ray already started in this process, or start a
    local one with ``workers`` CPUs. ``workers`` actors (default: the cluster's CPUs). An actor that dies fails
    its input and is replaced. Returns the number of actors."""
    import ray

    started = not ray.is_initialized()
    if started:
        joining = address is not None or bool(os.environ.get("RAY_ADDRESS"))  # Ray reads RAY_ADDRESS itself
        ray.init(address=address, num_cpus=None if joining else workers, include_dashboard=False,
                 log_to_driver=False, logging_level="ERROR",
                 runtime_env={"env_vars": dict.fromkeys(THREAD_VARIABLES, "1")})
    try:
        if workers is None:
            workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        workers = max(1, min(workers, len(tasks)))
        actor_class = ray.remote(num_cpus=1, max_restarts=0, scheduling_strategy="SPREAD")(BatchWorker)
        job, params = warm_params(tasks)
        idle = [actor_class.remote(job, params) for _ in range(workers)]
        actors = list(idle)
        try:
            _drive_actors(tasks, idle, actors, lambda: actor_class.remote(job, params), on_result)
        finally:
            for actor in actors:
                ray.kill(actor)
        return workers
    finally:
        if started:
            ray.shutdown()


def _drive_actors(tasks: Sequence[BatchTask], idle: list[Any], actors: list[Any], new_actor: Callable[[], Any],
                  on_result: OnResult) -> None:
    """Feed the idle actors one input each until every input has a result."""
    import ray

    queue = deque(tasks)
    pending: dict[Any, tuple[Any, BatchTask]] = {}
    while queue or pending:
        while idle and queue:
            actor, task = idle.pop(), queue.popleft()
            pending[actor.run.remote(task)] = (actor, task)
        ready, _ = ray.wait(list(pending), num_returns=1)
        actor, task = pending.pop(ready[0])
        try:
            result = ray.get(ready[0])
        except ray.exceptions.RayActorError as exc:
            result = died(task, f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}")
            actor = new_actor()
            actors.append(actor)
        except ray.exceptions.RayTaskError as exc:  # run_task returns failures; this is Ray's own trouble
            result = InputResult(task.source, task.name, "failed", " ".join(str(exc).split())[:500])
        idle.append(actor)
        on_result(result)
