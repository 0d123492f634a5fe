"""Checks made before a bag is handed to ``rosbags``: a ROS 2 folder's ``metadata.yaml`` may not
name files outside the folder, and the records ``rosbags`` reads straight from a ROS 1 ``.bag``
or an ``.mcap`` file must fit in the file. ``rosbags`` reads a record by asking the file for the
length the record claims, which allocates that length first: a corrupt length of a few GB would
allocate a few GB before the short read is noticed. Here every such length is checked against
the file's size (a walk over the file's record headers, not its data) and a bad one is a one-line
:class:`~evsmap.errors.DataFormatError` naming the file and the byte offset."""

from __future__ import annotations

import struct
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import BinaryIO

from evsmap.errors import DataFormatError
from evsmap.readers.rosbag.messages import _one_line

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
MAX_ROS1_HEADER = 1 << 20
"""Longest ROS 1 record header (and MCAP chunk index) accepted, bytes: real ones (bag, chunk,
index, connection, chunk-info) are tens of bytes; message definitions live in a connection's
data."""


# ------------------------------------------------------------------------- ROS 2 bag folders
def _leaves_folder(entry: str) -> bool:
    """Whether a file path from metadata.yaml is absolute or climbs out (``..``), as POSIX or
    Windows reads it."""
    posix, windows = PurePosixPath(entry), PureWindowsPath(entry)
    return posix.is_absolute() or bool(windows.anchor) or ".." in posix.parts or \
        ".." in windows.parts


def check_bag_folder(folder: Path) -> None:
    """Refuse a ROS 2 bag folder whose ``metadata.yaml`` names a file outside the folder (an
    absolute path or a ``..`` component in ``relative_file_paths`` or ``files``): a bag must not
    make evsmap open files elsewhere. Other problems with the file are left to the bag reader."""
    meta = folder / "metadata.yaml"
    try:
        from ruamel.yaml import YAML

        doc = YAML(typ="safe").load(meta.read_text(encoding="utf-8"))
    except MemoryError:
        raise
    except Exception as exc:  # unreadable or not YAML: OSError, YAMLError, UnicodeError, ...
        raise DataFormatError(f"{meta}: not a readable bag metadata file "
                              f"({_one_line(exc)})") from None
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        return
    entries = info.get("relative_file_paths")
    named = [("relative_file_paths", e) for e in entries] if isinstance(entries, list) else []
    files = info.get("files")
    if isinstance(files, list):
        named += [("files", f.get("path")) for f in files if isinstance(f, dict)]
    for key, entry in named:
        if isinstance(entry, str) and _leaves_folder(entry):
            raise DataFormatError(f"{meta}: {key} names {entry!r}, which is absolute or leaves "
                                  f"the bag folder; a bag's files must lie inside its folder")


# ---------------------------------------------------------------------------------- ROS 1
def _ros1_fields(header: bytes) -> dict[bytes, bytes]:
    fields, pos = {}, 0
    while pos + 4 <= len(header):
        (size,) = struct.unpack_from("<I", header, pos)
        field = header[pos + 4: pos + 4 + size]
        name, eq, value = field.partition(b"=")
        if eq:
            fields[name] = value
        pos += 4 + size
    return fields


def _ros1_records(fh: BinaryIO, size: int) -> tuple[list[int], dict[int, tuple[dict, int]]]:
    """Record starts from byte 13 while their lengths fit (and, for chunk-info records, agree
    with the `count` pairs rosbags reads as their data, so that rosbags' next read starts where
    the next record does), with each record's header fields and data length. Data is skipped,
    not read (a chunk's data is most of a bag)."""
    starts: list[int] = []
    records: dict[int, tuple[dict, int]] = {}
    pos = len(ROS1_MAGIC)
    while pos + 4 <= size:
        fh.seek(pos)
        (hlen,) = struct.unpack("<I", fh.read(4))
        if pos + 8 + hlen > size or hlen > MAX_ROS1_HEADER:
            break
        header = fh.read(hlen)
        (dlen,) = struct.unpack("<I", fh.read(4))
        if pos + 8 + hlen + dlen > size:
            break
        fields = _ros1_fields(header)
        op = fields.get(b"op")
        if op == b"\x06" and (_uint(fields, b"count", 4) or 0) * 8 != dlen:
            break  # a chunk info's data is read as `count` pairs of uint32
        starts.append(pos)
        records[pos] = (fields, dlen)
        pos += 8 + hlen + dlen
    return starts, records


def _uint(fields: dict, name: bytes, size: int) -> int | None:
    value = fields.get(name)
    if value is None or len(value) != size:
        return None
    return int.from_bytes(value, "little")


