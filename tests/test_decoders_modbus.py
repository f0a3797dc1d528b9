"""Property-based tests of the Modbus driver's decoders (issue 13, "bad input").

* Register words -> values: for every preset (and a user map with float32 angles, revolution
  counters and a float32 timestamp), arbitrary register contents read through the driver's own
  readers (the sample, ``state``, ``identify``, ``flange_pose``, ``read_payload``) give a value
  (finite where it is a measurement) or CommunicationError, never another exception.
* Round trips: the simulated device's encoder (pymodbus' register conversion, ``fakes.modbus``)
  and the driver's ``struct`` decoder agree within one register step for every type, word and
  byte order and scale; UR's unsigned angles with revolution counters come back as the angle the
  fake encoded; the driver's encoder and the fake's decoder agree the other way.
* Map validation: an arbitrary ``driver.map`` gives a RegisterMap or ConfigError naming the key.
* The wire: a Modbus TCP "device" answering a read with arbitrary bytes gives the words or
  CommunicationError (through pymodbus), bounded in time.
"""

from __future__ import annotations

import math
import os
import socket
import struct
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from payload_agent.drivers.base import MotionLimits
from payload_agent.drivers.stream import check_sample as _check_sample
from payload_agent.drivers.modbus.bus import Endpoint, ModbusBus
from payload_agent.drivers.modbus.driver import ModbusDriver
from payload_agent.drivers.modbus.options import parse_modbus_options
from payload_agent.drivers.modbus.registers import TYPES, Block, Entry, int_range
from payload_agent.drivers.modbus.regmap import SIGNALS, build_map, load_preset, preset_names
from payload_agent.errors import CommunicationError, ConfigError, UnsupportedCapability
from payload_agent.fakes.modbus import store as fake_store
from payload_agent.types import ControllerInfo, ControllerState, FlangePose, PayloadSetting, Sample
from fuzzing import HANG_S, bounded  # noqa: F401

