"""configs/devices/cia402.eds against an EDS checker: the two importers of the field (python-canopen's, which
the emulation and a lab's master use, and CanFestival's objdictgen), and the rules of CiA 306 (the EDS
format) and CiA 301 that can be checked from the file alone, read here with configparser, not through
either importer. Then the file against the host side (drivers/devices/cia402.py), which assumes its PDOs.
"""

from __future__ import annotations

import configparser
import logging
import re
import struct

import pytest

from drivers.devices.cia402 import RPDO1_FMT, TPDO1_FMT, TPDO2_FMT, TPDO3_FMT, eds_path

canopen = pytest.importorskip("canopen", reason="the cia402 profile needs python-canopen (a dependency)")

SIZES = {0x0001: 1, 0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}
"""CiA 301 data types (BOOLEAN, INTEGER8-32, UNSIGNED8-32) -> bits."""
SIGNED = {0x0002, 0x0003, 0x0004}
STRINGS = {0x0009, 0x000A, 0x000B}
ACCESS = {"ro", "wo", "rw", "rwr", "rww", "const"}
FILE_INFO = ("FileName", "FileVersion", "FileRevision", "EDSVersion", "Description", "CreationTime",
             "CreationDate", "CreatedBy", "ModificationTime", "ModificationDate", "ModifiedBy")  # fmt: skip
DEVICE_INFO = ("VendorName", "VendorNumber", "ProductName", "ProductNumber", "RevisionNumber", "OrderCode",
               *(f"BaudRate_{b}" for b in (10, 20, 50, 125, 250, 500, 800, 1000)), "SimpleBootUpMaster",
               "SimpleBootUpSlave", "Granularity", "DynamicChannelsSupported", "GroupMessaging",
               "NrOfRXPDO", "NrOfTXPDO", "LSS_Supported")  # fmt: skip
COMMUNICATION = (0x1000, 0x1001, 0x1003, 0x1005, 0x1006, 0x1008, 0x1009, 0x100A, 0x1014, 0x1016, 0x1017,
                 0x1018, *range(0x1400, 0x1404), *range(0x1600, 0x1604), *range(0x1800, 0x1804),
                 *range(0x1A00, 0x1A04))  # fmt: skip
"""What the drive must have of CiA 301 (issue 39)."""
TORQUE_DRIVE = (0x603F, 0x6040, 0x6041, *range(0x605A, 0x605F), 0x6060, 0x6061, 0x6064, 0x606C, 0x6071,
                *range(0x6072, 0x6079), 0x6087, 0x60FD, 0x6502)  # fmt: skip
"""What a CiA 402 drive in cyclic synchronous torque has (issue 39)."""
SUB = re.compile(r"^([0-9A-F]{4})sub([0-9A-F]{1,2})$", re.IGNORECASE)


def _number(text: str, node_id: int = 1) -> int:
    """An EDS number: decimal, 0x hex, 0 octal (CiA 306), or $NODEID+n."""
    text = text.strip()
    if text.upper().startswith("$NODEID"):
        return node_id + _number(text.split("+", 1)[1])
    if text.lower().startswith(("0x", "-0x")):
        return int(text, 16)
    if re.fullmatch(r"-?0[0-7]+", text):
        return int(text, 8)
    return int(text)


@pytest.fixture(scope="module")
def eds() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(interpolation=None, strict=True)  # strict: no section twice
    parser.optionxform = str  # keys keep their case
    parser.read(eds_path(), encoding="ascii")  # CiA 306: an ASCII file
    return parser


def _objects(eds) -> dict[int, configparser.SectionProxy]:
    return {int(s, 16): eds[s] for s in eds.sections() if re.fullmatch(r"[0-9A-Fa-f]{4}", s)}


def _subs(eds, index: int) -> dict[int, configparser.SectionProxy]:
    out = {}
    for s in eds.sections():
        m = SUB.match(s)
        if m and int(m[1], 16) == index:
            out[int(m[2], 16)] = eds[s]
    return out


def _mapped(eds, mapping: int) -> list[int]:
    """A PDO mapping object's default entries (sub-index 0 of them)."""
    entries = _subs(eds, mapping)
    return [_number(entries[s]["DefaultValue"]) for s in range(1, _number(entries[0]["DefaultValue"]) + 1)]


def _variables(eds):
    """Every VAR of the file as (index, subindex, section)."""
    for index, section in _objects(eds).items():
        if _number(section["ObjectType"]) == 0x7:
            yield index, 0, section
        for sub, sub_section in _subs(eds, index).items():
            yield index, sub, sub_section


# ------------------------------------------------------------------------------- the importers
def test_python_canopen_imports_it_for_every_node_id():
    for node_id in (1, 3, 127):
        od = canopen.import_od(str(eds_path()), node_id)
        assert od[0x1800][1].default & 0x7FF == 0x180 + node_id, "$NODEID resolved"
        assert od.device_information.vendor_number == od[0x1018][1].default != 0


