"""mcap's ``Writer`` with a bulk path for live rows, behind one adapter.

``Writer.add_message`` costs a record object, five small writes and two seeks per message.
The live path writes a stream's rows (a pose and a target each) into the open chunk in one
write, with the same message indexes and statistics. That needs the Writer's chunk builder,
statistics and chunk check, private attributes that mcap does not promise to keep. So the
bulk path is taken only with the mcap versions it was written against (:data:`TESTED`) and
when those attributes are there; otherwise, or with ``fast=False``, every message goes
through the public ``add_message``. :func:`status` says which path runs (``/healthz``).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import io
import struct
from collections.abc import Callable
from importlib.metadata import version
from itertools import chain
from typing import Any

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import MessageIndex, Statistics
from mcap.writer import Writer
from numpy.typing import NDArray

#: mcap versions (prefixes) whose Writer internals the bulk path was written and tested
#: against.
TESTED = ("1.6.",)
INSTALLED = version("mcap")

# A private module: one a future mcap may not have means the public path (looked up, not
# imported blindly, so its absence is an answer rather than an error).
_chunk_builder: type[Any] | None = None
if importlib.util.find_spec("mcap._chunk_builder") is not None:
    _chunk_builder = getattr(importlib.import_module("mcap._chunk_builder"), "ChunkBuilder", None)

#: A Message record's head: opcode, record length, channel id, sequence, log and publish time.
_MESSAGE = struct.Struct("<BQHIQQ")
_OP_MESSAGE = int(Opcode.MESSAGE)

#: ``write(first, firsts, second, seconds, t_ns)``: messages on two channels, interleaved
#: (first, second) per row at the times ``t_ns`` (int64 nanoseconds).
PairWriter = Callable[[int, list[bytes], int, list[bytes], NDArray[np.int64]], None]


class PackedMessageIndex(MessageIndex):
    """A chunk's message index whose entries the live path adds as packed (log time,
    offset) pairs: no tuple per message to allocate (and for the garbage collector to
    walk), one write per index at the chunk's end."""

    packed: list[NDArray[np.uint64]]

    def write(self, stream: RecordBuilder) -> None:
        pairs = list(self.packed)
        if self.records:  # entries the public add_message appended: in file order with ours
            pairs.append(np.array(self.records, dtype=np.uint64).reshape(-1, 2))
        table = np.concatenate(pairs) if pairs else np.empty((0, 2), np.uint64)
        if len(pairs) > 1:
            table = table[np.argsort(table[:, 1], kind="stable")]
        data = table.astype("<u8").tobytes()
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(data))
        stream.write(data)
        stream.finish_record()  # type: ignore[no-untyped-call]  # mcap is untyped


def writer_internals(writer: Writer) -> tuple[Any, Statistics, Callable[[], None]] | None:
    """The chunk builder, statistics and chunk check of mcap's Writer, when this mcap is one
    the bulk path knows and they are there; else None."""
    if _chunk_builder is None or not INSTALLED.startswith(TESTED):
        return None
    builder = getattr(writer, "_Writer__chunk_builder", None)
    stats = getattr(writer, "_Writer__statistics", None)
    finalize = getattr(writer, "_Writer__maybe_finalize_chunk", None)
    if (isinstance(builder, _chunk_builder) and isinstance(stats, Statistics) and callable(finalize)
            and hasattr(builder.record_writer, "_buffer")):
        return builder, stats, finalize
    return None


def pair_writer(writer: Writer, fast: bool = True) -> PairWriter:
    """How ``writer`` takes messages in pairs: the bulk path when it can (and ``fast``), else
    the public ``add_message`` per message. Both write the same records, indexes and
    statistics (tested)."""
    internals = writer_internals(writer) if fast else None
    if internals is None:
        add = writer.add_message

        def public(first: int, firsts: list[bytes], second: int, seconds: list[bytes],
                   t_ns: NDArray[np.int64]) -> None:
            for t, a, b in zip(t_ns.tolist(), firsts, seconds, strict=True):
                add(first, log_time=t, data=a, publish_time=t)
                add(second, log_time=t, data=b, publish_time=t)

        return public
    builder, stats, finalize = internals

    def bulk(first: int, firsts: list[bytes], second: int, seconds: list[bytes],
             t_ns: NDArray[np.int64]) -> None:
        times = t_ns.tolist()
        if not times:
            return
        buffer = builder.record_writer._buffer
        offset = buffer.tell()
        pack = _MESSAGE.pack
        sizes_a = [len(a) for a in firsts]
        sizes_b = [len(b) for b in seconds]
        buffer.writelines(chain.from_iterable(zip(
            [pack(_OP_MESSAGE, 22 + n, first, 0, t, t) for n, t in zip(sizes_a, times, strict=True)], firsts,
            [pack(_OP_MESSAGE, 22 + n, second, 0, t, t) for n, t in zip(sizes_b, times, strict=True)],
            seconds, strict=True)))
        # where each record starts in the chunk: its message index entry
        m = len(times)
        sizes = np.empty(2 * m, dtype=np.uint64)
        sizes[0::2] = sizes_a
        sizes[1::2] = sizes_b
        sizes += _MESSAGE.size
        starts = np.cumsum(sizes) - sizes + np.uint64(offset)
        for k, cid in enumerate((first, second)):
            index = builder.message_indices.get(cid)
            if type(index) is not PackedMessageIndex:
                fresh = PackedMessageIndex(channel_id=cid, records=[] if index is None
                                           else index.records)
                fresh.packed = []
                builder.message_indices[cid] = index = fresh
            pairs = np.empty((m, 2), dtype=np.uint64)
            pairs[:, 0] = t_ns
            pairs[:, 1] = starts[k::2]
            index.packed.append(pairs)
            stats.channel_message_counts[cid] += m
        lo, hi, n = min(times), max(times), 2 * len(times)
        builder.message_start_time = lo if builder.num_messages == 0 else min(
            builder.message_start_time, lo)
        builder.message_end_time = max(builder.message_end_time, hi)
        builder.num_messages += n
        stats.message_start_time = lo if stats.message_count == 0 else min(
            stats.message_start_time, lo)
        stats.message_end_time = max(stats.message_end_time, hi)
        stats.message_count += n
        finalize()

    return bulk


@functools.cache
def status() -> str:
    """Which path live rows take with the installed mcap: what ``/healthz`` reports."""
    writer = Writer(io.BytesIO())
    writer.start(profile="", library="canal-recorder")
    if writer_internals(writer) is not None:
        return f"internals (mcap {INSTALLED})"
    return (f"public API (mcap {INSTALLED}; the bulk path knows "
            f"{', '.join(v + 'x' for v in TESTED)})")