# DECODER_FUZZ_SCALE=20 searches 20 times harder (a deep run by hand; the suite keeps the default)
SCALE = float(os.environ.get("DECODER_FUZZ_SCALE", "1"))
FUZZ = settings(max_examples=int(100 * SCALE), deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
LIMITS = MotionLimits(math.radians(180), math.radians(360))
# a map of the kind a user writes: float32 angles, int16 revolution counters, a float32 clock
USER_MAP = {"joint_angles": {"table": "input", "address": 0, "count": 12, "type": "float32", "unit": "deg"},
            "joint_revolutions": {"table": "input", "address": 100, "count": 6, "type": "int16",
                                  "scale": 360.0, "unit": "deg"},
            "timestamp": {"table": "input", "address": 24, "count": 2, "type": "float32", "unit": "s"}}
MAPS = {name: {"preset": name} for name in preset_names()} | {"user": {"preset": "generic_float32", "map": USER_MAP}}




def modbus_driver(map_name: str) -> ModbusDriver:
    opts = parse_modbus_options({"type": "modbus", "host": "127.0.0.1", "heartbeat_timeout_s": 0.01,
                                 "repeat_is_stale": False, **MAPS[map_name]})
    return ModbusDriver(opts, LIMITS)


class ImageBus:
    """A device that answers every read from a register image (what pymodbus hands the driver)."""

    def __init__(self, image: dict[tuple[str, int], int | bool]):
        self.image = image

    def read(self, block: Block):
        zero = False if block.table in ("coil", "discrete_input") else 0
        return [self.image.get((block.table, a), zero) for a in range(block.address, block.address + block.count)]


# float32 high words of NaN, the infinities, huge and tiny numbers, plus anything
special_words = st.sampled_from([0x7F80, 0xFF80, 0x7FC0, 0xFFC0, 0x7F7F, 0xFF7F, 0x0000, 0x0001, 0x8000, 0x7FFF,
                                 0xFFFF, 0x4F00])


@st.composite
def register_images(draw, entries: list[Entry]):
    """Every address the map uses: random words (one draw of bytes, fast), some set to the special ones."""
    addresses = sorted({(e.table, a) for e in entries for a in range(e.address, e.end)})
    raw = draw(st.binary(min_size=2 * len(addresses), max_size=2 * len(addresses)))
    image = {key: (raw[2 * i] & 1 == 1) if key[0] in ("coil", "discrete_input") else raw[2 * i] << 8 | raw[2 * i + 1]
             for i, key in enumerate(addresses)}
    for i, w in draw(st.lists(st.tuples(st.integers(0, len(addresses) - 1), special_words), max_size=8)):
        if addresses[i][0] not in ("coil", "discrete_input"):
            image[addresses[i]] = w
    return image


@pytest.mark.parametrize("map_name", sorted(MAPS))
def test_any_register_contents_give_values_or_a_communication_error(map_name):
    entries = list(modbus_driver(map_name).map.entries.values())

    @FUZZ
    @given(st.lists(register_images(entries), min_size=1, max_size=3))
    def check(images):
        drv = modbus_driver(map_name)
        for image in images:
            drv._stream = drv._cmd = ImageBus(image)
            drv._next_poll = 0.0  # no pacing between reads here
            try:
                sample = drv._read_sample(0.05)
                if sample is not None:
                    _check_sample(sample, 6)  # what the base's reader does with it
            except CommunicationError:
                sample = None
            if sample is not None:
                assert isinstance(sample, Sample)
                assert all(math.isfinite(v) for v in (*sample.q, *sample.effort))
                assert sample.t_ctrl is None or math.isfinite(sample.t_ctrl), sample.t_ctrl
            for name, reader, kind in (("state", drv.state, ControllerState),
                                       ("identify", drv.identify, ControllerInfo),
                                       ("flange_pose", drv.flange_pose, (FlangePose, type(None))),
                                       ("read_payload", drv.read_payload, PayloadSetting)):
                try:
                    value = reader()
                except CommunicationError:
                    continue
                except UnsupportedCapability:  # a map without the payload readback registers
                    assert name == "read_payload" and "payload_readback_mass" not in drv.map
                    continue
                assert isinstance(value, kind), f"{name} returned {value!r}"
                if isinstance(value, FlangePose):
                    assert all(math.isfinite(v) for v in value.position_m)
                    assert all(math.isfinite(v) for row in value.rotation for v in row)
                if isinstance(value, PayloadSetting):
                    assert math.isfinite(value.mass_kg) and all(math.isfinite(c) for c in value.cog_m)

    check()


# -- round trips: the fake's encoder (pymodbus) against the driver's decoder (struct), both ways -------------
@st.composite
def entries_and_values(draw):
    type_name = draw(st.sampled_from([t for t in TYPES if t != "bool"]))
    width = TYPES[type_name][0]
    n = draw(st.integers(1, 6))
    scale = draw(st.sampled_from([1.0, 0.001, 0.01, 1e-5, 0.1, 6.283185307179586, 360.0, -0.5]))
    offset = draw(st.sampled_from([0.0, -100.0, 2.5]))
    e = Entry("joint_angles", "holding", draw(st.integers(0, 1000)), n * width, type_name,
              draw(st.sampled_from(["big", "little"])), draw(st.sampled_from(["big", "little"])), scale, offset)
    if type_name == "float32":
        raws = draw(st.lists(st.floats(width=32, allow_nan=False, allow_infinity=False).filter(lambda v: abs(v) < 1e30),
                                   min_size=n, max_size=n))
    else:
        lo, hi = int_range(type_name)
        raws = draw(st.lists(st.integers(lo, hi), min_size=n, max_size=n))
    return e, [r * scale + offset for r in raws]


def close(a: float, b: float, e: Entry) -> bool:
    """Equal within one register step (integers) or float32 precision."""
    if e.type == "float32":
        return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-6 * abs(e.scale) + 1e-9 * abs(e.offset) + 1e-12)
    return abs(a - b) <= 0.5 * abs(e.scale) + 1e-9 * max(1.0, abs(a), abs(b))


@FUZZ
@given(entries_and_values())
def test_fake_encoding_decodes_to_the_same_values_in_the_driver(case):
    e, values = case
    got = e.decode(fake_store.encode(e, values))
    assert all(close(a, b, e) for a, b in zip(got, values)), (values, got)


@FUZZ
@given(entries_and_values())
def test_driver_encoding_decodes_to_the_same_values_in_the_fake(case):
    e, values = case
    got = fake_store.decode(e, e.encode(values))
    assert all(close(a, b, e) for a, b in zip(got, values)), (values, got)


class StoreBus:
    """Reads straight from the simulated device's register store (no network: the codec is under test)."""

    def __init__(self, store):
        self.store = store

    def read(self, block: Block):
        return self.store.get(block.table, block.address, block.count)


angles = st.floats(-4 * math.pi + 1e-6, 4 * math.pi - 1e-6, allow_nan=False)


