"""Compression on a Dask cluster: the source whose two passes run as tasks on workers.

:class:`DaskSource` answers what the in-process sources answer (:mod:`.source`), so
:func:`~.core.compress` runs unchanged: the fit, the rate control, the encodes and the
evaluation stay in this process; the decoding and the projection go to the workers.

* **Paths travel, not pixels.**  The BTF object is sent once to every worker: file names,
  directions and sizes (a Bonn ``.btf`` reopens its file there).  Workers read their share
  of the files from storage they share with this machine, so they must see the input at
  the same absolute path.
* **Pass 1** -- one task per shard of samples (:class:`~.projection.WorkPlan`): decode the
  shard and return the stored values of the fitting and evaluation texels and of the error
  curve's sample rows (pure copies; curves are applied here, as in-process).
* **Pass 2** -- one task per (shard, group of texel blocks): decode the shard's tiles, rows
  covering the group only, and return its :class:`~.projection.ShardSums`.  Groups keep a
  task's sums under :data:`TASK_SUM_BYTES` (one group up to 400^2 texels at k = 150).  This
  process adds them to the coefficients per block in shard order
  (:class:`~.projection.ProjectionTotal`), at most a few tasks ahead of that order.

Same pieces, same order: the coefficients -- and the output folder -- are byte-identical
to an in-process run, for any number of workers, and when a killed worker's tasks are run
again (tasks only read files and return values).  Each task first checks that its worker
runs the same usdbtf code and libraries (:func:`usdbtf.cluster.require_environment`).
"""
from __future__ import annotations

import os
from collections import deque

import numpy as np

from ..cluster import POLL, environment, require_environment, session
from ..errors import IOFailure, UsageError
from ..manifest import outside_paths_allowed, outside_paths_are_allowed
from ..model import ArrayBTF, BTF, FileBTF
from ..progress import Progress, bar as progress_bar
from .projection import ProjectionTotal, ShardSums, TileProjector, WorkPlan
from .source import _KeptSource, _Source, kept_values

__all__ = ["DaskSource", "TASK_SUM_BYTES", "texel_groups"]

#: Largest shard sums (k x 3 n float32) one projection task holds and returns.
TASK_SUM_BYTES = 512e6


def texel_groups(plan: WorkPlan, k: int, limit: float | None = None) -> list[list[tuple[int, int]]]:
    """The plan's blocks in consecutive groups whose sums (k x 3 n float32) stay under ``limit``
    bytes (default :data:`TASK_SUM_BYTES`; at least one block each)."""
    limit = TASK_SUM_BYTES if limit is None else limit
    per_texel = max(1, k) * 3 * 4
    groups, current, size = [], [], 0
    for a, b in plan.blocks():
        if current and size + (b - a) * per_texel > limit:
            groups.append(current)
            current, size = [], 0
        current.append((a, b))
        size += (b - a) * per_texel
    return groups + [current]


# -- on the workers ------------------------------------------------------------------------------
class _Job:
    """What every task of one compress needs on a worker: the BTF (file names, not pixels), the
    manifest confinement flag, the environment the worker must match.  Held on the cluster
    as a task's result (:meth:`DaskSource._held`), fetched once per worker."""

    def __init__(self, btf: BTF, outside: bool, env: dict):
        self.btf, self.outside, self.env = btf, outside, env

    def checked(self, what: str) -> BTF:
        require_environment(self.env, f"{_worker_name()} ({what})")
        return self.btf

    def read(self, a: int, b: int, rows=None) -> np.ndarray:
        """Stored values of samples a..b (n, h, W, 3), manifest confinement as on the client."""
        with outside_paths_allowed(self.outside):
            return self.btf.read_encoded(slice(a, b), rows=rows)


def _result(future):
    """``future.result()`` once it is done, waited for in steps of :data:`usdbtf.cluster.POLL`
    seconds: between them the main thread runs a pending signal's handler (see
    :func:`usdbtf.cluster.polled`).  (Not ``result(timeout=...)``: Dask's timed wait can lose
    a result that arrives as it times out.)"""
    import threading

    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    while not done.wait(POLL):
        pass
    return future.result()


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"pid {os.getpid()}"


def _identity(value):
    return value


def first_pass_task(job: _Job, a: int, b: int, keep_texels: list, keep_rows: np.ndarray):
    """Samples a..b: the stored values of each kept texel set ((n, 3 m) per set) and of the
    kept sample rows ({sample: (P, 3)})."""
    job.checked(f"samples {a}..{b}")
    return kept_values(job.read(a, b), a, keep_texels, keep_rows)


def project_task(job: _Job, plan: WorkPlan, u: np.ndarray, mix: np.ndarray, ks, energy: bool, shard: tuple,
                 blocks: list, domain=None) -> ShardSums:
    """One shard's sums over one group of blocks: its tiles in sample order, each decoded
    only over the image rows that hold the group's texels (in the working ``domain``)."""
    btf = job.checked(f"samples {shard[0]}..{shard[1]}")
    decode = _Source(btf)
    if domain is not None:
        decode.set_domain(domain)
    proj = TileProjector(u, mix, ks, decode.curves, plan.tile, energy=energy)
    first, end = blocks[0][0], blocks[-1][1]
    y0, y1 = first // btf.width, -(-end // btf.width)
    rows = None if (y0, y1) == (0, btf.height) else (y0, y1)
    sums = ShardSums(proj, blocks)
    for t0, t1 in plan.tiles(*shard):
        flat = job.read(t0, t1, rows).reshape(t1 - t0, -1)
        off = 3 * (first - y0 * btf.width)
        sums.add_tile(proj, t0, flat[:, off:off + 3 * (end - first)])
    return sums


