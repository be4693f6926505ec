"""A file sent to a route, as a multipart upload (field ``file``, optional field ``label``) or
as the raw request body: what demonstrations and corrections read the same way."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

from fastapi import Query, Request
from starlette.datastructures import UploadFile
from starlette.exceptions import HTTPException

from canal_protocol.options import MAX_DEMO_LABEL
from canal_protocol.options import TimeUnit as TimeUnitName

from ..errors import BadUpload, InvalidInput, PayloadTooLarge, UnsupportedMediaType
from ..lanes import Lane
from ..uploads import UploadLimits

#: Content types of a raw file body (the format is told by ``?format=`` or the magic bytes
#: when they do not say it).
FILE_TYPES = ("text/csv", "application/csv", "application/x-npy", "application/npy",
              "application/x-mcap", "application/mcap", "application/octet-stream")
BINARY: dict[str, Any] = {"type": "string", "format": "binary"}

Format = Annotated[Literal["csv", "npy", "mcap"] | None,
                   Query(description="File format; guessed when omitted.")]
Topic = Annotated[str | None, Query(max_length=1024, description="MCAP pose topic.")]
TimeUnit = Annotated[TimeUnitName | None, Query(
    description="Unit of the timestamps (JSON) or of the CSV/NPY time column, seconds when "
                "omitted; with ms, us or ns they are stored as seconds from the first sample. "
                "Not for MCAP (its message stamps are read as such).")]


def file_content(max_label: int) -> dict[str, Any]:
    """The OpenAPI ``content`` of a file body: multipart (``file``, ``label`` of at most
    ``max_label`` characters) and the raw file types."""
    return {
        "multipart/form-data": {
            "schema": {
                "type": "object",
                "properties": {"file": BINARY, "label": {"type": "string", "maxLength": max_label}},
                "required": ["file"],
            }
        },
        "text/csv": {"schema": {"type": "string"}},
        "application/x-npy": {"schema": BINARY},
        "application/x-mcap": {"schema": BINARY},
        "application/octet-stream": {"schema": BINARY},
    }


@dataclass(frozen=True)
class FileBody:
    """A file's bytes and what the request said of it."""

    data: bytes
    filename: str | None
    content_type: str | None
    #: the multipart ``label`` field, else the file's name (a raw body has neither)
    label: str | None


async def file_body(request: Request, also: str = "", hint: str = "",
                    max_label: int = MAX_DEMO_LABEL) -> FileBody:
    """The file of a multipart or raw-body request; ``also`` names the other content types
    the route takes and ``hint`` where else to go, for the 415 that lists what is accepted.
    A multipart label longer than ``max_label`` is refused; a file name is cut to its end."""
    content_type = request.headers.get("content-type", "")
    base = content_type.split(";", 1)[0].strip().lower()
    if base == "multipart/form-data":
        data, filename, part_type, form_label = await _read_multipart(request, max_label)
        label = form_label if form_label is not None else _label_of(filename, max_label)
        upload = FileBody(data, filename, part_type, label)
    elif base in FILE_TYPES:
        upload = FileBody(await request.body(), None, base, None)
    else:
        raise UnsupportedMediaType(
            f"expected Content-Type {also}multipart/form-data or one of "
            f"{', '.join(FILE_TYPES)}, got {content_type or 'none'!r}{hint}",
            field="Content-Type",
        )
    if not upload.data:
        raise BadUpload("the uploaded file is empty", field="file")
    return upload


def _label_of(filename: str | None, max_label: int) -> str | None:
    """A file's name as its label, so lists and the viewer say which file each came from
    (a browser may send a Windows path; its end is what tells files apart)."""
    if not filename:
        return None
    name = filename.replace("\\", "/").rsplit("/", 1)[-1].replace("\x00", "")
    return name[-max_label:] or None


def upload_lane(request: Request) -> Lane:
    """The app's upload lane (``CANAL_UPLOAD_WORKERS`` threads)."""
    lane: Lane = request.app.state.upload_lane
    return lane


def upload_limits(request: Request) -> UploadLimits:
    """The deployment's per-upload limits (``CANAL_UPLOAD_*``), built once with the app."""
    limits: UploadLimits = request.app.state.upload_limits
    return limits


async def _read_multipart(request: Request, max_label: int,
                          ) -> tuple[bytes, str | None, str | None, str | None]:
    try:
        form = await request.form(max_files=1, max_fields=8)
    except PayloadTooLarge:
        raise
    except HTTPException as exc:
        raise BadUpload(f"unreadable multipart body: {exc.detail}", field="body") from exc
    try:
        upload = form.get("file")
        if not isinstance(upload, UploadFile):
            raise InvalidInput("expected a file in the multipart field 'file'", field="file")
        data = await upload.read()
        label = form.get("label")
        if label is not None and (not isinstance(label, str) or len(label) > max_label or "\x00" in label):
            came = ("a file" if not isinstance(label, str) else "text with a NUL character"
                    if "\x00" in label else f"{len(label)} characters")
            raise InvalidInput(f"expected 'label' as text of at most {max_label} characters "
                               f"without NUL, got {came}", field="label")
        return data, upload.filename, upload.content_type, label
    finally:
        await form.close()
