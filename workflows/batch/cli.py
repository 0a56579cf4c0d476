"""``smplik batch``: one job over many inputs, one output folder each, a report, resume (docs/batch.md).

Light module: the options, inputs and manifest are checked (one ``error:`` line each) before a worker starts
or torch loads.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from typer.core import TyperCommand

from smplik.cli.errors import say, user_errors
from workflows.batch.jobs import JOBS

ENGINES = ("local", "ray")
JOB_ARGS = "smplik.batch.job_args"
REPORT_EVERY_S = 2.0
"""The report is rewritten at most this often while inputs finish (and always at the end)."""


class BatchCommand(TyperCommand):
    """``smplik batch``'s command: the words after ``--`` are the job's own options (kept apart, unparsed)."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        if "--" in args:
            i = args.index("--")
            ctx.meta[JOB_ARGS] = list(args[i + 1:])
            args = args[:i]
        return super().parse_args(ctx, args)

    def collect_usage_pieces(self, ctx: Any) -> list[str]:
        return [*super().collect_usage_pieces(ctx), "[-- JOB_OPTIONS...]"]


app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)

_JOBS_HELP = "; ".join(f"{job.name}: {job.summary}" for job in JOBS.values())


@app.command("batch", cls=BatchCommand, epilog="The job's own options go after '--', as its command takes them: "
             "smplik batch animate clips/ --out runs -- --smoothing none --export bvh,glb")
def batch_cmd(
    ctx: typer.Context,
    job: Annotated[str, typer.Argument(help=f"The job: {_JOBS_HELP}.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder: one folder per input, and "
                                      "batch_report.json.")],
    inputs: Annotated[list[str] | None, typer.Argument(
        help="Input files, folders (their files of the job's kinds) or quoted glob patterns ('clips/**/*.pkl').")
    ] = None,
    manifest: Annotated[Path | None, typer.Option("--manifest", help="Inputs listed in a file: one path a line, "
                                                  "or JSON with per-input names and options (docs/batch.md).")
                        ] = None,
    engine: Annotated[str, typer.Option("--engine", help="local (a process pool) or ray (Ray actors, local or "
                                        "on a cluster; the ray extra).")] = "local",
    workers: Annotated[int | None, typer.Option("--workers", min=1, help="Worker processes, each holding the "
                                                "job's model, one thread each (default: local: the CPUs; ray: "
                                                "the cluster's CPUs).")] = None,
    address: Annotated[str | None, typer.Option("--address", help="--engine ray: the cluster to join "
                                                "(ray://HOST:10001, HOST:6379 or auto; default: a local Ray).")
                       ] = None,
    force: Annotated[bool, typer.Option("--force", help="Redo inputs whose outputs are complete.")] = False,
) -> None:
    """Run JOB on every input: OUT/NAME/ per input (written atomically, a done marker last), OUT/batch_report.json,
    a progress bar. A failing input never stops the others (exit status 1 with their count); a rerun skips the
    inputs whose outputs are complete for the same job, input and options."""
    from workflows.batch.engines import ray_available
    from workflows.batch.plan import BatchError, collect_inputs, job_by_name, plan_tasks

    job_args = ctx.meta.get(JOB_ARGS, [])
    with user_errors():
        if engine not in ENGINES:
            raise BatchError(f"--engine must be one of {', '.join(ENGINES)}, got {engine!r}.")
        if address is not None and engine != "ray":
            raise BatchError("--address is for --engine ray (the Ray cluster to join).")
        if engine == "ray" and not ray_available():
            raise BatchError("--engine ray needs Ray: pip install 'smplik[ray]'.")
        spec = job_by_name(job)
        if out.exists() and not out.is_dir():
            raise BatchError(f"--out {out}: is a file; give a folder.")
        items = collect_inputs(spec, inputs or [], manifest)
        tasks = plan_tasks(spec, items, out, job_args)
        code = run_batch(tasks, out, engine=engine, workers=workers, address=address, force=force,
                         options=job_args)
    if code:
        raise typer.Exit(code)


