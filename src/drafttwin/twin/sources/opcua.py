"""An OPC UA server as a live source (asyncua): a subscription to each machine's sample node,
reconnecting with backoff, reading the server's history after a restart (``--source opcua:URL``).
Where the server has a machine's sliver block beside its sample node (``NAME.Sliver.block``,
``plant serve --sliver``) it is subscribed too, and the leveller's description read
(``NAME.Leveller.Description``, :mod:`drafttwin.wire.sliver`)."""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path
from typing import Any, cast

from drafttwin.twin.sources.base import BACKOFF_S, Emit, Report, Sample, Source
from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.wire.sliver import MAX_DESCRIPTION, SliverBatch, from_block

SERVER_QUEUE = 10_000
"""Monitored-item queue asked of an OPC UA server (samples kept while the twin is busy)."""
DISCONNECT_S = 1.0
"""How long closing the session may take at a stop."""


class OpcUaSource(Source):
    """A subscription to each machine's sample node (a Double array laid out as the
    mapping's ``fields``), with queue sizes that keep every sample (docs/twin.md)."""

    def __init__(self, url: str, machines: tuple[MachineMap, ...], publish_ms: float = 10.0,
                 cert_dir: Path | None = None) -> None:  # fmt: skip
        self.spec, self.url, self.machines = f"opcua:{url}", url, machines
        self.publish_ms = publish_ms
        self.cert_dir = cert_dir
        self.silence_s = 5.0
        self.client: Any = None
        self.resume_after: dict[str, int] = {}  # a restart: read the server's history after these

    async def run(self, emit: Emit, report: Report) -> None:
        from asyncua import Client
        from asyncua.common.subscription import DataChangeEvent, OverflowPolicy

        by_node = {m.node: m for m in self.machines}
        attempt = 0
        while True:
            client = Client(self.url, timeout=2.0, watchdog_intervall=1.0)
            try:
                if self.cert_dir is not None:
                    from drafttwin.twin.sources.security import secure_client

                    await secure_client(client, self.cert_dir)
                async with client:
                    self.client = client
                    # server queues of 100 s at 100 Hz (asyncua's cap, 10 000; a spec server
                    # needs at least 2x the samples per publishing interval) and a client queue
                    # of minutes: a stalled loop loses nothing on either side
                    sub = await client.create_subscription(
                        self.publish_ms, None, queue_maxsize=200_000,
                        overflow=OverflowPolicy.DISCONNECT)  # fmt: skip
                    async with sub:
                        nodes = [client.get_node(n) for n in by_node]
                        await sub.subscribe_data_change(nodes, queuesize=SERVER_QUEUE)
                        by_sliver = await self._sliver_nodes(client, sub, report)
                        self._set("live", report)
                        attempt = 0
                        for each in self.machines:  # who each machine is, if the server says
                            await self._identify(client, each, report)
                        if self.resume_after:  # once, on the first connection after a restart
                            await self._backfill(client, emit, report)
                            self.resume_after = {}
                        while True:
                            # a subscription that goes quiet without an error (opcua-asyncio
                            # #1925) is dropped and made again, like a broken connection.
                            # asyncio.timeout, not wait_for: Python 3.11's wait_for swallows a
                            # cancellation that lands as the item arrives (the twin then ran
                            # on for tens of seconds after SIGTERM)
                            try:
                                async with asyncio.timeout(self.silence_s):
                                    ev = await anext(sub)
                            except asyncio.CancelledError:  # the stop: hand over what arrived
                                for ev in _received(sub):
                                    self._take(ev, by_node, DataChangeEvent, emit, report,
                                               by_sliver)  # fmt: skip
                                raise
                            self._take(ev, by_node, DataChangeEvent, emit, report, by_sliver)
            except asyncio.CancelledError:
                raise
            except TimeoutError:
                self._set("reconnecting", report, f"no sample for {self.silence_s:g} s")
            except Exception as exc:  # noqa: BLE001  any network / server failure: reconnect
                self._set("reconnecting", report, _reason(exc, self.cert_dir is not None))
            finally:
                self.client = None
                # bounded: a refused secured session can leave asyncua's disconnect waiting on
                # a reply that never comes, which would hold the twin's shutdown; shielded from
                # a second cancellation (else the coroutine is left never awaited)
                await _disconnect(client)
            await asyncio.sleep(BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)])
            attempt += 1

    @staticmethod
    def _take(ev: Any, by_node: dict[str, MachineMap], change: type, emit: Emit,
              report: Report, by_sliver: dict[str, MachineMap] | None = None) -> None:  # fmt: skip
        """One subscription item: a machine's sample (or sliver batch) emitted, a malformed
        one counted."""
        if not isinstance(ev, change):
            return
        ev = cast(Any, ev)
        key = ev.node.nodeid.to_string()
        m = by_node.get(key)
        if m is None:
            s = (by_sliver or {}).get(key)
            placeholder = isinstance(ev.value, list | tuple) and len(ev.value) == 1  # none yet
            if s is not None and not placeholder:
                got = from_block(s.name, ev.value)
                if isinstance(got, SliverBatch):
                    emit(got)
                else:
                    report(s.name, "dropped", got)
            return
        row = m.from_array(ev.value)
        if row is None:
            report(m.name, "dropped", f"malformed value {str(ev.value)[:80]}")
        else:
            emit(Sample(m.name, *row))

    async def _sliver_nodes(self, client: Any, sub: Any, report: Report) -> dict[str, MachineMap]:
        """Subscribe each machine's sliver block where the server has one beside its sample
        node, and report the leveller's description; node id -> machine."""
        out: dict[str, MachineMap] = {}
        for m in self.machines:
            if not m.node.endswith(".sample"):
                continue
            base = m.node.removesuffix(".sample")
            block = client.get_node(f"{base}.Sliver.block")
            try:
                await asyncio.wait_for(block.read_browse_name(), 5.0)
            except Exception:  # noqa: BLE001  asyncua's BadNodeIdUnknown: no sliver here
                continue
            await sub.subscribe_data_change([block], queuesize=SERVER_QUEUE)
            out[block.nodeid.to_string()] = m
            try:
                text = await asyncio.wait_for(
                    client.get_node(f"{base}.Leveller.Description").read_value(), 5.0)  # fmt: skip
            except Exception:  # noqa: BLE001  none to read: the twin levels nothing
                continue
            if isinstance(text, str) and len(text) <= MAX_DESCRIPTION:
                report(m.name, "leveller", text)
        return out

    async def _identify(self, client: Any, m: MachineMap, report: Report) -> None:
        """Read the machine's Identification (OPC 40001-1: SerialNumber, ProductInstanceUri,
        Manufacturer, Model) beside its sample node and report it (``identity``); a server
        without one says nothing."""
        from drafttwin.wire.identity import MachineIdentity

        names = {"SerialNumber": "serial_number", "ProductInstanceUri": "product_instance_uri",
                 "Manufacturer": "manufacturer", "Model": "model"}  # fmt: skip
        try:
            parent = await asyncio.wait_for(client.get_node(m.node).get_parent(), 5.0)
            found = {}
            for child in await asyncio.wait_for(parent.get_children(), 5.0):
                if (await child.read_browse_name()).Name != "Identification":
                    continue
                for prop in await asyncio.wait_for(child.get_children(), 5.0):
                    key = names.get((await prop.read_browse_name()).Name)
                    if key is not None:
                        value = await asyncio.wait_for(prop.read_value(), 5.0)
                        found[key] = getattr(value, "Text", value)
        except (TimeoutError, OSError, ValueError, AttributeError) as exc:
            report(m.name, "history", f"identification not read ({type(exc).__name__})")
            return
        except Exception as exc:  # noqa: BLE001  asyncua's status errors: none to read
            report(m.name, "history", f"identification not read ({type(exc).__name__})")
            return
        identity = MachineIdentity.from_dict(found)
        if identity is not None:
            report(m.name, "identity", json.dumps(identity.to_dict()))

    async def _backfill(self, client: Any, emit: Emit, report: Report) -> None:
        """Emit what the server's history holds after each machine's last stored sample (the
        subscription, made first, queues what comes meanwhile; the reorder step drops the
        overlap). A server without history recovers nothing, and says so."""
        import datetime as dt

        from asyncua import ua

        now = dt.datetime.now(dt.UTC)
        for m in self.machines:
            after = self.resume_after.get(m.name)
            if after is None:
                continue
            start = dt.datetime.fromtimestamp(after / 1e6, tz=dt.UTC)
            try:
                node = client.get_node(m.node)
                values = await asyncio.wait_for(node.read_raw_history(start, now), 30.0)
            except (ua.UaError, TimeoutError) as exc:
                report(m.name, "history", f"no history read ({type(exc).__name__}): samples "
                       "published while no twin ran are not recovered")  # fmt: skip
                continue
            rows = [m.from_array(dv.Value.Value) for dv in values if dv.Value is not None]
            fresh = [r for r in rows if r is not None and r[0] > after]
            for row in fresh:  # no receive time: their latency is not the live path's
                emit(Sample(m.name, *row, received=math.nan))
            report(m.name, "history", f"{len(fresh)} samples recovered from the server's history")


