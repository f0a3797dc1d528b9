"""The simulated Modbus device's memory: four tables, the addresses it defines, and how it answers.

``RegisterStore`` is what the pymodbus server reads and writes (it has the datastore calls the
server makes: ``async_getValues``, ``async_setValues``, ``device_ids``). It is strict like a real
device: a request touching an address the device does not define gets exception 2 (illegal
data address), and over RTU a request for another unit id gets no reply at all. Fault hooks:
a reply delay, exception replies for reads of chosen registers, and a callback on every write
(the controller logs move and stop commands with their receive time).

The codec (``encode``/``decode``) uses pymodbus' own register conversion, not the driver's
``struct`` code, so that the two sides check each other.
"""

from __future__ import annotations

import asyncio
import math
import threading
from typing import Callable, Sequence

from pymodbus.client.mixin import ModbusClientMixin
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException

from payload_agent.drivers.modbus.registers import BIT_TABLES, TABLES, Entry, int_range

_DT = ModbusClientMixin.DATATYPE
_DATATYPES = {"int16": _DT.INT16, "uint16": _DT.UINT16, "int32": _DT.INT32, "uint32": _DT.UINT32,
              "float32": _DT.FLOAT32}
FC_TABLE = {1: "coil", 5: "coil", 15: "coil", 2: "discrete_input", 3: "holding", 6: "holding", 16: "holding",
            22: "holding", 23: "holding", 4: "input"}
SIZE = 65536


def _swap(word: int) -> int:
    return ((word & 0xFF) << 8) | (word >> 8)


def encode(entry: Entry, values: Sequence[float]) -> list:
    """Registers for values in the entry's unit, as the device stores them (integers saturate)."""
    if entry.is_bits:
        return [bool(v) for v in values]
    out: list[int] = []
    for v in values:
        raw = (float(v) - entry.offset) / entry.scale
        if entry.type == "float32":
            value: float | int = raw
        else:
            lo, hi = int_range(entry.type)
            value = min(max(int(round(raw)), lo), hi) if math.isfinite(raw) else 0
        words = ModbusClientMixin.convert_to_registers(value, _DATATYPES[entry.type], word_order=entry.word_order)
        out.extend([_swap(w) for w in words] if entry.byte_order == "little" else words)
    return out


def decode(entry: Entry, words: Sequence) -> list[float]:
    """Values (entry unit) of the entry's registers as the agent wrote them."""
    if entry.is_bits:
        return [float(bool(w)) for w in words]
    regs = [_swap(w) for w in words] if entry.byte_order == "little" else list(words)
    out = []
    for i in range(entry.n_values):
        chunk = regs[i * entry.width:(i + 1) * entry.width]
        raw = ModbusClientMixin.convert_from_registers(chunk, _DATATYPES[entry.type], word_order=entry.word_order)
        out.append(float(raw) * entry.scale + entry.offset)
    return out


