"""The twin's history, one DuckDB file per twin: written, read back and audited.

:mod:`~drafttwin.twin.store.db` (the file, its tables and rows, the writer thread),
:mod:`~drafttwin.twin.store.history` (samples and events read back as tables, and the queries
the page's history runs) and :mod:`~drafttwin.twin.store.audit` (a store counted against the
plant's log, sample by sample). Nothing here knows the sources or the pages.
"""