def check_ros1_records(path: Path) -> None:
    """Refuse a ROS 1 bag whose index, connection, chunk-info, chunk or index-data records (the
    ones ``rosbags`` reads at open and while reading messages) claim more bytes than the file
    holds or start where no record starts. Bags without the ROS 1 magic are left to rosbags."""
    try:
        with path.open("rb") as fh:
            if fh.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
                return
            size = fh.seek(0, 2)
            starts, records = _ros1_records(fh, size)
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read the bag ({_one_line(exc)})") from None
    rank = {p: i for i, p in enumerate(starts)}

    def need(pos: int | None, count: int, what: str) -> list[int]:
        """The ``count`` records from ``pos`` on, all within the file."""
        if pos is None or pos not in rank or rank[pos] + count > len(starts):
            where = "none" if pos is None else f"byte {pos}"
            raise DataFormatError(f"{path}: the bag's {what} (at {where}) is not a complete "
                                  f"record within the file's {size} bytes (a corrupt or "
                                  f"truncated bag)")
        return starts[rank[pos]: rank[pos] + count]

    header = records[need(len(ROS1_MAGIC), 1, "header record")[0]][0]
    index_pos = _uint(header, b"index_pos", 8)
    conns = _uint(header, b"conn_count", 4) or 0
    chunks = _uint(header, b"chunk_count", 4) or 0
    if not index_pos or not chunks:
        return  # rosbags refuses an unindexed bag and reads nothing from one without chunks
    index = need(index_pos, conns + chunks, "index (connection and chunk-info records)")
    for pos in index[conns:]:
        fields, _ = records[pos]
        count = _uint(fields, b"count", 4)
        chunk = need(_uint(fields, b"chunk_pos", 8), 1 + (count or 0),
                     f"chunk named by the chunk-info record at byte {pos}")
        if records[chunk[0]][0].get(b"op") != b"\x05":
            raise DataFormatError(f"{path}: the chunk-info record at byte {pos} points at byte "
                                  f"{chunk[0]}, which is not a chunk record")


# ---------------------------------------------------------------------------------- MCAP
def check_mcap_records(path: Path) -> None:
    """Refuse an MCAP file whose top-level records (header, summary, chunks) claim more bytes
    than the file holds, whose footer points at no record, or whose chunk indexes point at no
    chunk or claim more compressed bytes than their chunk holds. Files without the MCAP magic
    are left to rosbags."""
    try:
        with path.open("rb") as fh:
            if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                return
            size = fh.seek(0, 2)
            _check_mcap(fh, size, path)
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read the MCAP file ({_one_line(exc)})") from None


def _check_mcap(fh: BinaryIO, size: int, path: Path) -> None:
    footer_start = size - 37
    records: dict[int, tuple[int, int]] = {}  # start -> (opcode, content length)
    pos = len(MCAP_MAGIC)
    while pos + 9 <= footer_start:
        fh.seek(pos)
        op, length = struct.unpack("<BQ", fh.read(9))
        if pos + 9 + length > size:
            raise DataFormatError(f"{path}: MCAP record at byte {pos} claims {length} bytes, "
                                  f"past the end of the file ({size} bytes)")
        records[pos] = (op, length)
        pos += 9 + length
    if footer_start < len(MCAP_MAGIC):
        return  # rosbags refuses a file this short before reading any length
    fh.seek(footer_start + 9)
    (summary_start,) = struct.unpack("<Q", fh.read(8))
    if not summary_start:
        return
    if summary_start not in records:
        raise DataFormatError(f"{path}: the MCAP footer's summary offset {summary_start} is "
                              f"not the start of a record")
    for start, (op, length) in sorted(records.items()):
        if start < summary_start or op != 0x08:
            continue
        if length > MAX_ROS1_HEADER:  # tens of bytes plus ten per channel
            raise DataFormatError(f"{path}: MCAP chunk index at byte {start} claims {length} "
                                  f"bytes")
        fh.seek(start + 9)
        content = fh.read(length)
        _check_chunk_index(content, start, records, path)


def _check_chunk_index(content: bytes, start: int, records: dict[int, tuple[int, int]],
                       path: Path) -> None:
    where = f"{path}: MCAP chunk index at byte {start}"
    try:
        chunk_start = struct.unpack_from("<Q", content, 16)[0]
        (offsets_len,) = struct.unpack_from("<I", content, 32)
        pos = 36 + offsets_len + 8
        (name_len,) = struct.unpack_from("<I", content, pos)
        compressed = struct.unpack_from("<Q", content, pos + 4 + name_len)[0]
    except struct.error:
        raise DataFormatError(f"{where} is truncated") from None
    op, length = records.get(chunk_start, (None, 0))
    if op != 0x06:
        raise DataFormatError(f"{where} points at byte {chunk_start}, which is not a chunk")
    if 40 + name_len + compressed > length:
        raise DataFormatError(f"{where} claims {compressed} compressed bytes; its chunk at byte "
                              f"{chunk_start} holds {length}")


def check_storage_files(bag: Path) -> None:
    """The record checks for a ROS 1 bag, a bare MCAP file or a folder's MCAP files."""
    if bag.is_dir():
        for mcap in sorted(bag.glob("*.mcap")):
            check_mcap_records(mcap)
    elif bag.suffix == ".mcap":
        check_mcap_records(bag)
    elif bag.is_file():
        check_ros1_records(bag)
