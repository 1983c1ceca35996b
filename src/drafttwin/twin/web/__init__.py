"""The twin over HTTP (FastAPI + uvicorn), behind one token guard.

:mod:`~drafttwin.twin.web.app` (the twin's page, REST API, WebSocket and ``/metrics``),
served in a thread of its own by :mod:`~drafttwin.twin.web.server` and reaching the twin's
state through :mod:`~drafttwin.twin.web.bridge`,
:mod:`~drafttwin.twin.web.history` (its history, alarms and events, paged and bounded, off the
processing path), :mod:`~drafttwin.twin.web.metrics` (Prometheus), :mod:`~drafttwin.twin.web.hall`
(a hall's page), :mod:`~drafttwin.twin.web.guard` (the one token check of both pages, HTTP and
WebSocket) and :mod:`~drafttwin.twin.web.assets` (the pages' files in ``static/``, shipped in
the package).
"""
