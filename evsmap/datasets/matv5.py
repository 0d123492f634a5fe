"""A structural check of MATLAB v5 files before scipy reads them.

scipy's MATLAB v5 reader trusts the element tags of the file: a tag with an unknown data type,
or an array whose elements do not match its class (a matrix where numbers belong, fewer values
than its dimensions and fields call for, so that it reads on into the next variable), makes its
compiled code index a table out of bounds and crash the interpreter (a segmentation fault, not
an exception); a tag claiming more bytes than its container holds makes it allocate that much.
:func:`check_mat5` walks every element of the file (inside compressed variables too,
decompressed as a stream), checks each array against its class, and refuses a file that breaks
the layout with one line naming it, before scipy sees it.

Layout (MathWorks, "MAT-File Format", v5): a 128-byte header whose last two bytes say the byte
order (``IM`` little-endian, ``MI`` big-endian), then data elements. An element is an 8-byte tag
(type, byte count) and its data padded to 8 bytes, or a small element (byte count <= 4 in the
tag's upper half, data in its second word). A ``miMATRIX`` element holds elements (array flags,
dimensions, name, then the class's data; cells and struct fields are ``miMATRIX`` again); a
``miCOMPRESSED`` element (top level only) holds one zlib-compressed element.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

from evsmap.errors import DataFormatError

MI_MATRIX, MI_COMPRESSED = 14, 15
DATA_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 15, 16, 17, 18})
"""miINT8 .. miUINT32, miSINGLE, miDOUBLE, miINT64, miUINT64, miMATRIX, miCOMPRESSED, miUTF8/16/32
(the types scipy knows)."""
MI_UINT32 = 6
ARRAY_CLASSES = range(1, 18)
"""mxCELL_CLASS (1) .. mxOPAQUE_CLASS (17)."""
MI_INT8, MI_INT32 = 1, 5
MX_CELL, MX_STRUCT, MX_OBJECT, MX_SPARSE, MX_UINT64 = 1, 2, 3, 5, 15
COMPLEX_FLAG = 0x800
MAX_DIMS = 32
"""scipy's limit on an array's dimensions."""
_HEADS = {MX_CELL: (), MX_STRUCT: (MI_INT32, MI_INT8), MX_OBJECT: (MI_INT8, MI_INT32, MI_INT8)}
"""Elements after the dimensions and the name before a cell's, struct's or object's values."""
MAX_DEPTH = 64
"""Nesting of miMATRIX elements (cells in struct fields in cells ...) beyond any real file's."""
_CHUNK = 1 << 16


class _Bad(Exception):
    """The file breaks the layout (turned into a DataFormatError naming it)."""


class _Source:
    """Sequential bytes: the file, or a compressed element's contents."""

    def __init__(self, read) -> None:
        self._read = read

    def take(self, n: int) -> bytes:
        data = self._read(n)
        if len(data) != n:
            raise _Bad("truncated element")
        return data

    def skip(self, n: int) -> None:
        while n > 0:
            n -= len(self.take(min(n, _CHUNK)))


class _Inflated:
    """The decompressed contents of the next ``nbytes`` bytes of ``parent``, read on demand
    (decompressed :data:`_CHUNK` bytes at a time)."""

    def __init__(self, parent: _Source, nbytes: int) -> None:
        self.parent, self.left = parent, nbytes
        self.z = zlib.decompressobj()
        self.pending = b""
        self.buf, self.pos = b"", 0

    def read(self, n: int) -> bytes:
        while len(self.buf) - self.pos < n and not self.z.eof:
            if not self.pending:
                if self.left == 0:
                    break
                k = min(self.left, _CHUNK)
                self.pending, self.left = self.parent.take(k), self.left - k
            more = self.z.decompress(self.pending, _CHUNK)
            self.pending = self.z.unconsumed_tail
            self.buf, self.pos = self.buf[self.pos:] + more, 0
        out = self.buf[self.pos:self.pos + n]
        self.pos += len(out)
        return out

    def finish(self) -> None:
        """Skip what is left of the compressed bytes in the parent."""
        self.parent.skip(self.left)
        self.left = 0


