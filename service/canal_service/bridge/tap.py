"""The pose path's recording tap: the rows each stream kept for the recording (see
:mod:`.answers`) and its count deltas, handed to the bridge's recording thread."""

from __future__ import annotations

from typing import Any

from .streams import StreamTable


class RecordTap(StreamTable):
    """The pose path's layer that hands rows and counts to the recording thread."""

    def take_record(self) -> list[tuple[Any, ...]]:
        """Each stream's rows and count deltas since the last call, as
        ``(skill, robot, poses, answered, coalesced, errors, decimated, rows)`` (streams
        with nothing new are left out); see :func:`canal_service.record_batches.encode_record_batch`."""
        out = []
        with self.rec_lock:
            retired, self.retired = self.retired, []
            for st in [*self.streams.values(), *retired]:
                if not (st.rec_poses or st.rec_errors or st.rec_answered):
                    continue
                rows, st.rec_rows = st.rec_rows, []
                out.append((st.skill, st.robot, st.rec_poses, st.rec_answered,
                            st.rec_coalesced, st.rec_errors, st.rec_poses - len(rows), rows))
                st.rec_poses = st.rec_answered = st.rec_coalesced = st.rec_errors = 0
        return out