def _reason(exc: Exception, secured: bool) -> str:
    """Why the connection failed, with what to do where it is a security mismatch (asyncua
    says only "No matching endpoints ... SecurityPolicy#None")."""
    text = f"{type(exc).__name__}: {exc}"
    if not secured and "No matching endpoints" in text:
        text = "the server accepts secured sessions only: add ?cert=DIR to --source (" + text + ")"
    return text[:200]


def _received(sub: Any) -> list[Any]:
    """The items a subscription received and queued but nobody took yet (asyncua keeps them in
    the iterator's queue; none when a later version keeps them elsewhere)."""
    queue = getattr(sub, "_event_queue", None)
    out = []
    while queue is not None and not queue.empty():
        item = queue.get_nowait()
        if item is not None:
            out.append(item)
    return out


async def _disconnect(client: Any) -> None:
    """Close the session within :data:`DISCONNECT_S`; a cancellation meanwhile waits for that
    (bounded) and is raised again after it."""
    task = asyncio.ensure_future(client.disconnect())
    cancelled = False
    deadline = asyncio.get_running_loop().time() + DISCONNECT_S
    while not task.done():
        left = deadline - asyncio.get_running_loop().time()
        if left <= 0:
            task.cancel()
            break
        try:
            await asyncio.wait([task], timeout=left)
        except asyncio.CancelledError:
            cancelled = True
    if task.done() and not task.cancelled():
        task.exception()  # retrieved: a failed close is no error at a stop
    if cancelled:
        raise asyncio.CancelledError


__all__ = ["SERVER_QUEUE", "OpcUaSource"]