class RegisterStore:
    """Four tables of 65536 registers or bits; thread-safe; the pymodbus server's datastore."""

    def __init__(self, valid: dict[str, list[tuple[int, int]]], unit_id: int = 1, any_unit: bool = True):
        self.tables: dict[str, list] = {t: ([False] * SIZE if t in BIT_TABLES else [0] * SIZE) for t in TABLES}
        self.valid = {t: sorted(valid.get(t, [])) for t in TABLES}
        self.unit_id = unit_id
        self.any_unit = any_unit  # TCP devices usually answer any unit id; RTU only their own
        self._lock = threading.Lock()
        self.reply_delay_s = 0.0
        self.failing_reads: list[tuple[str, int, int, int]] = []  # (table, start, end, exception code)
        self.on_write: Callable[[str, int, list], None] | None = None
        # registers computed only when read (table, start, end, fill): costly values a device refreshes
        # every cycle but a client reads rarely (the TCP pose)
        self.on_read: list[tuple[str, int, int, Callable[[], None]]] = []
        self.before_read: Callable[[], None] | None = None  # brings the device up to date first

    # -- direct access (controller side) ---------------------------------------------------------
    def set(self, table: str, address: int, words: Sequence) -> None:
        with self._lock:
            self.tables[table][address:address + len(words)] = list(words)

    def set_many(self, items: Sequence[tuple[str, int, Sequence]]) -> None:
        """Several writes at once (one refresh of the device image: no reader sees half of it)."""
        with self._lock:
            for table, address, words in items:
                self.tables[table][address:address + len(words)] = list(words)

    def get(self, table: str, address: int, count: int) -> list:
        with self._lock:
            return list(self.tables[table][address:address + count])

    def write_entry(self, entry: Entry, values: Sequence[float]) -> None:
        self.set(entry.table, entry.address, encode(entry, values))

    def read_entry(self, entry: Entry) -> list[float]:
        return decode(entry, self.get(entry.table, entry.address, entry.count))

    def defines(self, table: str, address: int, count: int) -> bool:
        end = address + count
        pos = address
        for a, b in self.valid[table]:
            if a <= pos < b:
                pos = b
                if pos >= end:
                    return True
        return pos >= end

    # -- the pymodbus datastore interface ----------------------------------------------------------
    def device_ids(self) -> list[int]:
        return [self.unit_id]

    def _check_unit(self, device_id: int) -> None:
        if not self.any_unit and device_id != self.unit_id:
            raise NoSuchIdException(f"unit {device_id} is not this device ({self.unit_id})")

    async def async_getValues(self, device_id: int, func_code: int, address: int, count: int = 1):
        result = self._get_values(device_id, func_code, address, count)
        if self.reply_delay_s:  # a slow device: the values are taken now, the reply comes late
            await asyncio.sleep(self.reply_delay_s)
        return result

    def _get_values(self, device_id: int, func_code: int, address: int, count: int):
        self._check_unit(device_id)
        table = FC_TABLE.get(func_code)
        if table is None:
            return ExcCodes.ILLEGAL_FUNCTION
        if not self.defines(table, address, count):
            return ExcCodes.ILLEGAL_ADDRESS
        if self.before_read is not None:
            self.before_read()
        for t, a, b, code in list(self.failing_reads):
            if t == table and address < b and a < address + count:
                return ExcCodes(code)
        for t, a, b, fill in self.on_read:
            if t == table and address < b and a < address + count:
                fill()
        return self.get(table, address, count)

    async def async_setValues(self, device_id: int, func_code: int, address: int, values):
        result = self._set_values(device_id, func_code, address, values)
        if self.reply_delay_s:  # the write takes effect now, its reply comes late
            await asyncio.sleep(self.reply_delay_s)
        return result

    def _set_values(self, device_id: int, func_code: int, address: int, values):
        self._check_unit(device_id)
        table = FC_TABLE.get(func_code)
        if table not in ("coil", "holding"):
            return ExcCodes.ILLEGAL_FUNCTION
        values = list(values) if isinstance(values, (list, tuple)) else [values]
        if not self.defines(table, address, len(values)):
            return ExcCodes.ILLEGAL_ADDRESS
        self.set(table, address, [bool(v) for v in values] if table == "coil" else [int(v) for v in values])
        if self.on_write is not None:
            self.on_write(table, address, values)
        return None


def valid_ranges(entries: Sequence[Entry], bridge_gaps: int) -> dict[str, list[tuple[int, int]]]:
    """The addresses a device defines: every entry, and the gaps the map says it answers."""
    out: dict[str, list[tuple[int, int]]] = {}
    for table in TABLES:
        spans = sorted((e.address, e.end) for e in entries if e.table == table)
        merged: list[list[int]] = []
        for a, b in spans:
            if merged and a - merged[-1][1] <= bridge_gaps:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        out[table] = [(a, b) for a, b in merged]
    return out