@FUZZ
@given(st.lists(angles, min_size=6, max_size=6), st.lists(st.floats(-300, 300), min_size=6, max_size=6))
@example([0.0, -1e-9, -math.pi, 2 * math.pi - 1e-9, -2 * math.pi, 4 * math.pi - 1e-6], [0.0] * 6)
@example([-1e-300, 1e-300, -2 * math.pi + 1e-12, 2 * math.pi, -4 * math.pi + 1e-6, 3.0], [-300.0] * 6)
def test_ur_unsigned_angles_with_revolution_counters_round_trip(q, torque):
    """UR's server: unsigned mrad within a turn + an int16 revolution counter (65535 for negative angles);
    the fake's image encodes the simulated angle, the driver's sample decodes it within half a mrad."""
    from payload_agent.fakes.arms import ur5e_spec
    from payload_agent.fakes.modbus.image import SensorImage
    from payload_agent.fakes.sim_robot import SimState

    drv = modbus_driver("ur_modbus_server")
    gains = np.full(6, 10.0)
    store = fake_store.RegisterStore({})
    SensorImage(store, drv.map, ur5e_spec().dh, gains, np.ones(6)).write(
        SimState(t=1.0, q=np.asarray(q), qd=np.zeros(6), qdd=np.zeros(6), torque_nm=np.asarray(torque),
                 moving=False, estop=False, protective_stop=False, servo_on=True, move_id=0))
    revs = store.get("holding", drv.map["joint_revolutions"].address, 6)
    assert all(w in (0, 1, 2, 3, 0xFFFF, 0xFFFE, 0xFFFD, 0xFFFC) for w in revs), revs  # two's complement turns
    drv._stream = StoreBus(store)
    sample = drv._read_sample(0.05)
    _check_sample(sample, 6)
    assert np.max(np.abs(np.asarray(sample.q) - q)) <= 0.0005 + 1e-9, (q, sample.q)
    assert np.max(np.abs(np.asarray(sample.effort) - np.asarray(torque) / gains)) <= 0.0005 + 1e-9


# -- map validation --------------------------------------------------------------------------------------------
scalars = (st.none() | st.booleans() | st.integers() | st.integers(10 ** 300, 10 ** 320) | st.floats()
           | st.text(max_size=8) | st.sampled_from(["holding", "input", "coil", "discrete_input", "float32", "int16",
                                                     "uint32", "bool", "big", "little", "rad", "deg", "A", "mm"]))
yaml_like = st.recursive(scalars, lambda kids: st.lists(kids, max_size=4)
                         | st.dictionaries(scalars.filter(lambda k: k == k and not isinstance(k, float)), kids,
                                           max_size=4), max_leaves=12)
numbers = st.floats() | st.integers(-70000, 70000) | st.integers(10 ** 300, 10 ** 320) | st.sampled_from([0, 0.0, -0.0])
entry_fields = st.one_of(
    st.dictionaries(st.sampled_from(["table", "address", "count", "type", "word_order", "byte_order", "scale",
                                     "offset", "unit", "ok_values", "value_names", "adress"]), yaml_like, max_size=8),
    # close to a valid entry, so that the later checks (scale, offset, unit, ok_values, overlaps) are reached
    st.fixed_dictionaries(
        {"table": st.sampled_from(["holding", "input", "coil", "discrete_input"]), "address": numbers,
         "count": st.sampled_from([1, 2, 3, 6, 12]) | numbers},
        optional={"type": st.sampled_from(sorted(TYPES)) | yaml_like, "scale": numbers | yaml_like,
                  "offset": numbers | yaml_like, "unit": st.sampled_from(["rad", "deg", "A", "Nm", "mm", "m", "kg"]),
                  "word_order": st.sampled_from(["big", "little", "middle"]), "ok_values": yaml_like,
                  "value_names": yaml_like}),
)
overrides = st.dictionaries(st.sampled_from(sorted(SIGNALS) + ["no_such_signal"]), st.none() | entry_fields | yaml_like,
                            max_size=5)


@FUZZ
@given(st.sampled_from([None, *preset_names()]), overrides | yaml_like)
@example("ur_modbus_server", {"joint_angles": {"scale": 10 ** 400}})
@example("ur_modbus_server", {"joint_efforts": {"offset": -(10 ** 400), "unit": "A"}})
def test_any_register_map_is_accepted_or_refused_with_the_key_named(preset, data):
    try:
        regmap = build_map(load_preset(preset) if preset else None, data, "driver", "robot.yaml", preset)
    except ConfigError as exc:
        assert exc.key_path.startswith("driver"), exc.key_path
        assert exc.source == "robot.yaml"
        return
    for name, e in regmap.entries.items():  # what it accepted is a usable map
        assert e.count % e.width == 0 and e.n_values == SIGNALS[name].values
        assert math.isfinite(e.scale) and e.scale != 0 and math.isfinite(e.offset)
        assert 0 <= e.address and e.end <= 65536


