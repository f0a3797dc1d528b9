"""One register-map entry: where a signal lives in a Modbus device and how its bits become numbers.

An entry names the table (``coil``, ``discrete_input``, ``input``, ``holding``), the first
address, ``count`` (registers for the register tables, bits for the bit tables, as in a
Modbus request), the value type (``int16``, ``uint16``, ``int32``, ``uint32``, ``float32``;
``bool`` for the bit tables), the word order of 32-bit values (``big``: most significant
register first, the Modbus convention; ``little``: least significant first, e.g. igus), the
byte order inside a register (``big`` is the Modbus convention), and the linear conversion
``value = raw * scale + offset`` into ``unit``.

The codec here is written with ``struct`` directly and deliberately shares nothing with the
simulated controllers' encoder (which uses pymodbus' own conversion), so that an encoding
mistake on either side shows up in the tests instead of cancelling out.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import Mapping, Sequence

TABLES = ("coil", "discrete_input", "input", "holding")
BIT_TABLES = ("coil", "discrete_input")
WRITABLE_TABLES = ("coil", "holding")
# type -> (registers per value, struct format, integer?)
TYPES: dict[str, tuple[int, str, bool]] = {
    "bool": (1, "?", True),
    "int16": (1, "h", True),
    "uint16": (1, "H", True),
    "int32": (2, "i", True),
    "uint32": (2, "I", True),
    "float32": (2, "f", False),
}
ORDERS = ("big", "little")
MAX_READ_REGISTERS = 125  # Modbus application protocol: FC3/FC4 read 1..125 registers
MAX_READ_BITS = 2000  # FC1/FC2
MAX_WRITE_REGISTERS = 123  # FC16
MAX_WRITE_BITS = 1968  # FC15


class EncodingError(ValueError):
    """A value cannot be represented in an entry's type (out of range, not finite)."""


@dataclass(frozen=True)
class Entry:
    """Where one signal lives and how it is encoded (see the module docstring)."""

    name: str
    table: str
    address: int
    count: int  # registers (register tables) or bits (bit tables)
    type: str
    word_order: str = "big"
    byte_order: str = "big"
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    ok_values: tuple[int, ...] | None = None  # status signals: raw values that mean "ready"
    value_names: Mapping[int, str] = field(default_factory=dict)  # status signals: names for messages
    source: str = ""  # "preset ur_modbus_server" or "map", for messages

    @property
    def width(self) -> int:
        """Registers (or bits) per value."""
        return TYPES[self.type][0]

    @property
    def n_values(self) -> int:
        return self.count // self.width

    @property
    def end(self) -> int:
        """First address after the entry."""
        return self.address + self.count

    @property
    def is_bits(self) -> bool:
        return self.table in BIT_TABLES

    @property
    def is_integer(self) -> bool:
        return TYPES[self.type][2]

    def describe(self) -> str:
        span = str(self.address) if self.count == 1 else f"{self.address}-{self.end - 1}"
        kind = "bits" if self.is_bits else "registers"
        return f"{self.name} ({self.table} {kind} {span}, {self.type})"

    def register_of(self, index: int) -> int:
        """Address of the first register of value ``index``."""
        return self.address + index * self.width

    # -- codec --------------------------------------------------------------------------------
    def raw_values(self, words: Sequence[int | bool]) -> list[int | float | bool]:
        """The raw numbers in ``words`` (this entry's registers or bits, in address order)."""
        if len(words) != self.count:
            raise ValueError(f"{self.describe()}: expected {self.count} words, got {len(words)}")
        if self.is_bits:
            return [bool(w) for w in words]
        fmt = TYPES[self.type][1]
        out = []
        for i in range(self.n_values):
            chunk = list(words[i * self.width:(i + 1) * self.width])
            if self.word_order == "little":
                chunk.reverse()
            data = b"".join(_word_bytes(int(w), self.byte_order) for w in chunk)
            out.append(struct.unpack(">" + fmt, data)[0])
        return out

    def decode(self, words: Sequence[int | bool]) -> list[float]:
        """Values in ``unit``: raw * scale + offset."""
        return [float(r) * self.scale + self.offset for r in self.raw_values(words)]

    def encode(self, values: Sequence[float | int | bool]) -> list[int | bool]:
        """Registers (or bits) for ``values`` given in ``unit``; EncodingError if one does not fit."""
        if len(values) != self.n_values:
            raise EncodingError(f"{self.describe()}: expected {self.n_values} values, got {len(values)}")
        if self.is_bits:
            return [bool(v) for v in values]
        fmt = TYPES[self.type][1]
        words: list[int | bool] = []
        for i, v in enumerate(values):
            raw = (float(v) - self.offset) / self.scale
            if not math.isfinite(raw):
                raise EncodingError(f"{self.name}[{i}] = {v!r} is not a finite number")
            if self.is_integer:
                raw_i = int(round(raw))
                lo, hi = _int_range(self.type)
                if not lo <= raw_i <= hi:
                    raise EncodingError(f"{self.name}[{i}] = {v:g} {self.unit} is {raw_i} in {self.type} units "
                                        f"(scale {self.scale:g}), outside {lo}..{hi}")
                data = struct.pack(">" + fmt, raw_i)
            else:
                data = struct.pack(">" + fmt, raw)
            chunk = [_bytes_word(data[k:k + 2], self.byte_order) for k in range(0, len(data), 2)]
            if self.word_order == "little":
                chunk.reverse()
            words.extend(chunk)
        return words


