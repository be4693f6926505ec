"""What every upload format shares: the limits of one upload, its running budget, and the
arrays a parser returns."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

from canal_protocol.codecs.csv_table import CsvTable
from canal_protocol.options import RECORDING_MAGIC

from ..errors import TooLarge

#: Raw arrays from a file, not yet checked (see ``validation.check_demonstration``): the
#: same four a CSV table gives, whatever the format.
ParsedUpload = CsvTable

UploadFormat = Literal["csv", "npy", "mcap"]
FORMATS: tuple[str, ...] = ("csv", "npy", "mcap")
NPY_MAGIC = b"\x93NUMPY"
MCAP_MAGIC = RECORDING_MAGIC["mcap"]

# A demonstration is a few minutes of a robot at up to 1 kHz: 200,000 samples is 6.7 min at
# 500 Hz. The other two defaults follow: a ROS 2 PoseStamped record is ~100 bytes, so 200,000
# samples need ~20 MB decompressed; 64 MiB leaves room for other topics in the same file.
DEFAULT_MAX_POINTS = 200_000
DEFAULT_MAX_DECOMPRESSED_BYTES = 64 * 1024 * 1024
DEFAULT_MAX_SECONDS = 10.0


@dataclass(frozen=True)
class UploadLimits:
    """What one upload may cost the server (see the module docstring)."""

    max_points: int = DEFAULT_MAX_POINTS
    max_decompressed_bytes: int = DEFAULT_MAX_DECOMPRESSED_BYTES
    max_seconds: float = DEFAULT_MAX_SECONDS


class Budget:
    """The running account of one upload against its limits."""

    def __init__(self, limits: UploadLimits) -> None:
        self.limits = limits
        self.deadline = time.monotonic() + limits.max_seconds
        self.decompressed = 0

    def tick(self) -> None:
        """Raise once the upload has used its server time."""
        if time.monotonic() > self.deadline:
            raise TooLarge(
                f"parsing this upload took more than {self.limits.max_seconds:g} s of server "
                "time (limit CANAL_UPLOAD_MAX_SECONDS); send fewer samples or a smaller file",
                field="file",
            )

    def produced(self, n_bytes: int) -> None:
        """Count decompressed bytes as they come out of the decompressor."""
        self.decompressed += n_bytes
        if self.decompressed > self.limits.max_decompressed_bytes:
            raise TooLarge(
                f"MCAP decompresses to more than {self.limits.max_decompressed_bytes} bytes "
                "(limit CANAL_UPLOAD_MAX_DECOMPRESSED_BYTES)",
                field="file",
            )

    def points(self, n_points: int, what: str) -> None:
        """Refuse more samples than one demonstration may have."""
        if n_points > self.limits.max_points:
            raise TooLarge(
                f"{what} has more than {self.limits.max_points} samples (limit "
                "CANAL_UPLOAD_MAX_POINTS); downsample it or split it",
                field="file",
            )
