"""Helpers any layer may use: argument checks (``_validate``), messages (``_format``),
refusals as data (``_errors``), bitmask tables and memory (``_tables``), the one call path
of a batch (``_batch``, with ``_dask`` and ``_progress``), safe files (``_safefiles``),
numerical derivatives (``_numdiff``) and the notice of a first compilation
(``_compiling``). They import only each other and the numbers of ``_limits`` and
``_numerics``."""