def _word_bytes(word: int, byte_order: str) -> bytes:
    hi, lo = (word >> 8) & 0xFF, word & 0xFF
    return bytes((hi, lo)) if byte_order == "big" else bytes((lo, hi))


def _bytes_word(two: bytes, byte_order: str) -> int:
    return (two[0] << 8 | two[1]) if byte_order == "big" else (two[1] << 8 | two[0])


def _int_range(type_name: str) -> tuple[int, int]:
    bits = 16 if type_name.endswith("16") else 32
    if type_name.startswith("u") or type_name == "bool":
        return 0, (1 << bits) - 1
    return -(1 << (bits - 1)), (1 << (bits - 1)) - 1


def int_range(type_name: str) -> tuple[int, int]:
    """Smallest and largest raw integer of an integer type."""
    return _int_range(type_name)


@dataclass(frozen=True)
class Block:
    """One read request: a contiguous span of one table covering one or more entries."""

    table: str
    address: int
    count: int
    entries: tuple[Entry, ...]

    def slice_for(self, entry: Entry, words: Sequence[int | bool]) -> Sequence[int | bool]:
        start = entry.address - self.address
        return words[start:start + entry.count]

    def describe(self) -> str:
        return f"{self.table} {self.address}-{self.address + self.count - 1}"


def group_reads(entries: Sequence[Entry], bridge_gaps: int = 0) -> list[Block]:
    """As few read requests as cover ``entries``: same table, gaps of at most ``bridge_gaps`` bridged.

    A real device may answer a read over addresses it does not define with exception 2
    (illegal data address), so gaps are only bridged when the map says the device allows it.
    """
    blocks: list[Block] = []
    for table in TABLES:
        mine = sorted((e for e in entries if e.table == table), key=lambda e: e.address)
        limit = MAX_READ_BITS if table in BIT_TABLES else MAX_READ_REGISTERS
        current: list[Entry] = []
        for e in mine:
            if current:
                start, end = current[0].address, max(c.end for c in current)
                if e.address - end <= bridge_gaps and max(end, e.end) - start <= limit:
                    current.append(e)
                    continue
                blocks.append(_block(table, current))
            current = [e]
        if current:
            blocks.append(_block(table, current))
    return blocks


def group_writes(entries: Sequence[Entry]) -> list[Block]:
    """Write requests for ``entries``: only exactly adjacent entries share a request (no gap is overwritten)."""
    blocks: list[Block] = []
    for table in WRITABLE_TABLES:
        mine = sorted((e for e in entries if e.table == table), key=lambda e: e.address)
        limit = MAX_WRITE_BITS if table in BIT_TABLES else MAX_WRITE_REGISTERS
        current: list[Entry] = []
        for e in mine:
            if current and e.address == current[-1].end and e.end - current[0].address <= limit:
                current.append(e)
                continue
            if current:
                blocks.append(_block(table, current))
            current = [e]
        if current:
            blocks.append(_block(table, current))
    return blocks


def _block(table: str, entries: list[Entry]) -> Block:
    start = entries[0].address
    end = max(e.end for e in entries)
    return Block(table, start, end - start, tuple(entries))
