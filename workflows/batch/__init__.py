"""``smplik batch``: one job (animate, from-estimate, track, invert-shape, export) over many inputs.

* :mod:`workflows.batch.jobs`: the jobs, each an existing command's Python entry point on one input;
* :mod:`workflows.batch.plan`: inputs, manifests, output names, the job's options, complete outputs (light);
* :mod:`workflows.batch.engines`: the workers (a process pool, Ray actors) and one input's atomic run;
* :mod:`workflows.batch.cli`: the command, its report and progress bar.
"""