def test_canfestivals_objdictgen_imports_and_validates_it(caplog):
    eds_utils = pytest.importorskip("objdictgen.eds_utils", reason="objdictgen is a dev dependency")
    with caplog.at_level(logging.WARNING):
        node = eds_utils.generate_node(str(eds_path()), 2)
        node.Validate()
    # Its own loggers only: a suite's other tests may leave threads that log while this one runs.
    warned = [r for r in caplog.records if r.levelno >= logging.WARNING and r.name.startswith("objdictgen")]
    assert warned == [], caplog.text
    assert node.ProfileName == "DS-402" and len(node.GetIndexes()) == len(_objects(_eds()))


def _eds() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(interpolation=None, strict=True)
    parser.optionxform = str
    parser.read(eds_path(), encoding="ascii")
    return parser


# ------------------------------------------------------------------------- CiA 306: the file
def test_file_and_device_info_have_every_key_cia306_asks_with_values_of_their_form(eds):
    info = eds["FileInfo"]
    assert [k for k in FILE_INFO if k not in info] == []
    assert info["EDSVersion"] == "4.0" and info["FileName"] == eds_path().name
    for key in ("CreationTime", "ModificationTime"):
        assert re.fullmatch(r"(0[1-9]|1[0-2]):[0-5]\d(AM|PM)", info[key]), key  # hh:mm(AM|PM)
    for key in ("CreationDate", "ModificationDate"):
        assert re.fullmatch(r"(0[1-9]|1[0-2])-(0[1-9]|[12]\d|3[01])-\d{4}", info[key]), key  # mm-dd-yyyy
    assert len(info["Description"]) <= 243 and len(info["CreatedBy"]) <= 245
    device = eds["DeviceInfo"]
    assert [k for k in DEVICE_INFO if k not in device] == []
    for key in DEVICE_INFO:
        if key.startswith(("BaudRate_", "Simple", "Dynamic", "Group", "LSS")):
            assert device[key] in ("0", "1"), key
    assert device["BaudRate_1000"] == "1", "the rig's bus"
    assert 0 <= _number(device["Granularity"]) <= 64
    dummies = eds["DummyUsage"]
    assert all(dummies[f"Dummy000{i}"] in ("0", "1") for i in range(1, 8))


def test_the_object_lists_name_each_object_once_in_its_range(eds):
    objects = _objects(eds)
    listed: list[int] = []
    for name, ranges in (
        ("MandatoryObjects", ((0x1000, 0x1000), (0x1001, 0x1001), (0x1018, 0x1018))),
        ("OptionalObjects", ((0x1000, 0x1FFF), (0x6000, 0x9FFF))),
        ("ManufacturerObjects", ((0x2000, 0x5FFF),)),
    ):
        section = eds[name]
        count = _number(section["SupportedObjects"])
        entries = [_number(section[str(k)]) for k in range(1, count + 1)]
        assert len(section) == count + 1, f"[{name}]: SupportedObjects={count}, {len(section) - 1} entries"
        assert all(any(lo <= i <= hi for lo, hi in ranges) for i in entries), f"[{name}]: out of range"
        listed += entries
    assert sorted(e for e in listed if e in (0x1000, 0x1001, 0x1018)) == [0x1000, 0x1001, 0x1018]
    assert sorted(listed) == sorted(set(listed)), "an object listed twice"
    assert sorted(listed) == sorted(objects), "listed objects and object sections differ"


def test_every_object_is_well_formed(eds):
    for index, section in _objects(eds).items():
        where = f"[{index:04X}]"
        assert 0 < len(section["ParameterName"]) <= 241, where
        kind = _number(section["ObjectType"])
        assert kind in (0x7, 0x8, 0x9), where
        subs = _subs(eds, index)
        if kind == 0x7:
            assert not subs, f"{where}: a VAR with sub-indices"
            continue
        assert _number(section["SubNumber"]) == len(subs), f"{where}: SubNumber"
        assert 0 in subs and _number(subs[0]["DataType"]) == 0x0005, f"{where}: sub-index 0 is an U8"
        count = _number(subs[0]["DefaultValue"])
        if index == 0x1003 or 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:
            assert count <= max(subs), f"{where}: sub 0 counts errors or mapped objects"
        else:
            assert count == max(subs), f"{where}: sub 0 is the highest sub-index"
    for index, sub, section in _variables(eds):
        where = f"0x{index:04X}:{sub}"
        dtype = _number(section["DataType"])
        assert dtype in SIZES or dtype in STRINGS, where
        assert section["AccessType"] in ACCESS, where
        assert section.get("PDOMapping", "0") in ("0", "1"), where
        if section.get("PDOMapping") == "1":
            assert dtype in SIZES and section["AccessType"] != "const", f"{where}: mappable"
        if dtype in SIZES and "DefaultValue" in section:
            value, bits = _number(section["DefaultValue"]), SIZES[dtype]
            low, high = (-(1 << bits - 1), (1 << bits - 1) - 1) if dtype in SIGNED else (0, (1 << bits) - 1)
            low = _number(section["LowLimit"]) if "LowLimit" in section else low
            high = _number(section["HighLimit"]) if "HighLimit" in section else high
            assert low <= value <= high, f"{where}: default {value} outside {low}..{high}"
        if "$NODEID" in section.get("DefaultValue", "").upper():
            assert 0x1000 <= index <= 0x1FFF and dtype == 0x0007, f"{where}: $NODEID only in a COB-ID"