def _elements(src: _Source, budget: int, order: str, depth: int, *,
              top: bool = False) -> list[tuple[int, int, bytes]]:
    """Check the elements filling ``budget`` bytes of ``src`` (matrices inside them too);
    their (type, byte count, data of the small and int32 ones), in order."""
    found = []
    while budget > 0:
        if budget < 8:
            raise _Bad(f"{budget} stray bytes after the last element")
        tag = src.take(8)
        word, count = struct.unpack(order + "II", tag)
        if word >> 16:  # small element: type and byte count in one word, data in the other
            mdtype, nbytes = word & 0xFFFF, word >> 16
            if nbytes > 4 or mdtype not in DATA_TYPES or mdtype in (MI_MATRIX, MI_COMPRESSED):
                raise _Bad(f"bad small element (type {mdtype}, {nbytes} bytes)")
            found.append((mdtype, nbytes, tag[4:4 + nbytes]))
            budget -= 8
            continue
        mdtype, nbytes = word, count
        if mdtype not in DATA_TYPES:
            raise _Bad(f"unknown data type {mdtype}")
        size = 8 + nbytes + (0 if mdtype == MI_COMPRESSED else -nbytes % 8)
        if size > budget:
            raise _Bad(f"an element claims {nbytes} bytes, more than its container holds")
        if mdtype == MI_COMPRESSED:
            if not top:
                raise _Bad("compressed data inside a variable")
            inner = _Inflated(src, nbytes)
            reader = _Source(inner.read)
            itype, ibytes = struct.unpack(order + "II", reader.take(8))
            if itype != MI_MATRIX:
                raise _Bad(f"compressed element holds type {itype}, not a matrix")
            _matrix(reader, ibytes, order, depth + 1)
            inner.finish()
        elif mdtype == MI_MATRIX:
            _matrix(src, nbytes, order, depth + 1)
            src.skip(-nbytes % 8)
        elif top:
            raise _Bad(f"a top-level element of type {mdtype}, not a variable")
        elif mdtype == MI_INT32 and nbytes <= 4 * MAX_DIMS:  # dimensions, name lengths: kept
            data = src.take(nbytes)
            src.skip(size - 8 - nbytes)
            found.append((mdtype, nbytes, data))
            budget -= size
            continue
        else:
            src.skip(size - 8)
        found.append((mdtype, nbytes, b""))
        budget -= size
    return found


def _matrix(src: _Source, nbytes: int, order: str, depth: int) -> None:
    """A miMATRIX's contents: array flags (scipy reads the class from the 8 bytes after their
    tag whatever the tag says and indexes a fixed table with it), dimensions, name, then what
    the class holds: matrices for cells, structs and objects (after their field names),
    numbers otherwise (scipy looks a data type up in a table that has no entry for a matrix)."""
    if depth > MAX_DEPTH:
        raise _Bad(f"variables nested more than {MAX_DEPTH} deep")
    if nbytes == 0:
        return  # an empty matrix
    if nbytes < 16:
        raise _Bad("a matrix without array flags")
    mdtype, count, flags, _nzmax = struct.unpack(order + "IIII", src.take(16))
    mclass = flags & 0xFF
    if mdtype != MI_UINT32 or count != 8:
        raise _Bad("a matrix without array flags")
    if mclass not in ARRAY_CLASSES:
        raise _Bad(f"unknown array class {mclass}")
    children = _elements(src, nbytes - 16, order, depth)
    if len(children) < 2 or children[0][0] != MI_INT32 or children[0][1] % 4 \
            or not 8 <= children[0][1] <= 4 * MAX_DIMS or children[1][0] != MI_INT8:
        raise _Bad("a matrix without dimensions and name")
    dims = struct.unpack(order + f"{children[0][1] // 4}i", children[0][2])
    if min(dims) < 0:
        raise _Bad(f"negative dimensions {dims}")
    cells = 1
    for d in dims:
        cells *= d
    rest = children[2:]
    kinds = [t for t, _, _ in rest]
    if mclass in _HEADS:
        head = _HEADS[mclass]
        if tuple(kinds[:len(head)]) != head:
            raise _Bad(f"a struct or object (class {mclass}) without field names")
        fields = 1
        if mclass != MX_CELL:
            length = rest[len(head) - 2]
            if len(length[2]) != 4:
                raise _Bad("a struct or object without its field name length")
            width = struct.unpack(order + "i", length[2])[0]
            names = rest[len(head) - 1][1]
            if width <= 0 or names % width:
                raise _Bad(f"field names of {names} bytes, not a multiple of {width}")
            fields = names // width
        values = kinds[len(head):]
        if any(t != MI_MATRIX for t in values) or len(values) != cells * fields:
            raise _Bad(f"a cell, struct or object (class {mclass}) of {cells} x {fields} "
                       f"values holding {len(values)} elements")
    elif mclass <= MX_UINT64:
        wanted = (3 if mclass == MX_SPARSE else 1) + bool(flags & COMPLEX_FLAG)
        if MI_MATRIX in kinds or len(kinds) != wanted:
            raise _Bad(f"an array of class {mclass} with {len(kinds)} data elements, "
                       f"expected {wanted}")


def check_mat5(path: Path) -> None:
    """Refuse ``path`` when it is a MATLAB v5 file whose elements break the layout (see the module
    docstring); other files (v4, HDF5, not MATLAB) are left to the reader's own checks."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(128)
            if len(head) < 128 or 0 in head[:4] or head[126:128] not in (b"IM", b"MI"):
                return
            if head[124 + (head[126] == ord("I"))] != 1:
                return  # version 2: MATLAB v7.3 (HDF5), which scipy refuses itself
            order = "<" if head[126:128] == b"IM" else ">"
            size = Path(path).stat().st_size
            _elements(_Source(fh.read), size - 128, order, 0, top=True)
    except _Bad as exc:
        raise DataFormatError(f"{path}: not a readable MATLAB file ({exc})") from None
    except zlib.error as exc:
        raise DataFormatError(f"{path}: not a readable MATLAB file (compressed data: {exc})") \
            from None
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
