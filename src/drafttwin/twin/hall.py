"""A hall of machines spread over K twins, one Ray actor each (``drafttwin twin hall``).

Each actor is a whole live twin (sources, hybrid, store) over one shard of the mapping's
machines: the source spec gets ``shard=I/K`` (machines at positions I, I+K, ... of the
mapping), so every machine lives, whole and in order, in exactly one actor.

Store: one DuckDB file per shard, ``DIR/shard-I-of-K/twin.duckdb``; ``twin query`` and ``twin
audit`` read them all. Why not one writer actor for all shards: DuckDB allows one writing
process, so a shared store would route every row through that actor (an actor call costs
about 1.4 ms here, research notes), make it a single point of failure for the whole hall, and
make a shard's restart depend on it to find where to resume. A file per shard keeps each
shard's crash and restart to itself (it resumes from its own file, like ``twin run``), needs
no traffic between processes, and a query over K files is a loop. The price: K fixed per
store folder (a machine's history must stay in one file); a hall refuses a folder written
with another K.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import contextlib
import os
import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drafttwin.errors import ConfigError, DrafttwinError
from drafttwin.execution.interrupt import Interrupted
from drafttwin.sliver.levelwatch import SEARCH_MM, WINDOW_M

SHARD_DIR = re.compile(r"^shard-(\d+)-of-(\d+)$")
RESTARTS = 3
"""Times Ray starts a shard again after its process died (an error in the twin is not retried)."""
POLL_S = 0.5
"""How often the driver looks at its actors (and lets Ctrl-C through)."""
STOP_S = 2.0
"""How long a stopped hall waits for its shards to commit before ending the ones still starting."""
STATUS_S = 1.0
"""How long the driver waits for a shard's status (a shard whose process is still starting
answers only once it runs: meanwhile it is 'starting', and a signal is not held up)."""


def shard_dir(store: Path, i: int, k: int) -> Path:
    return store / f"shard-{i}-of-{k}"


def check_store(store: Path, shards: int) -> None:
    """Refuse a store folder a hall of another size wrote (a machine's history in one file)."""
    if (store / "twin.duckdb").exists():
        from drafttwin.twin.store.history import machines_of

        try:
            machines_of(store)  # reads its format record
        except DrafttwinError:  # a DuckDB file of anything else (it read as a twin's store)
            raise ConfigError("this folder holds twin.duckdb, which is not a drafttwin twin "
                              "store", source=store, where="--store",
                              fix="give a new folder to the hall") from None  # fmt: skip
        raise ConfigError("this folder holds the store of a single 'twin run'", source=store,
                          where="--store", fix="give a new folder to the hall")  # fmt: skip
    for p in store.glob("shard-*") if store.is_dir() else []:
        m = SHARD_DIR.match(p.name)
        if m and int(m.group(2)) != shards:
            raise ConfigError(f"this store was written by a hall of {m.group(2)} shards",
                              source=store, where="--shards",
                              fix=f"use --shards {m.group(2)}, or a new --store folder")  # fmt: skip


def shard_source(source: str, i: int, k: int) -> str:
    return f"{source}{'&' if '?' in source else '?'}shard={i}/{k}"


def check_hall(model: Path, source: str, mapping: Path, shards: int) -> int:
    """Check the pieces before any actor starts; returns the number of machines."""
    from drafttwin.twin.build import load_twin_model
    from drafttwin.twin.sources.mapping import MachineMap, read_mapping
    from drafttwin.twin.sources.spec import parse_source

    kind = source.partition(":")[0]
    if kind not in ("opcua", "mqtt", "mqtts"):
        raise ConfigError(f"a hall reads a live server, not {kind!r}", where="--source",
                          fix="give opcua:opc.tcp://HOST:PORT or mqtt://HOST:PORT")  # fmt: skip
    if "shard=" in source:
        raise ConfigError("the hall sets each actor's shard itself", where="--source",
                          fix="drop shard=... from --source")  # fmt: skip
    channels = tuple(load_twin_model(model).channels_)
    mapped = read_mapping(mapping, channels)
    if shards > len(mapped):  # an empty shard: refused here, not in an actor
        raise ConfigError(f"{shards} shards for {len(mapped)} machine(s): a shard would watch "
                          "none", where="--shards",
                          fix=f"use at most {len(mapped)} shards (--mapping's machines)")  # fmt: skip
    try:  # the source as the user wrote it (the shard each actor gets is the hall's)
        parse_source(source, MachineMap("fa320a", channels), mapped)
    except ConfigError as exc:
        if exc.fix_template is not None:
            exc.fix_template = exc.fix_template.replace("shard, ", "")  # not the user's to set
        raise
    for i in range(shards):
        parse_source(shard_source(source, i, shards), MachineMap("fa320a", channels), mapped)
    return len(mapped)


async def _shard_main(shard: Any, duration_s: float | None) -> None:
    """A shard's twin in its loop. Not a method: one ``async def`` on the class makes Ray run
    it as an async actor, whose plain methods share one event loop thread, so ``status()``
    waited behind ``run()`` for the whole run (the hall said "starting" throughout)."""
    shard.loop = asyncio.get_running_loop()
    if shard.stopping.is_set():
        return
    await shard.service.run(duration_s=duration_s)


COMMAND_S = 10.0
"""How long an operator's command may wait for a shard's twin, s."""


class ConsoleLines:
    """What ``twin run`` prints of a shard's events (:func:`~drafttwin.twin.alarms.event_line`:
    alarms, causes, learning, the sliver), numbered, the last :data:`KEEP` kept: the shard's
    status carries them and the hall's console prints those it has not printed."""

    KEEP = 100

    def __init__(self) -> None:
        self.run_id = f"{os.getpid()}-{time.time_ns()}"  # a restarted shard numbers anew
        self.lines: collections.deque[tuple[int, str]] = collections.deque(maxlen=self.KEEP)
        self.seq = 0

    def hook(self, ev: Any) -> None:
        """An event hook of the shard's twin (``TwinService.event_hooks``)."""
        from drafttwin.twin.alarms import event_line

        line = event_line(ev.machine, ev.kind, ev.ts_us, ev.detail)
        if line is not None:
            self.seq += 1
            self.lines.append((self.seq, line))

    def status(self) -> dict[str, Any]:
        return {"run": self.run_id, "lines": [list(x) for x in list(self.lines)]}


class ConsoleFollower:
    """The hall's side: each shard's console lines not printed yet, once each (a shard
    started again by Ray numbers from 1: its run id says so)."""

    def __init__(self) -> None:
        self.printed: dict[int, tuple[str, int]] = {}

    def new_lines(self, statuses: list[dict[str, Any] | None]) -> list[str]:
        out = []
        for i, st in enumerate(statuses):
            console = (st or {}).get("console")
            if not isinstance(console, dict) or not console.get("lines"):
                continue
            run, done = self.printed.get(i, ("", 0))
            if run != console.get("run"):
                run, done = str(console.get("run")), 0
            lines = [(int(seq), str(line)) for seq, line in console["lines"]]
            out += [line for seq, line in lines if seq > done]
            self.printed[i] = (run, max(done, lines[-1][0]))
        return out


def shard_command(service: Any, kind: str, machine: str, args: dict[str, Any]) -> dict[str, Any]:
    """``relearn``, ``acknowledge`` or ``confirm`` (:mod:`drafttwin.twin.commands`, as the
    twin's REST API runs them) as ``{"status": ..., "body": ...}`` for the hall's page."""
    from drafttwin.twin import commands

    try:
        if kind == "relearn":
            body = commands.relearn(service, machine, "operator's command (hall)")
        else:
            body = commands.take_alarms(service, machine, kind, str(args.get("comment", "")),
                                        args.get("alarm"))  # fmt: skip
    except commands.Refused as exc:
        return {"status": exc.status, "body": exc.text}
    return {"status": 200, "body": body}


def _actor_class(ray: Any) -> Any:
    # run() in one thread, status()/stop() beside it. A shard whose process dies is started
    # again and its run() retried (RESTARTS times): the new twin resumes from its own store
    # (and the server's history), as a restarted 'twin run' does
    @ray.remote(num_cpus=1, max_concurrency=2, max_restarts=RESTARTS, max_task_retries=RESTARTS)
    class ShardTwin:
        """One twin over one shard, in its own process."""

        def __init__(self, options: dict[str, Any]) -> None:
            self.options = options
            self.service: Any = None
            self.loop: asyncio.AbstractEventLoop | None = None
            self.stopping = threading.Event()
            self.console = ConsoleLines()

        def run(self, duration_s: float | None) -> dict[str, Any]:
            import torch

            from drafttwin.twin.aio import run_bounded
            from drafttwin.twin.build import build_service

            torch.set_num_threads(1)
            o = self.options
            self.service = build_service(o["model"], [o["source"]], mapping=o["mapping"],
                                         store_dir=o["store"], commit_ms=o["commit_ms"],
                                         physics=o["physics"], silent_s=o["silent_s"],
                                         detector=o["detector"], learn_s=o["learn_s"],
                                         level_window_m=o["level_window_m"],
                                         level_search_mm=o["level_search_mm"])  # fmt: skip
            self.service.event_hooks.append(self.console.hook)
            failed: list[BaseException] = []

            def loop() -> None:  # a thread of its own: Ray's method thread runs its own loop
                try:
                    run_bounded(_shard_main(self, duration_s))
                except BaseException as exc:  # noqa: BLE001  raised again in the method
                    failed.append(exc)

            try:
                thread = threading.Thread(target=loop, name="twin-shard")
                thread.start()
                thread.join()
                if failed:
                    raise failed[0]
            finally:
                if self.service.writer is not None:
                    self.service.writer.close()
                    self.service.writer.store.close()
            return {"source": o["source"], "store_dir": str(o["store"]), **self.service.status()}

        def status(self) -> dict[str, Any] | None:
            """The shard's status: ``loading`` before its twin is built, then ``running`` with
            the twin's status. Read from this thread while the twin's loop runs: a collection
            changing under the read is read again (``None``: it kept changing)."""
            for _ in range(5):
                if self.service is None:
                    return {"state": "loading"}
                try:
                    return {**self.service.status(), "state": "running",
                            "console": self.console.status()}  # fmt: skip
                except RuntimeError:  # "deque mutated during iteration"
                    time.sleep(0.01)
            return None

        def command(self, kind: str, machine: str, args: dict[str, Any]) -> dict[str, Any]:
            """An operator's command on one of this shard's machines, run on its twin's loop
            (:func:`shard_command`): ``{"status": HTTP status, "body": answer or why}``."""
            if self.loop is None or self.service is None:
                return {"status": 503, "body": "the shard's twin is still starting"}
            done: concurrent.futures.Future[dict[str, Any]] = concurrent.futures.Future()

            def run() -> None:  # an unexpected failure is answered, not left to the timeout
                try:
                    done.set_result(shard_command(self.service, kind, machine, args))
                except Exception as exc:  # noqa: BLE001
                    done.set_exception(exc)

            self.loop.call_soon_threadsafe(run)
            return done.result(timeout=COMMAND_S)

        def stop(self) -> None:
            self.stopping.set()
            if self.loop is not None and self.service is not None:
                with contextlib.suppress(RuntimeError):  # the loop already closed
                    self.loop.call_soon_threadsafe(self.service.stop)

    return ShardTwin


def run_hall(model: Path, source: str, mapping: Path, store: Path, shards: int, *,
             address: str | None = None, commit_ms: float = 200.0, physics: str = "reduced",
             silent_s: float = 2.0, duration_s: float | None = None,
             on_status: Callable[[list[dict[str, Any] | None]], None] | None = None,
             on_actors: Callable[[Callable[..., dict[str, Any]]], None] | None = None,
             status_every_s: float = 10.0, detector: str = "auto",
             learn_s: float | None = None,
             level_window_m: float = WINDOW_M,
             level_search_mm: float = SEARCH_MM) -> list[dict[str, Any]]:  # fmt: skip
    """Run ``shards`` twin actors on Ray (the cluster at ``address``, else a private instance
    with ``shards`` CPUs) until ``duration_s`` or Ctrl-C; each shard's final status. Each
    shard's machines learn their own healthy state (``detector``, ``learn_s``: as ``twin
    run``'s), kept in the shard's store; ``level_window_m``: metres of sliver per leveller
    recommendation, as ``twin run``'s."""
    from drafttwin.execution.executor import ray_session

    check_store(store, shards)
    # the caller's SIGTERM handler stays (not Ray's stack dump): it stops the shards, which
    # commit what they received
    with ray_session(shards, address, foreground=True) as ray:
        cls = _actor_class(ray)
        opts = {"model": model.resolve(), "mapping": mapping.resolve(), "commit_ms": commit_ms,
                "physics": physics, "silent_s": silent_s, "learn_s": learn_s,
                "level_window_m": level_window_m, "level_search_mm": level_search_mm,
                "detector": detector if detector in ("auto", "none") else
                str(Path(detector).resolve())}  # fmt: skip
        actors = [cls.remote({**opts, "source": shard_source(source, i, shards),
                              "store": shard_dir(store.resolve(), i, shards)})
                  for i in range(shards)]  # fmt: skip
        refs = [a.run.remote(duration_s) for a in actors]
        if on_actors is not None:  # the page's commands reach a machine through its shard

            def command(
                shard: int, kind: str, machine: str, args: dict[str, Any]
            ) -> dict[str, Any]:
                answer: dict[str, Any] = ray.get(actors[shard].command.remote(kind, machine, args),
                                                 timeout=COMMAND_S + 5)  # fmt: skip
                return answer

            on_actors(command)
        seen: list[dict[str, Any] | None] = [None] * shards
        try:
            _wait(ray, actors, refs, on_status, status_every_s, seen)
        except Interrupted as exc:  # Ctrl-C or SIGTERM: each actor commits what it received
            ended = _stop_shards(ray, actors, refs)
            stopped = Interrupted(exc.signum, _stop_note(shards, ended, seen))
            stopped.results = _collect_stopped(ray, refs, ended)  # type: ignore[attr-defined]
            raise stopped from None
        except BaseException:
            _stop_shards(ray, actors, refs)
            raise
        return _collect(ray, refs)


def _stop_note(shards: int, ended: list[int],
               seen: list[dict[str, Any] | None] | None = None) -> str:  # fmt: skip
    """What a stop did, shard by shard: a shard ended after its twin had run is said so, not
    "still starting" (its last status says which; its rows not yet committed are lost)."""
    ran = [i for i in range(shards) if i not in ended]
    seen = seen or [None] * shards
    late = [i for i in ended if (seen[i] or {}).get("machines") is not None]
    starting = [i for i in ended if i not in late]
    parts = []
    if ran:
        parts.append(f"{_shards(ran)} committed what {'it' if len(ran) == 1 else 'they'} received")
    if starting:
        parts.append(
            f"{_shards(starting)} still starting ({'was' if len(starting) == 1 else 'were'} ended)"
        )
    if late:
        parts.append(f"{_shards(late)} ran but did not end within {STOP_S:g} s of the stop "
                     f"({'was' if len(late) == 1 else 'were'} ended: rows not yet committed "
                     "are lost)")  # fmt: skip
    return "; ".join(parts)


def _shards(idx: list[int]) -> str:
    return ("shard " if len(idx) == 1 else "shards ") + ", ".join(str(i) for i in idx)


def _stop_shards(ray: Any, actors: list[Any], refs: list[Any]) -> list[int]:
    """Ask every shard to stop (a running twin commits what it received and returns within
    a second or two) and wait STOP_S for them; a shard still starting (importing, loading its
    model: tens of seconds on 2 cores) has nothing to commit and is ended instead. Returns
    the shards ended so."""
    for a in actors:
        a.stop.remote()
    with contextlib.suppress(Exception):
        ray.wait(refs, num_returns=len(refs), timeout=STOP_S)
    ended = []
    for i, (a, ref) in enumerate(zip(actors, refs, strict=True)):
        done, _ = ray.wait([ref], timeout=0)
        if not done:
            ended.append(i)
            with contextlib.suppress(Exception):
                ray.kill(a, no_restart=True)
    return ended


def _wait(ray: Any, actors: list[Any], refs: list[Any], on_status: Any, every_s: float,
          seen: list[dict[str, Any] | None]) -> None:  # fmt: skip
    """Until every shard's run returns; ``seen`` (one per shard) keeps their last status."""
    last = time.monotonic()
    pending = list(refs)
    from drafttwin.execution.interrupt import signals_deferred

    while pending:
        # a signal must not raise inside Ray's Cython calls (it left ray.get hanging): under
        # stop_on_signals it is raised when the call has returned, within POLL_S
        with signals_deferred():
            _, pending = ray.wait(pending, num_returns=len(pending), timeout=POLL_S)
        if on_status is not None and time.monotonic() - last >= every_s:
            last = time.monotonic()
            with signals_deferred():
                seen[:] = _statuses(ray, actors, refs, seen)
            on_status(list(seen))


def _statuses(ray: Any, actors: list[Any], refs: list[Any],
              seen: list[dict[str, Any] | None]) -> list[dict[str, Any] | None]:  # fmt: skip
    """Each shard's status, asked of all at once, with its ``state``: ``starting`` (its
    process is not up yet), ``loading`` (its model), ``running``, ``not answering`` (it did,
    but not within STATUS_S now: busy, or started again after its process died; its last
    status kept), ``restarting`` (its process was started again and loads: its last status
    kept), ``ended`` or ``failed``."""
    asked = {i: a.status.remote() for i, (a, ref) in enumerate(zip(actors, refs, strict=True))
             if not ray.wait([ref], timeout=0)[0]}  # fmt: skip
    done, _ = ray.wait(list(asked.values()), num_returns=len(asked), timeout=STATUS_S)
    out: list[dict[str, Any] | None] = []
    for i, ref in enumerate(refs):
        if i not in asked:  # its run returned
            try:
                out.append({**ray.get(ref, timeout=0), "state": "ended"})
            except Exception as exc:  # noqa: BLE001  said on the page; _collect raises it
                out.append({"state": "failed", "error": str(exc).strip().splitlines()[-1][:200]})
            continue
        got = None
        if asked[i] in done:
            with contextlib.suppress(ray.exceptions.RayError, TimeoutError):
                got = ray.get(asked[i], timeout=0)
        before = seen[i]
        restarted = got is not None and "machines" not in got
        if restarted and before is not None and "machines" in before:
            # started again after its process died (Ray restarts it): its machines and their
            # standing alarms stay listed as last seen until it runs again (they had vanished
            # from the page, and a command to one of them answered 404 "no machine")
            out.append({**before, "state": "restarting"})
        elif got is not None:
            out.append(got)
        elif seen[i] is None or seen[i].get("state") == "starting":  # type: ignore[union-attr]
            out.append({"state": "starting"})
        else:
            out.append({**seen[i], "state": "not answering"})  # type: ignore[dict-item]
    return out


def _collect_stopped(ray: Any, refs: list[Any], ended: list[int]) -> list[dict[str, Any] | None]:
    """The final status of each shard a stop let finish (None: ended while starting, or
    failed): a hall stops by a signal as a rule, and its summary is what it did."""
    out: list[dict[str, Any] | None] = []
    for i, ref in enumerate(refs):
        result = None
        if i not in ended:
            with contextlib.suppress(Exception):
                result = ray.get(ref, timeout=STOP_S)
        out.append(result)
    return out


def _collect(ray: Any, refs: list[Any]) -> list[dict[str, Any]]:
    """Each actor's final status; a shard's user error (a refused store, an unreadable
    model) comes back as that error, anything else as one line naming the shard."""
    from drafttwin.errors import DrafttwinError

    out = []
    for i, ref in enumerate(refs):
        try:
            out.append(ray.get(ref, timeout=60))
        except ray.exceptions.RayTaskError as exc:
            cause = getattr(exc, "cause", None)
            if isinstance(cause, DrafttwinError):
                raise cause from None
            text = str(cause or exc).strip().splitlines()
            raise DrafttwinError(f"shard {i} failed: {text[-1] if text else type(exc).__name__}",
                                 fix="see the shard's message; run that shard alone with "
                                 "'drafttwin twin run --source ...?shard=I/K' to debug") from None  # fmt: skip
    return out


__all__ = ["check_hall", "check_store", "run_hall", "shard_dir", "shard_source"]
