"""Where ``reproduce`` trains its models: local processes, a dask or a Ray cluster.

dask.distributed and Ray are optional dependencies, imported only when their
backend is chosen.
"""

from __future__ import annotations

import contextlib
import importlib
import sys

import joblib

__all__ = ["BACKENDS", "add_backend_arguments", "check_backend", "joblib_backend"]

#: joblib backends ``reproduce`` trains the models with.
BACKENDS = ("loky", "dask", "ray")

#: Backend -> (module that must be importable, what the error message says is missing, extra).
_NEEDS = {
    "dask": ("distributed", "dask needs dask.distributed", "dask"),
    "ray": ("ray", "ray needs Ray", "ray"),
}


def add_backend_arguments(parser) -> None:
    """``--backend`` and ``--scheduler``: where the models are trained."""
    group = parser.add_argument_group("cluster", "where the models are trained")
    group.add_argument(
        "--backend", choices=BACKENDS, default="loky",
        help="where the models are trained: local worker processes (loky), or the workers of "
        "a dask.distributed cluster (dask) or a Ray cluster (ray), --n-jobs of them for a local "
        "cluster, all of them with --scheduler; see docs/cluster.rst (default: %(default)s)",
    )
    group.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="with --backend dask: address of a running dask scheduler, e.g. tcp://host:8786; "
        "with --backend ray: address of a running Ray cluster, e.g. auto or ray://host:10001 "
        "(default: start a local cluster of --n-jobs single-threaded worker processes)",
    )


def check_backend(args, parser):
    """Exit with a usage error unless ``--backend`` and ``--scheduler`` can be used together
    and the backend's package is installed."""
    if args.scheduler is not None and args.backend == "loky":
        parser.error("argument --scheduler: only with --backend dask or --backend ray")
    if args.backend in _NEEDS:
        module, missing, extra = _NEEDS[args.backend]
        try:
            importlib.import_module(module)
        except ImportError:
            parser.error(f'argument --backend: {missing}: pip install "skcath[{extra}]"')


@contextlib.contextmanager
def joblib_backend(args, parser):
    """The joblib backend of ``reproduce``: local processes, a dask or a Ray cluster.

    With ``--backend dask``, connects to ``--scheduler`` or starts a local
    cluster of ``--n-jobs`` worker processes of one thread each (each model
    trains with one torch thread), and closes what it opened on exit.
    ``--backend ray`` does the same with Ray.
    """
    if args.backend == "ray":
        with _ray_backend(args, parser):
            yield
        return
    if args.backend != "dask":
        yield
        return
    from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        if args.scheduler is not None:
            try:
                client = stack.enter_context(Client(args.scheduler, timeout="20s"))
            except OSError as exc:
                parser.error(f"argument --scheduler: cannot connect to {args.scheduler!r}: {exc}")
        else:
            n_workers = joblib.effective_n_jobs(args.n_jobs)  # -1: all cores
            cluster = stack.enter_context(
                LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                             dashboard_address=None)
            )
            client = stack.enter_context(Client(cluster))
        n_threads = sum(client.nthreads().values())
        print(f"dask cluster: {client.scheduler.address}, {n_threads} worker threads",
              file=sys.stderr, flush=True)
        stack.enter_context(joblib.parallel_config(backend="dask"))
        yield


@contextlib.contextmanager
def _ray_backend(args, parser):
    """Connect to the Ray cluster at ``--scheduler``, or start a local one of ``--n-jobs`` CPUs."""
    import ray
    from ray.util.joblib import register_ray

    register_ray()
    if args.scheduler is not None:
        try:
            ray.init(address=args.scheduler, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            parser.error(f"argument --scheduler: cannot connect to {args.scheduler!r}: {exc}")
    else:
        ray.init(num_cpus=joblib.effective_n_jobs(args.n_jobs), include_dashboard=False,
                 log_to_driver=False)
    try:
        n_cpus = int(ray.cluster_resources().get("CPU", 0))
        print(f"ray cluster: {n_cpus} CPUs", file=sys.stderr, flush=True)
        with joblib.parallel_config(backend="ray"):
            yield
    finally:
        ray.shutdown()