# -- in this process -----------------------------------------------------------------------------
def _portable(btf: BTF) -> BTF:
    """A shallow copy of ``btf`` that names its files by absolute path (a worker's working
    folder is not this process's); the reader's own pickling sends it."""
    if isinstance(btf, ArrayBTF) or not (isinstance(btf, FileBTF) or getattr(btf, "source", "")):
        raise UsageError("--dask: the input must be files that the workers can read (a manifest, UBO data or a "
                         ".btf file), not an in-memory BTF")
    clone = object.__new__(type(btf))
    clone.__dict__.update(btf.__dict__)
    clone.__dict__.pop("_zip", None)
    if isinstance(btf, FileBTF) and not getattr(btf, "archive", False):
        clone.paths = [os.path.abspath(p) for p in btf.paths]
    if getattr(btf, "source", ""):
        clone.source = os.path.abspath(btf.source)
    return clone


class DaskSource(_KeptSource):
    """The source of :mod:`.source`, with both passes on a Dask cluster (module docstring).

    Parameters
    ----------
    btf : a BTF read from files.
    keep_texels : sorted texel arrays whose columns :meth:`columns` answers.
    keep_rows : sample indices :meth:`working_samples` answers.
    options : ``dask`` (the cluster address), ``progress`` (a bar on stderr).
    """

    kind = "dask"

    def __init__(self, btf: BTF, keep_texels: list, keep_rows, options):
        super().__init__(btf)
        self.progress = bool(getattr(options, "progress", False))
        portable = _portable(btf)        # refuse an in-memory BTF before starting or joining a cluster
        self._session = session(options.dask)
        self.client = self._session.__enter__()
        try:
            n_workers = len(self.client.scheduler_info().get("workers", {}))
            self.in_flight = max(2, n_workers + 1)
            self.kind = f"dask, {n_workers} worker(s)"
            self._job = self._held(_Job(portable, outside_paths_are_allowed(), environment()), "job")
            self._first_pass(keep_texels, keep_rows)
        except BaseException:
            self.close()
            raise

    def _held(self, value, what: str):
        """``value`` on the cluster as the result of a task that returns it: a worker that dies
        loses nothing, the scheduler runs the task again (scattered data would be lost)."""
        return self.client.submit(_identity, value, pure=False, key=f"usdbtf-{what}-{os.urandom(4).hex()}")

    def _bar(self, label: str, total: int) -> Progress:
        """A progress bar of a pass (drawn as :func:`usdbtf.progress.bar` decides: on a
        terminal or with ``usdbtf --progress``, not with ``-q``), or a silent one."""
        return progress_bar(label, total) if self.progress else Progress(label, total, enabled=False)

    def close(self) -> None:
        if self._session is not None:
            session, self._session = self._session, None
            session.__exit__(None, None, None)

    def _first_pass(self, keep_texels: list, keep_rows) -> None:
        keep_texels, keep_rows = self._keep(keep_texels, keep_rows)
        shards = self.plan.shards()
        futures = [self.client.submit(first_pass_task, self._job, a, b, keep_texels, keep_rows, pure=False,
                                      key=f"usdbtf-columns-{a}-{os.urandom(4).hex()}") for a, b in shards]
        bar = self._bar("dask pass 1/2 (fit columns)", len(shards))
        for (a, _), (cols, rows) in zip(shards, self._results(futures, bar)):
            self._store(a, cols, rows)
        bar.finish()

    def _results(self, futures, bar):
        """Each future's result in order (waiting as needed), releasing it once taken."""
        from distributed import KilledWorker

        for n, future in enumerate(futures):
            try:
                result = _result(future)
            except KilledWorker as exc:
                raise IOFailure(f"Dask: the workers running task {exc.task} died, again and again (out of memory? "
                                "see the workers' logs)") from None
            futures[n] = None
            future.release()
            bar.update()
            yield result

    def project(self, u: np.ndarray, mix: np.ndarray, ks, *, energy: bool = False):
        """Pass 2 on the workers; the shard sums are added here in the fixed order."""
        proj = self.projector(u, mix, ks, energy)
        total = ProjectionTotal(proj, self.plan)
        u_remote = self._held(np.ascontiguousarray(u), "basis")
        shards = self.plan.shards()
        # Group-major: each group's shards come in order, so the reduction rarely waits.
        work = [(g, n) for g in texel_groups(self.plan, max(proj.ks)) for n in range(len(shards))]
        bar = self._bar("dask pass 2/2 (projection)", len(work))
        tag = os.urandom(4).hex()
        pending: deque = deque()
        todo = iter(work)

        def submit_next() -> bool:
            item = next(todo, None)
            if item is None:
                return False
            blocks, n = item
            key = f"usdbtf-project-{n}-{blocks[0][0]}-{tag}"
            pending.append((n, self.client.submit(project_task, self._job, self.plan, u_remote, proj.mix, proj.ks,
                                                  energy, shards[n], blocks, self.domain, pure=False, key=key)))
            return True

        for _ in range(self.in_flight):
            submit_next()
        while pending:
            n, future = pending.popleft()
            sums = next(self._results([future], bar))
            total.add(n, sums)
            del sums
            submit_next()
        bar.finish()
        return total.result()

