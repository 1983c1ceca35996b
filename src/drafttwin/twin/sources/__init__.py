"""Where a live twin's samples come from: the sources and what tells them apart.

:mod:`~drafttwin.twin.sources.base` (a :class:`~drafttwin.twin.sources.base.Sample`, the
:class:`~drafttwin.twin.sources.base.Source` every kind is), the kinds
(:mod:`~drafttwin.twin.sources.replay`, :mod:`~drafttwin.twin.sources.opcua` with its client
security in :mod:`~drafttwin.twin.sources.security`, :mod:`~drafttwin.twin.sources.mqtt`), the
mapping file (:mod:`~drafttwin.twin.sources.mapping`: which node or topic is which machine) and
the ``--source`` text parsed into a source (:mod:`~drafttwin.twin.sources.spec`). Nothing here
knows the store or the pages.
"""
