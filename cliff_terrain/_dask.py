"""How the core hands tasks to a Dask client, in one place for a season's dates and a mosaic's tiles.

Dask is imported only here and only when called (``distributed`` is the command line's optional
``season`` extra, never the extension's). The clusters themselves are made by
:func:`cliff_terrain.season.cluster.local_cluster`.
"""

from __future__ import annotations

import collections
import itertools
import uuid


def in_order(client, function, arguments, *, ahead):
    """``function(*args)`` of each tuple of `arguments` as tasks on `client`, results in order.

    At most `ahead` tasks are queued beyond the one being taken, so memory here stays a few
    results; a task's exception is raised when its result is taken, as in a loop. Tasks not yet
    taken when the caller stops (or after an exception) are cancelled.
    """
    pending = iter(arguments)
    futures = collections.deque()

    def submit(batch):
        futures.extend(client.submit(function, *args, pure=False) for args in batch)

    submit(itertools.islice(pending, ahead))
    try:
        while futures:
            result = futures.popleft().result()
            submit(itertools.islice(pending, 1))
            yield result
    finally:
        if futures:
            client.cancel(list(futures))


def as_done(client, function, arguments, *, ahead):
    """``function(*args)`` of each tuple of `arguments` as tasks on `client`, results as they finish.

    As :func:`in_order`, at most `ahead` tasks are queued beyond the one being taken, and a task's
    exception is raised when it is taken; but no result waits for the one submitted before it. For
    results placed by what they carry (a window's corner): taken in order, a worker that finished
    its tasks waits for the one still measuring the oldest.
    """
    from distributed import as_completed

    pending = iter(arguments)
    running = set()

    def submit(batch):
        for args in batch:
            future = client.submit(function, *args, pure=False)
            running.add(future)
            done.add(future)

    done = as_completed(loop=client.loop)
    submit(itertools.islice(pending, ahead))
    try:
        for future in done:
            running.discard(future)
            result = future.result()
            submit(itertools.islice(pending, 1))
            yield result
    finally:
        if running:
            client.cancel(list(running))


def as_completed_results(client, function, payloads, finished, *, prefix):
    """``function(payload)`` of each ``(name, payload)`` of `payloads` as one task on `client`, all
    submitted at once; ``finished(index, result)`` as each completes, in any order.

    The task keys are ``{prefix}-{run}-{index}-{name}``, ``run`` new for each call, so that runs
    sharing a scheduler never share a task. A task that fails (its worker died at its memory limit,
    the task was lost) gives ``{"ok": False, "error": ...}`` instead of raising.
    """
    from distributed import as_completed

    futures = {}
    run = uuid.uuid4().hex[:8]
    for index, (name, payload) in enumerate(payloads):
        futures[client.submit(function, payload, key=f"{prefix}-{run}-{index}-{name}", pure=False)] = index
    for future in as_completed(futures, loop=client.loop):
        try:
            result = future.result()
        except Exception as exc:
            result = {"ok": False, "error": f"{type(exc).__name__}: {exc}".replace("\n", " ")}
        finished(futures[future], result)