def run_batch(tasks: list, out: Path, *, engine: str = "local", workers: int | None = None,
              address: str | None = None, force: bool = False, options: list[str] | None = None) -> int:
    """Run planned tasks (:func:`workflows.batch.plan.plan_tasks`) on ``engine``; write the report; print
    progress and the summary. Returns the exit status: 0, or 1 when an input failed."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from smplik.atomic import write_json_atomic
    from smplik.cli.errors import console, print_error
    from workflows.batch.engines import InputResult, run_local, run_ray
    from workflows.batch.plan import REPORT_FILE, REPORT_FORMAT, BatchError, is_complete, tidy_leftovers

    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    tidy_leftovers(out, [t.name for t in tasks])
    rows: dict[str, InputResult] = {}
    for task in tasks:
        done = None if force else is_complete(Path(task.out_dir), task.identity)
        if done is not None:
            rows[task.name] = InputResult(task.source, task.name, "skipped",
                                          outputs=(*done["outputs"], "batch_done.json"))
    to_run = [t for t in tasks if t.name not in rows]
    if engine == "local":
        workers = min(workers or os.cpu_count() or 1, len(to_run))
    report_path = out / REPORT_FILE
    start = time.perf_counter()
    last_write = [0.0]

    def write_report(final: bool = False) -> None:
        entries = [rows[t.name].to_dict() if t.name in rows else
                   {"input": t.source, "name": t.name, "status": "pending", "error": None, "seconds": 0.0,
                    "outputs": [], "notes": []} for t in tasks]
        counts = {s: sum(e["status"] == s for e in entries) for s in ("done", "skipped", "failed", "pending")}
        write_json_atomic(report_path, {
            "format": REPORT_FORMAT, "version": 1, "job": tasks[0].job, "options": list(options or []),
            "engine": engine, "workers": workers, "address": address, "force": force, "finished": final,
            "seconds": round(time.perf_counter() - start, 3), "counts": counts,
            "inputs": entries})
        last_write[0] = time.monotonic()

    write_report()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    finished = [0]
    with Progress(*columns, console=console, transient=True, disable=not console.is_terminal) as bar:
        progress = bar.add_task(f"batch {tasks[0].job} ({engine})", total=len(to_run))

        def on_result(result: InputResult) -> None:
            if result.fatal:  # no input's fault: the batch stops, its inputs stay pending
                raise BatchError(f"{result.error} (the job's model could not be loaded; batch stopped)")
            rows[result.name] = result
            finished[0] += 1
            bar.update(progress, advance=1)
            if result.status == "failed":
                say(f"failed: {result.name} ({result.input}): {result.error}")
            elif not console.is_terminal:
                say(f"[{finished[0]}/{len(to_run)}] {result.name}: done in {result.seconds:.1f} s")
            if time.monotonic() - last_write[0] > REPORT_EVERY_S:
                write_report()

        try:
            if to_run and engine == "ray":
                workers = run_ray(to_run, workers, on_result, address=address)
            elif to_run:
                run_local(to_run, workers, on_result)
        finally:
            tidy_leftovers(out, [t.name for t in to_run])  # what stopped workers left half-written
            write_report(final=True)
    counts = {s: sum(r.status == s for r in rows.values()) for s in ("done", "skipped", "failed")}
    elapsed = time.perf_counter() - start
    rate = f", {60 * finished[0] / elapsed:.1f} inputs/min" if finished[0] and elapsed > 0 else ""
    say(f"{counts['done']} done, {counts['skipped']} skipped (complete), {counts['failed']} failed of {len(tasks)} "
        f"inputs in {elapsed:.1f} s ({engine}, {workers or 0} worker(s){rate}); report: {report_path}")
    if counts["failed"]:
        print_error(f"{counts['failed']} of {len(tasks)} inputs failed (see {report_path}).")
        return 1
    return 0