# -- the wire: pymodbus' client and the driver's bus against a device answering arbitrary bytes ----------------
class RawDevice:
    """A Modbus TCP "device" on loopback: reads one request, answers ``reply(request)`` bytes, then closes."""

    def __init__(self):
        self._ls = socket.create_server(("127.0.0.1", 0))
        self._ls.settimeout(0.2)
        self.port = self._ls.getsockname()[1]
        self.reply = lambda request: b""
        self.hold = False  # True: keep the connection open after the reply (a device gone silent)
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while not self._stop.is_set():
            try:
                conn, _ = self._ls.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn, self.reply, self.hold), daemon=True).start()

    @staticmethod
    def _serve(conn, reply, hold):
        conn.settimeout(HANG_S)
        try:
            with conn:
                request = conn.recv(260)
                if request:
                    conn.sendall(reply(request))
                    if not hold:
                        conn.shutdown(socket.SHUT_WR)
                    while conn.recv(260):  # until the client hangs up
                        pass
        except OSError:
            pass

    def close(self):
        self._stop.set()
        self._ls.close()


@pytest.fixture(scope="module")
def device():
    dev = RawDevice()
    yield dev
    dev.close()


def mbap(request: bytes, pdu: bytes, unit: int | None = None, length_delta: int = 0) -> bytes:
    """A reply header answering ``request``'s transaction id, with ``pdu``."""
    tid = request[:2]
    unit_id = request[6] if unit is None else unit
    return tid + b"\0\0" + struct.pack(">H", (len(pdu) + 1 + length_delta) % 65536) + bytes([unit_id]) + pdu


replies = st.one_of(
    st.binary(max_size=40).map(lambda b: (lambda req: b)),
    st.binary(max_size=40).map(lambda pdu: (lambda req: mbap(req, pdu))),
    st.tuples(st.sampled_from([3, 4, 0x83, 0x84, 1, 16]), st.integers(0, 255), st.binary(max_size=30),
              st.integers(-2, 2)).map(lambda t: (lambda req: mbap(req, bytes([t[0], t[1]]) + t[2], length_delta=t[3]))),
    st.tuples(st.integers(0, 255), st.binary(max_size=12)).map(lambda t: (lambda req: mbap(req, bytes([3]) + t[1],
                                                                                            unit=t[0]))),
    st.builds(lambda n: (lambda req: mbap(req, bytes([3, 2 * n]) + b"\x12\x34" * n)), st.integers(0, 10)),
)


@settings(FUZZ, max_examples=int(60 * SCALE))
@given(replies)
def test_a_read_answered_with_any_bytes_gives_the_words_or_a_communication_error(device, reply):
    device.reply = reply
    ep = Endpoint("tcp", "127.0.0.1", device.port, None, 115200, "N", 1, 8, 1, 0.3, 0)
    entry = Entry("joint_angles", "holding", 270, 6, "uint16")
    block = Block("holding", 270, 6, (entry,))
    bus = ModbusBus(ep, "fuzz connection")
    try:
        bounded(bus.open)
        words = bounded(bus.read, block)
    except CommunicationError:
        return
    finally:
        bus.close()
    assert len(words) == 6 and all(isinstance(w, int) and 0 <= w <= 0xFFFF for w in words)
    assert entry.decode(words)  # and they decode


@pytest.mark.parametrize("reply", [lambda req: b"", lambda req: req[:5],
                                   lambda req: mbap(req, bytes([3, 12]) + b"\x12")],
                         ids=["silence", "half a header", "half a reply"])
def test_a_device_that_goes_silent_mid_reply_gives_a_timeout_not_a_hang(device, reply):
    device.reply, device.hold = reply, True
    ep = Endpoint("tcp", "127.0.0.1", device.port, None, 115200, "N", 1, 8, 1, 0.2, 0)
    entry = Entry("joint_angles", "holding", 270, 6, "uint16")
    bus = ModbusBus(ep, "fuzz connection")
    try:
        bounded(bus.open)
        with pytest.raises(CommunicationError):
            bounded(bus.read, Block("holding", 270, 6, (entry,)))
    finally:
        bus.close()
        device.hold = False
