"""Adapters to what other libraries do not promise: one module per library.

Where a fast path needs another library's internals, its adapter checks the installed
version at import, falls back to the library's public API otherwise, and says which path it
takes (:func:`adapter_paths`, shown in ``/healthz``). No other module imports a private name
of another distribution.
"""

from __future__ import annotations


def adapter_paths() -> dict[str, str]:
    """``{library: path}``: "internals (...)" or "public API (...)" for each adapter."""
    # Imported here: each loads its library (seconds for rerun), which /healthz's callers
    # have loaded already and other importers of this package may not need.
    from . import mcap_writer, rerun_chunks

    return {"mcap": mcap_writer.status(), "rerun-sdk": rerun_chunks.status()}