# ------------------------------------------------------------- CiA 301 and 402: what it must hold
def test_it_has_the_objects_of_a_cia301_device_and_a_cia402_torque_drive(eds):
    objects = _objects(eds)
    assert [f"0x{i:04X}" for i in (*COMMUNICATION, *TORQUE_DRIVE) if i not in objects] == []
    assert len(_eds()["1008"]["DefaultValue"]) > 4, "the device name takes a segmented SDO"
    assert _number(eds["1000"]["DefaultValue"]) & 0xFFFF == 402
    assert _number(eds["6502"]["DefaultValue"]) & 0x200, "cyclic synchronous torque supported"
    identity = _subs(eds, 0x1018)
    device = eds["DeviceInfo"]
    for sub, key in ((1, "VendorNumber"), (2, "ProductNumber"), (3, "RevisionNumber")):
        assert _number(identity[sub]["DefaultValue"]) == _number(device[key]), key
    assert _number(device["VendorNumber"]) != 0, "a vendor id"
    assert len(_subs(eds, 0x1003)) == 9 and eds["1003sub0"]["AccessType"] == "rw", "8 errors, cleared by 0"


def test_the_pdos_match_nrofpdo_are_mapped_as_cia301_allows_and_use_the_predefined_set(eds):
    objects = _objects(eds)
    device = eds["DeviceInfo"]
    for first, count_key, mapping, base in (
        (0x1400, "NrOfRXPDO", 0x1600, 0x200),
        (0x1800, "NrOfTXPDO", 0x1A00, 0x180),
    ):
        count = sum(1 for i in objects if first <= i < first + 0x200)
        assert count == _number(device[count_key]), count_key
        for n in range(count):
            cob = _number(_subs(eds, first + n)[1]["DefaultValue"], node_id=5)
            assert cob & 0x7FF == base + 0x100 * n + 5, f"0x{first + n:04X}: the predefined connection set"
            if first == 0x1800:
                assert cob & 0x40000000, f"0x{first + n:04X}: no RTR (not emulated)"
            entries = _subs(eds, mapping + n)
            mapped = [
                _number(entries[s]["DefaultValue"]) for s in range(1, _number(entries[0]["DefaultValue"]) + 1)
            ]
            bits = 0
            for entry in mapped:
                target = eds[f"{entry >> 16:04X}"]
                assert target.get("PDOMapping") == "1", f"0x{entry:08X} in 0x{mapping + n:04X}: not mappable"
                assert entry & 0xFF == SIZES[_number(target["DataType"])], f"0x{entry:08X}: its length"
                writable = target["AccessType"] in ("rw", "wo", "rww")
                assert writable or first == 0x1800, f"0x{entry:08X}: an RPDO writes only writable objects"
                bits += entry & 0xFF
            assert bits <= 64, f"0x{mapping + n:04X}: {bits} bits"


def test_the_default_pdos_are_what_the_host_side_assumes(eds):
    """drivers/devices/cia402.py reads and writes the PDOs without SDO: its formats are the EDS's."""

    def layout(mapping: int) -> str:
        entries = _subs(eds, mapping)
        mapped = [
            _number(entries[s]["DefaultValue"]) for s in range(1, _number(entries[0]["DefaultValue"]) + 1)
        ]
        codes = {(0x0002, 8): "b", (0x0003, 16): "h", (0x0004, 32): "i", (0x0006, 16): "H", (0x0007, 32): "I"}
        return "<" + "".join(codes[_number(eds[f"{e >> 16:04X}"]["DataType"]), e & 0xFF] for e in mapped)

    for mapping, fmt in ((0x1A00, TPDO1_FMT), (0x1A01, TPDO2_FMT), (0x1A02, TPDO3_FMT), (0x1600, RPDO1_FMT)):
        assert struct.Struct(layout(mapping)).format == fmt.format, f"0x{mapping:04X}"
